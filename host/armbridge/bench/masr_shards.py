"""The trial loops of `bench masr-plan` (Fig. 5, Fig. 7) as shards (armbridge.shards).

A shard is one environment and a list of (p_c, seed) runs of it: in Fig. 5 one
random environment (seed e) with every planner at seed e, in Fig. 7 one of
E1-E3, one planner, FIG7_CHUNK trial seeds. Each run's result is a function
of the environment, p_c, the seed and the goal IK model only, so the shards
may run anywhere, in any order, and give the serial loop's costs exactly.
(The seconds each run took are measurements of where it ran: reported, never
compared.)

A run's best-cost curve (best tau after every iteration, inf before the first
path) only falls, in a few steps: a shard stores the steps (iteration, value)
and decode_curves rebuilds the curves exactly, so a Fig. 7 trial of 12,000
iterations is a few hundred bytes on disk, not 96 kB.
"""
from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from armbridge.shards import Runner, Shard

FIG7_CHUNK = 10  # Fig. 7 trials per shard: about a minute of work at the full size's 12,000 iterations
_IK: dict[str, Any] = {}


def run_planner(env: Any, p_c: float, iterations: int, seed: int, goal_ik: Callable, checker: Any) -> Any:
    """MASR-RRT* with goal biasing p_c (p_c = 0: the baseline RRT*), one run."""
    from armbridge.planning.masr import rrt_star

    if p_c == 0:
        return rrt_star.plan(env, planner="rrt*", iterations=iterations, seed=seed, checker=checker)
    return rrt_star.plan(env, planner="masr-rrt*", iterations=iterations, goal_ik=goal_ik, p_c=p_c, seed=seed,
                         checker=checker)

def card_ref(card: Path) -> str:
    """How a shard names the goal IK card: "models:<path>" inside the shipped models (found on every
    node where armbridge is installed), else the absolute path (which every node must then see)."""
    from armbridge import resources

    path, models = Path(card).resolve(), resources.models_dir().resolve()
    return f"models:{path.relative_to(models)}" if path.is_relative_to(models) else str(path)


def goal_ik(card: str | Path) -> Callable[[np.ndarray, np.ndarray], np.ndarray]:
    """The planners' goal IK from a model card (a path or card_ref), loaded once per process
    (a Ray worker runs many shards)."""
    key = str(card)
    if key not in _IK:
        from armbridge import resources
        from armbridge.ik.masr_ik import MasrIK

        path = resources.models_dir() / key[7:] if key.startswith("models:") else Path(key)
        _IK[key] = MasrIK.load(path)
    ik = _IK[key]

    def solve(x_goal: np.ndarray, q_c: np.ndarray) -> np.ndarray:
        return ik.solve(x_goal, q_c, refine=True, sparsify=False)  # as planning.command.resolve_goal_ik

    return solve


def encode_curves(curves: np.ndarray) -> dict[str, np.ndarray]:
    """(R, I) best-cost curves -> their steps: at (iteration of each change), value, start (R + 1 offsets)."""
    c = np.asarray(curves, dtype=np.float64)
    change = np.ones(c.shape, dtype=bool)
    change[:, 1:] = c[:, 1:] != c[:, :-1]  # inf == inf: no step while no path is found
    rows, at = np.nonzero(change)
    start = np.searchsorted(rows, np.arange(c.shape[0] + 1))
    return {"at": at.astype(np.int64), "value": c[rows, at], "start": start.astype(np.int64)}


def decode_curves(at: np.ndarray, value: np.ndarray, start: np.ndarray, iterations: int) -> np.ndarray:
    """encode_curves' inverse: the (R, I) curves."""
    out = np.empty((start.size - 1, iterations))
    for r in range(start.size - 1):
        a, v = at[start[r] : start[r + 1]], value[start[r] : start[r + 1]]
        out[r] = np.repeat(v, np.diff(np.append(a, iterations)))
    return out


def trials_shard(params: Mapping[str, Any], shard: Shard) -> dict[str, np.ndarray]:
    """The runs of one shard: params card, iterations; shard.params env (E1-E3 or a random
    environment's seed) and runs [(p_c, seed), ...]. Curves in run order, seconds per run."""
    import time

    from armbridge.planning.masr.environment import fixed_environment
    from armbridge.planning.masr.random_env import random_environment
    from armbridge.robots import get_masr

    its = int(params["iterations"])
    where = shard.params["env"]
    t0 = time.perf_counter()
    env = fixed_environment(where) if isinstance(where, str) else random_environment(get_masr("masr5"), seed=where)
    env_s = time.perf_counter() - t0
    chk = env.checker()
    ik = goal_ik(params["card"])
    runs = [run_planner(env, float(p), its, int(s), ik, chk) for p, s in shard.params["runs"]]
    return {**encode_curves(np.array([r.best_costs for r in runs]).reshape(len(runs), its)),
            "time_s": np.array([r.time_s for r in runs]), "environment_s": np.asarray(env_s)}


def sweep(name: str, card: Path, iterations: int, groups: Sequence[tuple[Any, Sequence[tuple[float, int]]]],
          runner: Runner | None) -> list[tuple[np.ndarray, np.ndarray, float]]:
    """Run the groups (environment, runs) as shards of job `name`: per group (curves (R, I),
    seconds (R,), environment generation s), in group order."""
    from armbridge.ik.export import sha256
    from armbridge.shards import Job, Runner, Shard

    job = Job(name, trials_shard, {"card": card_ref(card), "card_sha256": sha256(Path(card)),
                                   "iterations": int(iterations)})
    shards = [Shard(i, [int(s) for _, s in runs], {"env": env, "runs": [[float(p), int(s)] for p, s in runs]})
              for i, (env, runs) in enumerate(groups)]
    out = (runner or Runner()).map(job, shards, label=f"masr-plan {name}")
    return [(decode_curves(r["at"], r["value"], r["start"], iterations), r["time_s"], float(r["environment_s"]))
            for r in out]
