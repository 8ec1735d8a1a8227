"""A board's constants read as data: its MicroPython config module, or its C header.

Nothing is executed. A MicroPython config (firmware/*/config.py) is a module of
constants: its top-level assignments of numbers, strings, tuples, lists and
dicts, with arithmetic on them and names of earlier constants, are evaluated
here from the source's syntax tree; any other statement is an error naming the
file and the line, so a config that grows code is noticed rather than run on
the host. A C firmware's constants are the `#define`s of its config header
whose value is an integer, a string or a brace list (nested lists become
tuples); LIMITS_MRAD ((min, max) per joint) is derived from
LIM_MIN_MRAD/LIM_MAX_MRAD when the header has them, so every reader sees the
limits the firmware enforces under one name.
"""
from __future__ import annotations

import ast
import operator
import re
import types
from pathlib import Path
from typing import Any

from armbridge.errors import ArmbridgeError

_BINOPS: dict[type, Any] = {ast.Add: operator.add, ast.Sub: operator.sub, ast.Mult: operator.mul, ast.Div: operator.truediv,
           ast.FloorDiv: operator.floordiv, ast.Mod: operator.mod, ast.Pow: operator.pow,
           ast.LShift: operator.lshift, ast.RShift: operator.rshift, ast.BitOr: operator.or_,
           ast.BitAnd: operator.and_}
_UNARY: dict[type, Any] = {ast.USub: operator.neg, ast.UAdd: operator.pos, ast.Invert: operator.invert}


def read_micropython_config(path: Path, constants_only: bool = True) -> types.SimpleNamespace:
    """The constants of a MicroPython config module (module docstring). `constants_only`
    False: statements other than constants are passed over (a generated table such as
    protodef.py, whose const() fallback is a try block), not refused."""
    try:
        tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    except FileNotFoundError:
        raise ArmbridgeError(f"the board's constants are read from {path}, which is missing") from None
    except SyntaxError as exc:
        raise ArmbridgeError(f"{path}, line {exc.lineno}: not Python: {exc.msg}") from None
    found: dict[str, Any] = {}
    for node in tree.body:
        if isinstance(node, ast.Expr) and isinstance(node.value, ast.Constant):
            continue  # a docstring
        if isinstance(node, (ast.Import, ast.ImportFrom)) and all(a.name in ("const", "micropython")
                                                                  for a in node.names):
            continue  # from micropython import const
        if isinstance(node, ast.Assign):
            targets, expr = node.targets, node.value
        elif isinstance(node, ast.AnnAssign) and node.value is not None:
            targets, expr = [node.target], node.value
        else:
            targets, expr = [], None
        names = [t.id for t in targets if isinstance(t, ast.Name)]
        if (expr is None or not names or len(names) != len(targets)) and not constants_only:
            continue
        if expr is None or not names or len(names) != len(targets):
            raise ArmbridgeError(f"{path}, line {node.lineno}: a config holds constants only "
                                 f"(NAME = value), not {type(node).__name__}")
        value = _value(expr, found, path)
        for name in names:
            found[name] = value
    found["__file__"] = str(path)  # where it was read from (a HAL finds its firmware folder by it)
    return types.SimpleNamespace(**found)


def _value(node: ast.expr, names: dict[str, Any], path: Path) -> Any:
    def ev(n: ast.expr) -> Any:
        if isinstance(n, ast.Constant):
            return n.value
        if isinstance(n, (ast.Tuple, ast.List)):
            items = [ev(x) for x in n.elts]
            return tuple(items) if isinstance(n, ast.Tuple) else items
        if isinstance(n, ast.Dict):
            return {ev(k): ev(v) for k, v in zip(n.keys, n.values)}  # type: ignore[arg-type]
        if isinstance(n, ast.Name) and n.id in names:
            return names[n.id]
        if isinstance(n, ast.BinOp) and type(n.op) in _BINOPS:
            return _BINOPS[type(n.op)](ev(n.left), ev(n.right))
        if isinstance(n, ast.UnaryOp) and type(n.op) in _UNARY:
            return _UNARY[type(n.op)](ev(n.operand))
        if isinstance(n, ast.Call) and isinstance(n.func, ast.Name) and n.func.id == "const" and len(n.args) == 1:
            return ev(n.args[0])
        raise ArmbridgeError(f"{path}, line {n.lineno}: a config value must be a constant, not "
                             f"{ast.unparse(n)!r}")

    return ev(node)


_DEFINE = re.compile(r"^\s*#define\s+([A-Z_][A-Z0-9_]*)\s+(.+)$")


def _c_value(text: str) -> Any:
    text = re.sub(r"/\*.*?\*/|//.*$", "", text).strip()
    if text.startswith('"') and text.endswith('"'):
        return text[1:-1]
    if text.startswith("{"):
        try:
            return ast.literal_eval(re.sub(r"(\d)[uUlL]+\b", r"\1", text).replace("{", "(").replace("}", ",)"))
        except (ValueError, SyntaxError):
            return None
    m = re.fullmatch(r"(-?(?:0x[0-9a-fA-F]+|\d+))[uUlL]*", text)
    return int(m.group(1), 0) if m else None


def read_config_h(path: Path) -> types.SimpleNamespace:
    """The `#define`s of a C firmware's config header (module docstring)."""
    if not path.is_file():
        raise ArmbridgeError(f"the firmware's constants are read from {path}, which is missing")
    found: dict[str, Any] = {}
    for line in path.read_text(encoding="utf-8", errors="replace").splitlines():
        m = _DEFINE.match(line)
        if m:
            v = _c_value(m.group(2))
            if v is not None:
                found[m.group(1)] = v
    if "LIM_MIN_MRAD" in found and "LIM_MAX_MRAD" in found:
        found["LIMITS_MRAD"] = tuple(zip(found["LIM_MIN_MRAD"], found["LIM_MAX_MRAD"]))
    if "N_JOINTS" not in found:
        raise ArmbridgeError(f"{path} defines no N_JOINTS")
    return types.SimpleNamespace(**found)
