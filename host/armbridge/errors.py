"""The error types a user sees: printed by the CLI as a single line.

Exit codes (docs/formats.md §7): an ArmbridgeError is bad input or usage
(exit 2: nothing was sent to a board); a BoardFailure is a run or a board
request that was tried and failed (exit 1: a fault, a refusal, no answer, a
busy or lost port).
"""


class ArmbridgeError(Exception):
    """A problem the user can fix (bad file, wrong port, board mismatch).

    The message names what is wrong and where (file, line, field, allowed range).
    """

    exit_code = 2


class BoardFailure(ArmbridgeError):
    """The board or the link failed what was asked of it (exit code 1)."""

    exit_code = 1
