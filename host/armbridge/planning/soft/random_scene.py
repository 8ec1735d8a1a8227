"""Random soft-arm scenes (2, 3 and 7 links; corridors, narrow passages, clutter), each with a known solution.

    scene = random_scene(3, "corridor", seed=7)     # a Scene, like fixed_scene("three-arm")
    scene.provenance["witness"]                     # the path that proves it solvable
    save_scene(scene, "mine.json")                  # scene.py's format; load_scene reads it back
    scenes = spec_scenes("random:3:corridor:0-9")   # what `bench wjrrt --scenes` takes
    scene = open_scene("random:3:corridor:7")       # `plan soft --env`: a spec of one seed, a file or a name

The robots are the catalog's soft2, soft3 and soft7 (the fixed scenes'
robots: their link lengths and joint limits), links 15 mm wide, the base at
the origin with a random heading. Each scene is built around a witness
(as planning/masr/random_env.py keeps its known_path): a start and a goal
configuration uniform in the joint box and one to three via configurations
(near the box's corners, or some joints at the start's values and the rest
at the goal's; of VIA_CANDIDATES draws, the one whose sweep the straight
start-goal edge leaves farthest), joined by straight joint-space edges.
The region the arm sweeps along the witness, grown by the link half-width
and a clearance c, is kept free of obstacles, so the witness keeps about c
from every obstacle:

* corridor: walls along the whole boundary of that region (simplified,
  at most MAX_WALLS segments), and around the larger areas it encloses but
  never sweeps: the arm is caged in a corridor shaped by the witness's
  motion, which folds and unfolds the arm on its way (c 6-12 mm);
* passage: two parallel walls across the workspace through the middle of
  the tip's route, perpendicular to it, with the gap the witness sweeps
  through them cut out: a slot 20-40 mm deep (c 3-8 mm);
* clutter: 8 to 16 convex polygons (fewer where they do not fit), at least
  c apart, one on the straight joint-space edge from the start to the goal,
  the others around points of the arm at random configurations (c 5-10 mm).

c is lowered where needed so that an obstacle fits between the witness and
the straight edge (BLOCK), and a candidate whose c would fall under
MIN_CLEARANCE is dropped.

A candidate is kept only when (1) our checker (space.ChainChecker at the
scene's link width) passes the witness (`path_problem`: valid start, every
edge free), so the scene is solvable, and (2) the straight edge from the
start to the goal is not free, so it is not trivially so. Otherwise the
generator draws again (MAX_TRIES). Same (links, kind, seed), same scene.
The goal is the witness's last tip point within GOAL_TOL (the fixed soft
scenes' 2 mm), with goal.q the witness's last state. "params" are the fixed
scene's of as many links (two-arm, three-arm, seven-tube), with WJRRT's
d_min and C1 lowered to half what the witness keeps (least link clearance,
least sum of link clearances), so that WJRRT's thresholds do not refuse the
only way through; "margin" (the clearance plans keep, margin.py) is the
robot's execution margin, lowered likewise to half the witness's least
clearance where that is less. The witness, c and the witness's clearance are in the
scene's provenance.
"""
from __future__ import annotations

import math
import re
from functools import lru_cache
from typing import Any

import numpy as np

from armbridge.errors import ArmbridgeError
from armbridge.planning.soft.scene import FORMAT, VERSION, Scene, fixed_scene, load_scene, scene_from_dict
from armbridge.planning.soft.margin import execution_margin
from armbridge.planning.soft.space import ChainChecker
from armbridge.robots.catalog import get_robot

