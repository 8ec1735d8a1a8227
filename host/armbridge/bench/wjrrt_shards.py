"""The seed loop of `bench wjrrt` as shards (armbridge.shards): one shard is one (scene, seed).

A shard runs every planner of the sweep on its scene and seed in turn, in
one worker process, as the serial loop does, so a load change on that
machine falls on all planners alike. The scene travels as its document
(Scene.to_dict, in the job's parameters, hashed into the checkpoint's
manifest); the worker rebuilds it once per process and finds its goal
configurations (deterministic: planning.soft.ik.goal_configs, seed 0), so
every worker plans on the driver's scene. Before its first run a worker
process warms its planners up (wjrrt_run.warm_up: numba compiles or loads
every jitted function on a tiny scene), so no run's budget pays for that.

What equals the serial run, and what does not:

* our planners (WJRRT, JT-RRT, Bi-RRT) draw from one numpy Generator seeded
  by the run's seed and stop at the goal or at the iteration budget: every
  field of their records but time_s is the serial run's, wherever the shard
  ran, as long as no run was stopped by the wall-clock budget T instead (a
  run that is gives whatever it reached in T on that machine);
* OMPL's planners are bounded by T only, and OMPL's generator is seeded
  once per process (planning.ompl_bridge.seed_once, STRIDE's shim alike):
  each planner object draws its seed from that process's sequence, so an
  OMPL run depends on every OMPL run before it in the same process. Its
  rows are not bit-reproducible even serially: the same command in a fresh
  process repeats them only while no OMPL run ends at T (where the draws
  stop depends on the machine's speed), and another --seeds, planner list
  or scene list moves them. On Ray, which shards share a worker process,
  and in what order, is Ray's choice, so they differ from the serial rows
  (a worker's first shard aside). Every OMPL path is still re-checked by
  our checker (bench.wjrrt_run.one_run);
* time_s (and everything read off it: the time medians, success at a budget
  t, the targets) is measured on the worker that ran the shard. On a
  cluster of unlike machines those columns mix machines. On one machine
  with N workers every run has one core to itself while N is at most the
  cores nothing else uses: the planners are single-threaded (numba njit
  kernels without parallel=True, OMPL's planners are sequential, and Ray
  runs each task with OMP_NUM_THREADS=1); with more, runs share cores and
  their times grow (docs/cluster.md).

A shard's result is three arrays (no pickles: shards.store keeps arrays
only) that encode_runs / decode_runs turn into the records of one_run and
back exactly, key order and Python types included.
"""
from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from typing import TYPE_CHECKING, Any, Optional

import numpy as np

if TYPE_CHECKING:
    from armbridge.planning.soft.scene import Scene
    from armbridge.shards import Runner, Shard

#: one_run's record, key by key in its order: (key, type). status is OMPL's only.
FIELDS: tuple[tuple[str, type], ...] = (
    ("seed", int), ("success", bool), ("planner_success", bool), ("recheck", str), ("time_s", float),
    ("iterations", int), ("nodes", int), ("track_nodes", int), ("goal_nodes", int), ("random_nodes", int),
    ("obstacle_checks", int), ("final_H", float), ("tip_error_m", float), ("clearance_min_m", float), ("status", str))
ABSENT, NONE, GIVEN = 0, 1, 2  # a field's state in a record
_NUM = [k for k, t in FIELDS if t is not str]
_TXT = [k for k, t in FIELDS if t is str]
_AT = {k: f for f, (k, _) in enumerate(FIELDS)}
_SCENES: dict[str, Scene] = {}


