"""The one error type a user sees: printed by the CLI as a single line."""


class ArmbridgeError(Exception):
    """A problem the user can fix (bad file, wrong port, board mismatch).

    The message names what is wrong and where (file, line, field, allowed range).
    """