KINDS = ("corridor", "passage", "clutter")
#: links -> (catalog robot, the fixed scene whose params a generated scene starts from)
ROBOTS = {2: ("soft2", "two-arm"), 3: ("soft3", "three-arm"), 7: ("soft7", "seven-tube")}
LINK_WIDTH = 0.015
GOAL_TOL = 0.002
#: kind -> clearance c (m) the witness keeps from the obstacles: drawn uniformly in this range.
CLEARANCE = {"corridor": (0.006, 0.012), "passage": (0.003, 0.008), "clutter": (0.005, 0.010)}
MAX_WALLS = 60
MAX_TRIES = 300
#: Witness candidates per try (the one whose sweep the straight start-goal edge leaves farthest is kept).
VIA_CANDIDATES = 6
#: c is at most (that distance - the link half-width - BLOCK), so that an obstacle fits between; and >= MIN.
BLOCK = 0.004
MIN_CLEARANCE = 0.004
#: Sweep sampling: the largest joint change (rad) between two arm shapes of the swept region.
SWEEP_STEP = 0.01
SPEC = "random:LINKS:KIND:SEEDS (LINKS 2, 3 or 7; KIND corridor, passage or clutter; SEEDS N or A-B)"


def _sweep(checker: ChainChecker, path: np.ndarray, step: float = SWEEP_STEP) -> np.ndarray:
    """(S, n+1, 2) the arm's points at states along path's straight edges, at most `step` rad apart."""
    shapes = []
    for a, b in zip(path[:-1], path[1:]):
        k = max(2, int(math.ceil(float(np.max(np.abs(b - a))) / step)) + 1)
        for t in np.linspace(0.0, 1.0, k):
            shapes.append(checker.points(a + t * (b - a)))
    return np.array(shapes)


def _farthest(direct: np.ndarray, shapes: np.ndarray) -> float:
    """The largest distance (m) from a point of the arm in `direct` (links sampled at 4 points) to the
    nearest link centre line of any shape in `shapes`."""
    a, b = shapes[:, :-1, :].reshape(-1, 2), shapes[:, 1:, :].reshape(-1, 2)
    t = np.linspace(0.0, 1.0, 4)[None, None, :, None]
    p = (direct[:, :-1, None, :] + t * (direct[:, 1:, None, :] - direct[:, :-1, None, :])).reshape(-1, 2)
    ab = b - a
    L2 = np.maximum(np.einsum("ij,ij->i", ab, ab), 1e-18)
    best = np.full(p.shape[0], np.inf)
    for k in range(0, a.shape[0], 512):
        A, AB, l2 = a[k:k + 512], ab[k:k + 512], L2[k:k + 512]
        ap = p[:, None, :] - A[None]
        u = np.clip(np.einsum("ijk,jk->ij", ap, AB) / l2, 0.0, 1.0)
        e = ap - u[..., None] * AB[None]
        best = np.minimum(best, np.einsum("ijk,ijk->ij", e, e).min(axis=1))
    return float(np.sqrt(best.max()))


def _region(shapes: np.ndarray, grow: float) -> Any:
    """The union of the arm's centre lines over shapes, grown by `grow` m (a shapely Polygon)."""
    import shapely  # type: ignore[import-untyped]

    geom = shapely.union_all(shapely.buffer(shapely.linestrings(shapes), grow, quad_segs=6))
    if geom.geom_type == "MultiPolygon":  # cannot happen (every shape starts at the base), but be safe
        geom = max(geom.geoms, key=lambda g: g.area)
    return geom


def _walls_of(geom: Any) -> list[np.ndarray]:
    """The 2-vertex wall segments of a (Multi)LineString."""
    parts = getattr(geom, "geoms", [geom])
    out = []
    for part in parts:
        xy = np.asarray(part.coords)
        for a, b in zip(xy[:-1], xy[1:]):
            if np.linalg.norm(b - a) > 1e-6:
                out.append(np.array([a, b]))
    return out


def _convex(rng: np.random.Generator, centre: np.ndarray, radius: float) -> np.ndarray:
    """A convex polygon around centre (which it contains): 5-9 vertices at spread angles, 0.6-1 radius out."""
    k = int(rng.integers(5, 10))
    ang = np.sort(np.linspace(0.0, 2 * math.pi, k, endpoint=False) + rng.uniform(0, 2 * math.pi / k, k))
    rad = radius * rng.uniform(0.6, 1.0, k)
    pts = centre + np.stack([rad * np.cos(ang), rad * np.sin(ang)], 1)
    from shapely.geometry import MultiPoint  # type: ignore[import-untyped]

    hull = MultiPoint(pts).convex_hull
    return np.asarray(hull.exterior.coords)[:-1] if hull.geom_type == "Polygon" else np.zeros((0, 2))


