"""Reading the project's JSON files (plans, environments): every problem is one
ArmbridgeError that names the file, and the line and column of bad JSON. And
writing the JSON every reporting command offers with `--json FILE|-`
(`emit_json`): '-' is standard output, which then carries the JSON alone,
because the command line (cli.py) sends everything else a command prints to
standard error while `json_to_stdout` holds."""
from __future__ import annotations

import contextlib
import json
import os
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any, TextIO

#: --json's help, the same on every command
JSON_HELP = "Also write {what} as JSON to FILE ('-': stdout, which then carries the JSON alone)."
_stdout: TextIO | None = None     # the real stdout while json_to_stdout holds

from armbridge.errors import ArmbridgeError


def parse_json(text: str, source: Path | str) -> Any:
    try:
        return json.loads(text)
    except json.JSONDecodeError as exc:
        raise ArmbridgeError(f"{source}: line {exc.lineno}, column {exc.colno}: not valid JSON: {exc.msg}") from None


def read_json(path: Path | str, what: str, hint: str = "") -> Any:
    """The parsed file; `what` names the kind of file in messages ("plan file")."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise ArmbridgeError(f"{path}: no such {what}{hint}") from None
    except IsADirectoryError:
        raise ArmbridgeError(f"{path}: is a directory, not a {what}") from None
    except UnicodeDecodeError as exc:
        raise ArmbridgeError(f"{path}: not UTF-8 text (byte {exc.start}): a {what} is JSON") from None
    except OSError as exc:
        raise ArmbridgeError(f"{path}: cannot read: {exc.strerror}") from None
    return parse_json(text, path)


def write_json(path: Path, doc: Any, what: str = "the summary") -> None:
    """Write doc as indented JSON to the file `path` (emit_json's file case: whole, the folder made)."""
    emit_json(doc, Path(path), what)


def wants_json_stdout(argv: list[str]) -> bool:
    """Whether a command line asks for `--json -`."""
    return any(a == "--json=-" or (a == "--json" and nxt == "-") for a, nxt in zip(argv, [*argv[1:], ""]))


@contextlib.contextmanager
def json_to_stdout() -> Iterator[None]:
    """While it holds, what a command prints goes to stderr; `emit_json(..., "-")` to the real stdout."""
    global _stdout
    _stdout = sys.stdout
    try:
        with contextlib.redirect_stdout(sys.stderr):
            yield
    finally:
        _stdout = None


def emit_json(doc: Any, target: str | Path, what: str = "the summary") -> None:
    """`--json TARGET`: '-' writes doc to stdout, anything else to that file, whole (a temporary
    file renamed), making its folder; an OSError is one line naming the file."""
    text = json.dumps(doc, indent=2, default=float) + "\n"
    if str(target) == "-":
        out = _stdout or sys.stdout
        try:
            out.write(text)
            out.flush()
        except OSError:  # the terminal is gone: the exit code still says it
            detach(out)
        return
    path = Path(target)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp.write_text(text)
        os.replace(tmp, path)
    except OSError as exc:
        tmp.unlink(missing_ok=True)
        raise ArmbridgeError(f"{path}: cannot write {what}: {exc.strerror}") from None


def detach(stream: TextIO) -> None:
    """Point `stream`'s file at /dev/null, so that Python's flush at exit cannot fail on a
    closed terminal (which would turn the exit code into 120)."""
    try:
        fd = os.open(os.devnull, os.O_WRONLY)
        os.dup2(fd, stream.fileno())
        os.close(fd)
    except (OSError, ValueError):
        pass
