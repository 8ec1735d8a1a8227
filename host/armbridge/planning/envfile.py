"""Reading the planning environment files (the MASR's armbridge-masr-env, the chains' armbridge-chain-env).

Both formats are one JSON object with a format tag, a version, a robot,
polygon obstacles, a start and a goal; the loaders (planning.masr.environment,
planning.soft.scene) check their own fields with these shared pieces and stop
at the first problem with one ArmbridgeError "FILE: what is wrong", naming the
field (`obstacles[2][1]`, `goal.q[3]`) and, for numbers, the allowed range.
"""
from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from armbridge.errors import ArmbridgeError


def fmt(x: float) -> str:
    """A number in messages and files: at most 4 decimals, no trailing zeros."""
    s = f"{x:.4f}".rstrip("0").rstrip(".")
    return "0" if s in ("-0", "") else s


class Ctx:
    """Where a document came from; err() prefixes messages with it. kind names the document in messages."""

    def __init__(self, source: Any, kind: str = "environment"):
        self.name = str(source) if source is not None else f"<{kind}>"
        self.kind = kind
        self.given = source is not None

    def err(self, msg: str) -> ArmbridgeError:
        return ArmbridgeError(f"{self.name}: {msg}")


def _shown(x: Any) -> str:
    try:
        return json.dumps(x)
    except (TypeError, ValueError):
        return type(x).__name__


def number(x: Any, where: str, ctx: Ctx) -> float:
    """A finite number (not a bool)."""
    if isinstance(x, bool) or not isinstance(x, (int, float, np.floating, np.integer)):
        raise ctx.err(f"{where} must be a number, got {_shown(x)}")
    if not math.isfinite(float(x)):
        raise ctx.err(f"{where} is {x}: {ctx.kind}s hold finite numbers only")
    return float(x)


def vector(v: Any, n: int, where: str, ctx: Ctx) -> np.ndarray:
    """A list of exactly n finite numbers."""
    if not isinstance(v, (list, tuple, np.ndarray)):
        raise ctx.err(f"{where} must be a list of {n} numbers, got {type(v).__name__}")
    if len(v) != n:
        raise ctx.err(f"{where} must have {n} values, got {len(v)}")
    return np.array([number(x, f"{where}[{i}]", ctx) for i, x in enumerate(v)])


def obstacle(v: Any, i: int, ctx: Ctx, walls: bool = False) -> np.ndarray:
    """obstacles[i]: a simple polygon (>= 3 vertices, area > 0; a repeated closing vertex is dropped) or,
    where walls are allowed, a wall segment (2 distinct vertices)."""
    import shapely  # type: ignore[import-untyped]
    from shapely.geometry import Polygon  # type: ignore[import-untyped]

    where = f"obstacles[{i}]"
    least = 2 if walls else 3
    if not isinstance(v, (list, tuple, np.ndarray)) or len(v) < least:
        what = "2 for a wall segment, at least 3 for a polygon" if walls else "at least 3"
        raise ctx.err(f"{where} must be a list of {what} [x, y] vertices")
    pts = np.array([vector(p, 2, f"{where}[{k}]", ctx) for k, p in enumerate(v)])
    if len(pts) == 2:
        if np.allclose(pts[0], pts[1]):
            raise ctx.err(f"{where} is a wall of zero length: its two vertices are the same point")
        return pts
    if len(pts) > 3 and np.allclose(pts[0], pts[-1]):
        pts = pts[:-1]  # a closed ring: drop the repeated vertex
    poly = Polygon(pts)
    if not (shapely.is_valid(poly) and poly.exterior.is_simple):
        reason = shapely.is_valid_reason(poly)
        at = ""
        if reason.startswith("Self-intersection"):
            xy = reason[reason.find("[") + 1: reason.find("]")].split()
            at = f" at ({fmt(float(xy[0]))}, {fmt(float(xy[1]))})" if len(xy) == 2 else ""
        raise ctx.err(f"{where} is self-intersecting{at}: its edges cross ({reason}); list the vertices in order "
                      "around the polygon")
    if poly.area <= 1e-12:
        raise ctx.err(f"{where} has zero area")
    return pts


def header(doc: Any, ctx: Ctx, form: str, version: int, top: Sequence[str], required: Sequence[str],
           default_name: str) -> tuple[str, str]:
    """Check the object, its format tag, version, that every field is known and the required ones are there;
    returns (name, description) (name defaults to the file's stem, or default_name without a file)."""
    if not isinstance(doc, dict):
        raise ctx.err(f"a{'n' if ctx.kind[0] in 'aeiou' else ''} {ctx.kind} is a JSON object")
    if doc.get("format") != form:
        raise ctx.err(f'format is {json.dumps(doc.get("format"))}, expected "{form}"')
    if doc.get("version") != version or isinstance(doc.get("version"), bool):
        raise ctx.err(f"unsupported version {json.dumps(doc.get('version'))} (this armbridge reads version {version})")
    for key in doc:
        if key not in top:
            raise ctx.err(f'unknown field "{key}" (allowed: {", ".join(top)})')
    for key in required:
        if key not in doc:
            raise ctx.err(f'missing field "{key}"')
    name = doc.get("name", Path(ctx.name).stem if ctx.given else default_name)
    if not isinstance(name, str) or not name:
        raise ctx.err("name must be a non-empty string")
    description = doc.get("description", "")
    if not isinstance(description, str):
        raise ctx.err("description must be a string")
    return name, description