def _corridor(rng: np.random.Generator, region: Any, grow: float, c: float, reach: float, shapes: np.ndarray,
              direct: np.ndarray, workspace: np.ndarray) -> list[np.ndarray]:
    tol = c / 4
    rings = [region.exterior, *[r for r in region.interiors if r.length > 4 * c]]

    def walls_at(tol: float) -> list[np.ndarray]:
        return [w for r in rings for w in _walls_of(r.simplify(tol))]

    walls = walls_at(tol)
    while len(walls) > MAX_WALLS and tol < c / 2:
        tol *= 1.25
        walls = walls_at(tol)
    return walls


def _passage(rng: np.random.Generator, region: Any, grow: float, c: float, reach: float, shapes: np.ndarray,
             direct: np.ndarray, workspace: np.ndarray) -> list[np.ndarray]:
    from shapely.geometry import LineString  # type: ignore[import-untyped]

    tips = shapes[:, -1, :]
    seg = np.linalg.norm(np.diff(tips, axis=0), axis=1)
    along = np.concatenate([[0.0], np.cumsum(seg)])
    mid = int(np.searchsorted(along, along[-1] * rng.uniform(0.35, 0.65)))
    mid = min(max(mid, 1), len(tips) - 2)
    d = tips[mid + 1] - tips[mid - 1]
    if np.linalg.norm(d) < 1e-9:
        return []
    d = d / np.linalg.norm(d)
    normal = np.array([-d[1], d[0]])
    depth = rng.uniform(0.02, 0.04)
    base = shapes[0, 0]
    walls: list[np.ndarray] = []
    for off in (-depth / 2, depth / 2):
        p = tips[mid] + off * d
        span = 1.3 * reach + float(np.linalg.norm(p - base))
        line = LineString([p - span * normal, p + span * normal])
        walls += _walls_of(line.difference(region))
    return walls


def _clutter(rng: np.random.Generator, region: Any, grow: float, c: float, reach: float, shapes: np.ndarray,
             direct: np.ndarray, workspace: np.ndarray) -> list[np.ndarray]:
    import shapely  # type: ignore[import-untyped]
    from shapely.geometry import Polygon  # type: ignore[import-untyped]

    count = int(rng.integers(8, 17))
    # the blocker: around the point the straight start-goal edge sweeps farthest from the witness's region
    pts = direct[:, 1:, :].reshape(-1, 2)
    far = shapely.distance(region, shapely.points(pts))
    at = int(np.argmax(far))
    if far[at] < 0.004:
        return []
    polys = [_convex(rng, pts[at], min(0.95 * float(far[at]), reach * rng.uniform(0.04, 0.10)))]
    taken: Any = Polygon(polys[0])
    # the others around points of the arm at random configurations: where the arm can go
    reachable = workspace[:, 1:, :].reshape(-1, 2)
    for _ in range(count - 1):
        for _ in range(40):
            verts = _convex(rng, reachable[rng.integers(len(reachable))], reach * rng.uniform(0.04, 0.10))
            if len(verts) < 3:
                continue
            poly = Polygon(verts)
            if not poly.is_valid or poly.intersects(region) or poly.distance(taken) < c:
                continue
            polys.append(verts)
            taken = taken.union(poly)
            break
    return polys


_BUILD = {"corridor": _corridor, "passage": _passage, "clutter": _clutter}


