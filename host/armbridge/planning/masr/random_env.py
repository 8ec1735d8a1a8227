"""Random MASR environments as in section V-C of the masr paper, each with a known solution.

    env = random_environment(MASR5, seed=3)
    env.known_path     # the MASR-RRT* path that verified it
"""
from __future__ import annotations

import math
from functools import lru_cache
from typing import Optional

import numpy as np

from armbridge.errors import ArmbridgeError
from armbridge.ik import masr_dls
from armbridge.planning.masr import rrt_star
from armbridge.planning.masr.collision import CollisionChecker
from armbridge.planning.masr.environment import E_P, E_PHI, FORMAT, VERSION, Environment, environment_from_dict
from armbridge.robots.catalog import get_masr, is_registered
from armbridge.robots.masr import MasrArm


@lru_cache(maxsize=8)
def workspace_grid(arm: MasrArm, cell: float = 0.01, samples: int = 200_000, seed: int = 0) -> np.ndarray:
    """Centres (m, 2) of the grid cells the arm can reach (any point on any link, i.e. any MA position)."""
    rng = np.random.default_rng(seed)
    tb = arm.theta_b
    q = np.concatenate([rng.uniform(-tb, tb, (samples, arm.n)), np.zeros((samples, 1))], 1)
    pts = arm.joint_points(q)  # (S, n+1, 2)
    t = rng.random((samples, arm.n, 1))
    on_links = pts[:, :-1] + t * (pts[:, 1:] - pts[:, :-1])
    allp = np.concatenate([pts.reshape(-1, 2), on_links.reshape(-1, 2)])
    L = arm.total_length
    m = int(math.ceil(2 * L / cell)) + 1
    idx = np.clip(np.floor((allp + L) / cell).astype(int), 0, m - 1)
    grid = np.zeros((m, m), bool)
    grid[idx[:, 0], idx[:, 1]] = True
    ii, jj = np.nonzero(grid)
    return np.stack([ii * cell - L + cell / 2, jj * cell - L + cell / 2], 1)


def _star_polygon(rng: np.random.Generator, center: np.ndarray, radius: float) -> np.ndarray:
    k = int(rng.integers(3, 8))
    ang = np.sort(rng.uniform(0, 2 * np.pi, k))
    # spread the angles a little so the polygon is not a sliver
    ang = np.sort((ang + np.linspace(0, 2 * np.pi, k, endpoint=False)) / 2 + rng.uniform(0, np.pi))
    rad = radius * rng.uniform(0.6, 1.0, k)
    return center + np.stack([rad * np.cos(ang), rad * np.sin(ang)], 1)


def random_environment(arm: MasrArm | None = None, seed: int = 0, *, max_obstacles: int = 4,
                       max_coverage: float = 0.30, name: Optional[str] = None, e_p: float = E_P,
                       e_phi: float = E_PHI, verify_iterations: int = 3000, max_tries: int = 200) -> Environment:
    """A random environment as in section V-C, with a known solution.

    The start and goal configurations are uniform in C_f (their MA positions
    at least 0.15 m apart); the goal pose is f(q_goal). One to max_obstacles
    random star-shaped polygons, disjoint, at least 5 cm from the base and
    clear of the start and goal configurations, cover a random fraction of up
    to max_coverage of the workspace (the area the arm can reach, a 1 cm grid).
    A candidate is kept only if MASR-RRT* (numeric DLS goal IK,
    verify_iterations iterations) finds a path; that path is stored as
    known_path, so every environment has a known solution.
    """
    import shapely  # type: ignore[import-untyped]
    from shapely.geometry import Polygon  # type: ignore[import-untyped]

    arm = arm if arm is not None else get_masr("masr5")
    rng = np.random.default_rng(seed)
    tb = arm.theta_b
    ws = workspace_grid(arm)
    ws_area = ws.shape[0] * 0.01 ** 2
    ik = masr_dls.goal_ik(arm, e_p=e_p, e_phi=e_phi)

    def rand_q() -> np.ndarray:
        return np.concatenate([rng.uniform(-tb, tb), [rng.uniform(0, arm.total_length)]])

    for _ in range(max_tries):
        q0, qg = rand_q(), rand_q()
        if np.linalg.norm(arm.ma_point(q0) - arm.ma_point(qg)) < 0.15:
            continue
        k = int(rng.integers(1, max_obstacles + 1))
        coverage = rng.uniform(0.0, 1.0) * max_coverage
        polys: list[np.ndarray] = []
        union = None
        for _p in range(k):
            target = coverage * ws_area / k
            for _t in range(30):
                c = ws[rng.integers(ws.shape[0])]
                radius = math.sqrt(target / math.pi) * rng.uniform(0.8, 1.25)
                verts = _star_polygon(rng, c, radius)
                poly = Polygon(verts)
                if not poly.is_valid or poly.distance(shapely.Point(0, 0)) < 0.05 or (
                        union is not None and poly.intersects(union)):
                    target *= 0.9
                    continue
                chk = CollisionChecker.create(arm, [verts])
                if not np.all(chk.free(np.stack([q0, qg]))):
                    target *= 0.9
                    continue
                polys.append(verts)
                union = poly if union is None else union.union(poly)
                break
        if not polys:
            continue
        cov = float(shapely.contains_xy(union, ws[:, 0], ws[:, 1]).mean())
        if cov > max_coverage:
            continue
        doc = {
            "format": FORMAT, "version": VERSION, "name": name or f"random-{seed}",
            "description": f"random environment (section V-C), seed {seed}, {len(polys)} obstacles covering "
                           f"{cov * 100:.1f}% of the workspace",
            "robot": arm.name if is_registered(arm) else arm.to_dict(),
            "obstacles": [p.tolist() for p in polys],
            "margin": 0.0,  # Fig. 5 as the paper ran it: its check, half the link width
            "start": q0.tolist(),
            "goal": {"pose": arm.fk(qg).tolist(), "q": qg.tolist(), "e_p": e_p, "e_phi": e_phi},
            "provenance": {"tool": "armbridge.planning.random_environment", "seed": seed, "coverage": cov},
        }
        try:
            env = environment_from_dict(doc)
        except ArmbridgeError:
            continue
        res = rrt_star.plan(env, planner="masr-rrt*", iterations=verify_iterations, goal_ik=ik, seed=seed)
        if res.path is None:
            continue
        env.known_path = res.path
        return env
    raise ArmbridgeError(f"random_environment: no solvable environment after {max_tries} tries (seed {seed})")
