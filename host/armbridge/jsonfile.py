"""Reading the project's JSON files (plans, environments): every problem is one
ArmbridgeError that names the file, and the line and column of bad JSON."""
from __future__ import annotations

import json
from pathlib import Path
from typing import Any

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
    """Write doc as indented JSON (numpy scalars as floats), making the folder; an OSError is one line."""

    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps(doc, indent=2, default=float) + "\n")
    except OSError as exc:
        raise ArmbridgeError(f"{path}: cannot write {what}: {exc.strerror}") from None