def encode_runs(records: Sequence[Mapping[str, Any]]) -> dict[str, np.ndarray]:
    """Records (one per planner) -> numbers (R, n) float64, texts (R, t) str, state (R, fields) int8.

    Integers are exact in float64 below 2**53 (checked); a key or a type that
    FIELDS does not name is refused, so a new field of one_run cannot be
    dropped on the way.
    """
    kinds = dict(FIELDS)
    numbers = np.zeros((len(records), len(_NUM)))
    texts = [[""] * len(_TXT) for _ in records]
    state = np.full((len(records), len(FIELDS)), ABSENT, dtype=np.int8)
    for r, rec in enumerate(records):
        for key, v in rec.items():
            if key not in kinds:
                raise ValueError(f"wjrrt shard: record field {key!r} is not in wjrrt_shards.FIELDS")
            kind = kinds[key]
            state[r, _AT[key]] = NONE if v is None else GIVEN
            if v is None:
                continue
            if type(v) is not kind:
                raise ValueError(f"wjrrt shard: field {key!r} is {type(v).__name__}, expected {kind.__name__}")
            if isinstance(v, str):
                texts[r][_TXT.index(key)] = v
            elif isinstance(v, (int, float)):  # bool is an int
                if isinstance(v, int) and abs(v) >= 2**53:
                    raise ValueError(f"wjrrt shard: field {key!r} = {v} is not exact in float64")
                numbers[r, _NUM.index(key)] = float(v)
    return {"numbers": numbers, "texts": np.array(texts, dtype=str).reshape(len(records), len(_TXT)),
            "state": state}


def decode_runs(numbers: np.ndarray, texts: np.ndarray, state: np.ndarray) -> list[dict[str, Any]]:
    """encode_runs' inverse."""
    out = []
    for r in range(state.shape[0]):
        rec: dict[str, Any] = {}
        for f, (key, kind) in enumerate(FIELDS):
            if state[r, f] == NONE:
                rec[key] = None
            elif state[r, f] == GIVEN:
                rec[key] = str(texts[r, _TXT.index(key)]) if kind is str else kind(numbers[r, _NUM.index(key)])
        out.append(rec)
    return out


def scene_of(doc: Mapping[str, Any]) -> Scene:
    """The scene of a document, built and its goal configurations found once per process."""
    from armbridge.planning.soft.scene import scene_from_dict
    from armbridge.shards.store import digest

    key = digest(doc)
    if key not in _SCENES:
        scene = scene_from_dict(dict(doc), "bench wjrrt shard")
        scene.find_goal_states()  # outside every planner's time, as the serial loop
        _SCENES[key] = scene
    return _SCENES[key]


def seed_shard(params: Mapping[str, Any], shard: Shard) -> dict[str, np.ndarray]:
    """Every planner of params on scene shard.params["scene"] at seed shard.seed, in turn."""
    from armbridge.bench.wjrrt_run import OMPL, one_run, warm_up
    from armbridge.planning import ompl_bridge

    scene = scene_of(params["scenes"][shard.params["scene"]])
    planners = list(params["planners"])
    if any(pl in OMPL for pl in planners):
        ompl_bridge.seed_once(0)  # the first seed of this process stays (module doc)
    warm_up(planners, float(params["res"]))  # once per process, before any run's budget starts
    its = params["iterations"]
    return encode_runs([one_run(scene, pl, int(shard.seed), float(params["time_limit"]),
                                None if its is None else int(its), float(params["res"])) for pl in planners])


def sweep(scenes: Sequence[Scene], seeds: int, planners: Sequence[str], time_limit: float,
          iterations: Optional[int], res: float, runner: Optional[Runner] = None,
          on_seed: Callable[[int, int, list[dict[str, Any]]], None] = lambda k, s, recs: None
          ) -> list[list[list[dict[str, Any]]]]:
    """Shards (scene k, seed s), k-major, on `runner` (None: here, serially) -> runs[k][s][planner]
    (records in planner order). on_seed(k, s, records) is called in shard order as they come in."""
    from armbridge.shards import Job, Runner, Shard

    job = Job("wjrrt", seed_shard, {"scenes": [s.to_dict() for s in scenes], "planners": list(planners),
                                    "time_limit": float(time_limit), "iterations": iterations, "res": float(res)})
    shards = [Shard(k * seeds + s, s, {"scene": k}) for k in range(len(scenes)) for s in range(seeds)]
    out: list[list[list[dict[str, Any]]]] = [[] for _ in scenes]

    def got(shard: Shard, arrays: dict[str, np.ndarray]) -> None:
        k = int(shard.params["scene"])
        recs = decode_runs(arrays["numbers"], arrays["texts"], arrays["state"])
        out[k].append(recs)
        on_seed(k, int(shard.seed), recs)

    (runner or Runner()).map(job, shards, on_result=got, label="bench wjrrt")
    return out
