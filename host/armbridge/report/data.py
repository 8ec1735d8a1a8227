"""A run's recording read back (rerun-sdk 0.41's `rerun.chunk.RrdReader`): what `armbridge report`
draws and counts, from the .rrd alone.

The entities are those `telemetry.recording` writes (its docstring lists them): the joints'
measured and set-point series, the arm over time, the plan's path and waypoints, the measured
tip trace, obstacles and a soft plan's planned tip path, the board's own columns, the event and
error logs, the plan's text and, since the summary went into the recording, the run's summary
(`run/summary`). Whatever a recording lacks is listed in `RunData.missing`, in words.

Every failure to read is one ArmbridgeError line naming the file: no such file, not a Rerun
recording (its first bytes), empty, unreadable, or holding nothing armbridge wrote.
"""
from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from armbridge.errors import ArmbridgeError
from armbridge.telemetry.recording import SUMMARY_ENTITY, TIMELINE
from armbridge.telemetry.rrdfile import check_rrd

Series = tuple[np.ndarray, np.ndarray]  # board time (s), values


@dataclass
class RunData:
    """What a recording holds, as numpy arrays and text."""

    path: Path
    summary: dict | None = None  # run/summary: the run's `--json` document
    plan_info: str | None = None  # plan/info: the plan's source, robot, waypoints
    joint_names: list[str] = field(default_factory=list)
    joints: dict[str, dict[str, Series]] = field(default_factory=dict)  # joint -> q/target/error/effort
    series: dict[str, Series] = field(default_factory=dict)  # board/done, ma/*, pump/*
    strips: dict[str, list[np.ndarray]] = field(default_factory=dict)  # static line strips, entity -> strips
    points: dict[str, np.ndarray] = field(default_factory=dict)  # static points (plan/waypoints)
    arm: dict[str, tuple[np.ndarray, list]] = field(default_factory=dict)  # arm/links, arm/target: t, strips
    drawing_trace: list[np.ndarray] = field(default_factory=list)  # drawing/trace: the last trace logged
    events: list[tuple[float, str, str]] = field(default_factory=list)  # t, level, text
    errors: list[tuple[float, str, str]] = field(default_factory=list)
    damaged: str | None = None  # the reader's error where the file ends early (a cut or damaged file)
    no_footer: bool = False  # no footer: closed by nobody (a run killed mid-way), or written by an older rerun

    @property
    def robot(self) -> str | None:
        if self.summary and self.summary.get("robot"):
            return str(self.summary["robot"])
        for line in (self.plan_info or "").splitlines():
            if line.startswith("robot: "):
                return line[len("robot: "):].strip()
        return None

    @property
    def dim(self) -> int:
        """2 or 3: the space the arm was drawn in."""
        for strips in self.strips.values():
            if strips:
                return int(strips[0].shape[1])
        return 2

    @property
    def missing(self) -> list[str]:
        """What this recording does not hold, one phrase each."""
        out = []
        if self.summary is None:
            out.append("the run's summary (link statistics, tracking, goal): the recording predates "
                       "`run/summary` or was not written by `armbridge run`; its `--json` file has it")
        if not self.joints:
            out.append("telemetry: no joint samples")
        if "plan/path" not in self.strips:
            out.append("the plan (no plan/path)")
        if self.damaged:
            out.append(f"the end of the file (read up to a damaged or cut chunk: {self.damaged})")
        elif self.no_footer:
            out.append("the file's footer: it was cut short (the run did not close it) or written by an older "
                       "rerun; what could be read is shown")
        return out

    def time_span(self) -> tuple[float, float] | None:
        ts = [s[0] for j in self.joints.values() for s in j.values() if len(s[0])]
        if not ts:
            return None
        return float(min(t[0] for t in ts)), float(max(t[-1] for t in ts))


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    return text[0] if text else type(exc).__name__


def _times(rb) -> np.ndarray | None:
    if TIMELINE not in rb.schema.names:
        return None
    ns = np.asarray(rb.column(TIMELINE).to_numpy(zero_copy_only=False)).astype("timedelta64[ns]")
    return ns.astype(np.int64) / 1e9


def _scalars(col) -> np.ndarray:
    """A Scalars column (one value per row) as floats; an empty row is NaN."""
    rows = col.to_pylist()
    return np.array([r[0] if r else np.nan for r in rows], float)


def _strips(value) -> list[np.ndarray]:
    return [np.asarray(s, float) for s in (value or []) if s]