def _check(links: Any, kind: Any, seed: Any) -> tuple[int, str, int]:
    if isinstance(links, bool) or not isinstance(links, (int, np.integer)) or int(links) not in ROBOTS:
        raise ArmbridgeError(f"random scene: links = {links!r}; use 2, 3 or 7")
    if kind not in KINDS:
        raise ArmbridgeError(f"random scene: kind {kind!r} unknown; use {', '.join(KINDS)}")
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ArmbridgeError(f"random scene: seed = {seed!r}; use a whole number >= 0")
    return int(links), str(kind), int(seed)


def random_scene(links: int, kind: str = "corridor", seed: int = 0) -> Scene:
    """A random scene (module doc) of `links` links (2, 3, 7) and `kind` (KINDS); deterministic per seed.

    The Scene is shared (cached): copy it before changing it."""
    return _random_scene(*_check(links, kind, seed))


@lru_cache(maxsize=256)
def _random_scene(links: int, kind: str, seed: int) -> Scene:
    robot_name, like = ROBOTS[links]
    robot = get_robot(robot_name)
    params = dict(fixed_scene(like).params)
    rng = np.random.default_rng([seed, links, KINDS.index(kind), 24])
    lo, hi = np.asarray(robot.q_min, float), np.asarray(robot.q_max, float)
    reach = float(np.sum(robot.link_lengths))
    for attempt in range(MAX_TRIES):
        heading = float(rng.uniform(-math.pi, math.pi))
        base = np.array([0.0, 0.0, heading])
        free = ChainChecker.create(robot, [], base=base, link_width=LINK_WIDTH)
        ends = lo + rng.random((2, links)) * (hi - lo)
        if np.linalg.norm(free.tip(ends[0]) - free.tip(ends[1])) < 0.2 * reach:
            continue
        direct, coarse = _sweep(free, ends), _sweep(free, ends, 0.03)
        best, far = None, -1.0
        for _ in range(VIA_CANDIDATES):  # the witness whose sweep leaves the straight edge's farthest
            vias = int(rng.integers(1, 4))
            # vias near the box's corners (joints at their limits: the arm folds or stretches on the way), or
            # a joint at the start's value and the others at the goal's (the edge taken one joint at a time)
            corner = np.where(rng.random((vias, links)) < 0.5, lo, hi)
            stair = np.where(rng.random((vias, links)) < 0.5, ends[0], ends[1])
            via = np.where(rng.random((vias, 1)) < 0.5, corner, stair)
            via = np.clip(via + rng.uniform(-0.1, 0.1, (vias, links)) * (hi - lo), lo, hi)
            cand = np.vstack([ends[0], via, ends[1]])
            if free.path_problem(cand) is not None:  # self-collision along the witness
                continue
            f = _farthest(coarse, _sweep(free, cand, 0.03))
            if f > far:
                best, far = cand, f
        if best is None:
            continue
        path = best
        lo_c, hi_c = CLEARANCE[kind]
        c = min(float(rng.uniform(lo_c, hi_c)), far - 0.5 * LINK_WIDTH - BLOCK)
        if c < MIN_CLEARANCE:
            continue
        grow = 0.5 * LINK_WIDTH + c
        shapes = _sweep(free, path)
        region = _region(shapes, grow)
        workspace = np.array([free.points(q) for q in lo + rng.random((64, links)) * (hi - lo)])
        obstacles = _BUILD[kind](rng, region, grow, c, reach, shapes, direct, workspace)
        if not obstacles:
            continue
        checker = ChainChecker.create(robot, obstacles, base=base, link_width=LINK_WIDTH)
        if checker.path_problem(path) is not None or checker.motion_valid(path[0], path[-1]):
            continue
        cl = np.array([checker.link_clearance(q) for q in _dense(path)])
        least, least_sum = float(cl.min()), float(cl.sum(axis=1).min())
        if not least > 0:
            continue
        p = dict(params)
        p["d_min"] = min(float(p.get("d_min", 0.0)), round(0.5 * least, 4))
        p["C1"] = min(float(p.get("C1", 0.0)), round(0.5 * least_sum, 4))
        doc = {
            "format": FORMAT, "version": VERSION, "name": f"random-{links}-{kind}-{seed}",
            "description": f"random {kind} for {robot_name} (armbridge.planning.soft.random_scene, seed {seed}): "
                           f"{len(obstacles)} {'walls' if kind != 'clutter' else 'polygons'}, a witness path of "
                           f"{len(path) - 1} edges keeps {least * 1000:.1f} mm",
            "robot": robot_name, "base": base.tolist(), "link_width": LINK_WIDTH,
            "margin": min(round(execution_margin(robot), 6), round(0.5 * least, 4)),
            "obstacles": [np.asarray(o, float).tolist() for o in obstacles],
            "start": path[0].tolist(),
            "goal": {"point": free.tip(path[-1]).tolist(), "tol": GOAL_TOL, "q": path[-1].tolist()},
            "params": p,
            "provenance": {"tool": "armbridge.planning.soft.random_scene", "links": links, "kind": kind,
                           "seed": seed, "attempt": attempt, "clearance_m": round(c, 6),
                           "witness_clearance_m": least, "witness": path.tolist()},
        }
        try:
            return scene_from_dict(doc, f"random_scene({links}, {kind!r}, {seed})")
        except ArmbridgeError:
            continue
    raise ArmbridgeError(f"random scene: no {kind} for {links} links after {MAX_TRIES} tries (seed {seed})")