def load(path: Path | str) -> RunData:
    """The recording at `path` read back (module docstring); ArmbridgeError in one line otherwise."""
    path = Path(path)
    check_rrd(path)
    import warnings

    try:
        from rerun.chunk import RrdReader

        with warnings.catch_warnings(record=True) as caught:  # no footer (cut, or older): rerun warns, then scans
            warnings.simplefilter("always")
            reader = RrdReader(path)
            stores = reader.recordings()
    except Exception as exc:  # noqa: BLE001 - rerun raises plain exceptions for bad files
        raise ArmbridgeError(f"{path}: cannot read the recording: {_first_line(exc)}") from None
    if not stores:
        raise ArmbridgeError(f"{path}: holds no recording (only a blueprint)")
    data = RunData(path, no_footer=any("footer" in str(w.message) for w in caught))
    parts: dict[str, list[tuple[np.ndarray, list]]] = {}  # timed entity -> [(t, values)]
    order: list[str] = []  # joint names in the order of their first entity
    chunks = 0
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            for chunk in reader.stream(store=stores[0]):
                chunks += 1
                _chunk(data, chunk, parts, order)
    except Exception as exc:  # noqa: BLE001 - a cut file raises mid-stream
        if chunks == 0:
            raise ArmbridgeError(f"{path}: cannot read the recording: {_first_line(exc)}") from None
        data.damaged = _first_line(exc)
    _assemble(data, parts, order)
    if not (data.joints or data.summary or data.plan_info or data.strips):
        raise ArmbridgeError(f"{path}: holds nothing of an armbridge run (no joints, plan or summary)")
    return data


def _chunk(data: RunData, chunk, parts: dict, order: list[str]) -> None:
    ent = chunk.entity_path.lstrip("/")
    rb = chunk.to_record_batch()
    names = rb.schema.names
    if ent.startswith("joints/") and ent.count("/") == 2:
        joint = ent.split("/")[1]
        if joint not in order:
            order.append(joint)
    if ent == SUMMARY_ENTITY and "TextDocument:text" in names:
        text = rb.column("TextDocument:text").to_pylist()[-1]
        try:
            data.summary = json.loads(text[0]) if text else None
        except (json.JSONDecodeError, TypeError):
            data.summary = None
        return
    if ent == "plan/info" and "TextDocument:text" in names:
        text = rb.column("TextDocument:text").to_pylist()[-1]
        data.plan_info = text[0] if text else None
        return
    t = _times(rb)
    if ent in ("events", "errors") and "TextLog:text" in names and t is not None:
        texts = rb.column("TextLog:text").to_pylist()
        levels = rb.column("TextLog:level").to_pylist() if "TextLog:level" in names else [None] * len(texts)
        out = data.events if ent == "events" else data.errors
        out.extend((float(ti), (lv or ["INFO"])[0], (tx or [""])[0]) for ti, lv, tx in zip(t, levels, texts))
        return
    if "Scalars:scalars" in names and t is not None:
        parts.setdefault(ent, []).append((t, _scalars(rb.column("Scalars:scalars"))))
        return
    strips = next((n for n in names if n.endswith(":strips")), None)
    positions = next((n for n in names if n.endswith(":positions")), None)
    if strips is not None:
        rows = rb.column(strips).to_pylist()
        if t is None:
            if rows and rows[-1]:
                data.strips[ent] = _strips(rows[-1])
        elif ent in ("arm/links", "arm/target"):
            parts.setdefault(ent, []).append((t, rows))
        elif ent == "drawing/trace" and rows:
            parts.setdefault(ent, []).append((t, [rows[-1]]))
    elif positions is not None and t is None:
        rows = rb.column(positions).to_pylist()
        if rows and rows[-1]:
            data.points[ent] = np.asarray(rows[-1], float)


def _assemble(data: RunData, parts: dict, order: list[str]) -> None:
    """The chunks of each timed entity in board-time order."""
    units = list((data.summary or {}).get("joint_units") or {})
    data.joint_names = [n for n in units if n in order] + [n for n in order if n not in units]
    for ent, pieces in parts.items():
        t = np.concatenate([p[0] for p in pieces])
        idx = np.argsort(t, kind="stable")
        t = t[idx]
        if ent in ("arm/links", "arm/target", "drawing/trace"):
            rows = [r for p in pieces for r in p[1]]
            rows = [rows[i] for i in idx]
            if ent == "drawing/trace":
                data.drawing_trace = _strips(rows[-1]) if rows else []
            else:
                data.arm[ent] = (t, rows)
            continue
        v = np.concatenate([p[1] for p in pieces])[idx]
        if ent.startswith("joints/") and ent.count("/") == 2:
            _, joint, what = ent.split("/")
            data.joints.setdefault(joint, {})[what] = (t, v)
        else:
            data.series[ent] = (t, v)
    data.joint_names = [n for n in data.joint_names if n in data.joints] or data.joint_names


def arm_at(data: RunData, entity: str, i: int) -> list[np.ndarray]:
    """The arm's strips (entity arm/links or arm/target) at sample i."""
    _t, rows = data.arm[entity]
    return _strips(rows[i])