def _dense(path: np.ndarray, step: float = 0.02) -> list[np.ndarray]:
    out = []
    for a, b in zip(path[:-1], path[1:]):
        k = max(2, int(math.ceil(float(np.max(np.abs(b - a))) / step)) + 1)
        out += [a + t * (b - a) for t in np.linspace(0.0, 1.0, k)]
    return out


_SPEC = re.compile(r"random:([^:]*):([^:]*):([^:]*)")


def parse_spec(spec: str) -> list[tuple[int, str, int]]:
    """'random:3:corridor:0-9' -> [(3, 'corridor', 0), ..., (3, 'corridor', 9)]; one clear error line else."""
    m = _SPEC.fullmatch(spec.strip())
    if not m:
        raise ArmbridgeError(f"scene {spec!r}: a generated scene is {SPEC}")
    links_s, kind, seeds_s = m.groups()
    if not links_s.isdigit() or int(links_s) not in ROBOTS:
        raise ArmbridgeError(f"scene {spec!r}: LINKS {links_s!r} must be 2, 3 or 7 ({SPEC})")
    if kind not in KINDS:
        raise ArmbridgeError(f"scene {spec!r}: KIND {kind!r} must be corridor, passage or clutter ({SPEC})")
    rng = re.fullmatch(r"(\d+)(?:-(\d+))?", seeds_s)
    if not rng or (rng.group(2) is not None and int(rng.group(2)) < int(rng.group(1))):
        raise ArmbridgeError(f"scene {spec!r}: SEEDS {seeds_s!r} must be N or A-B with A <= B ({SPEC})")
    a = int(rng.group(1))
    b = a if rng.group(2) is None else int(rng.group(2))
    if b - a >= 10_000:
        raise ArmbridgeError(f"scene {spec!r}: at most 10000 seeds per spec")
    return [(int(links_s), kind, s) for s in range(a, b + 1)]


def is_spec(text: Any) -> bool:
    return isinstance(text, str) and text.strip().startswith("random:")


def spec_scenes(spec: str) -> list[Scene]:
    """The scenes of a spec (parse_spec), generated in seed order."""
    return [random_scene(*t) for t in parse_spec(spec)]


def open_scene(text: str) -> Scene:
    """One scene: a generated one (random:LINKS:KIND:SEED, one seed), else scene.load_scene's (a scene file
    or a fixed scene's name); what `armbridge plan soft --env` takes."""
    from pathlib import Path

    if is_spec(text) and not Path(text).exists():
        one = parse_spec(text)
        if len(one) != 1:
            raise ArmbridgeError(f"scene {text!r}: one scene is random:LINKS:KIND:SEED (one seed, not a range)")
        return random_scene(*one[0])
    return load_scene(text)
