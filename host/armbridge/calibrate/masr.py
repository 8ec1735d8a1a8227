"""`armbridge calibrate masr_ma`: the MASR mobile actuator measured from its own
sensors (docs/masr.md, "Calibration").

Steps:
* "magnets" and "wheel" (one drive, measured together): HOME, then at a low
  speed (SETLIM d) up the arm, crossing every magnet 2..n-1 up, back down and
  up again (a zig-zag of +-ZIG_MM about r_j, the way up to the next one), and magnet 1 down from ZIG_MM
  (the MA cannot pass below it: the base stop). The board reports each hall
  edge it re-anchors at with the edge's wheel count from home (`EV MAGNET j
  count`): a rising edge fires where the MA enters the window, at m_j - W_j
  coming up and m_j + W_j coming down, so a pair of neighbouring edges gives
  the centre (their mean) and the half window (half their difference), in
  counts. ROUNDS such drives, each from a fresh HOME, are averaged (the slip
  of the wheel on the link is a random walk from home). The wheel's travel
  per count is the least-squares scale from those centres to the joints'
  known positions r_j (l_1 + ... + l_{j-1}, home = 0; magnet 1, with one edge
  only, is left out); the centres in mm are that scale times the counts.
  Magnet 1: its window is the mean of the others', its centre its upper edge
  less that. After each drive, END pushes onto the far end stop (d = l) and
  the board reports its count from home: a second exact reference beside home,
  weighed with the magnets in the scale (`fit`), which the magnets alone leave
  about 0.07 % off (0.5 mm at l). Set with `MAG j pos win` (um) and `WHEEL nm`.
* "gains": relay experiments (RELAY) on the speed loop (MA on link 1) and on
  each joint's angle loop (the MA on its magnet): Ku, Tu and the
  Tyreus-Luyben gains are reported; the shipped gains are kept unless
  `set_gains` (the relay gains did not beat them on drawn plants:
  docs/masr.md, "Calibration").

Only the board's own sensors are read (events and answers): never the
emulator's plant.
"""
from __future__ import annotations

from typing import Any, Sequence

import numpy as np

from armbridge.calibrate.base import Found
from armbridge.calibrate.tuning import pid_gains, ultimate
from armbridge.errors import ArmbridgeError
from armbridge.link.protodef import VERB

STEPS = ("magnets", "wheel", "gains")
SPEED_MM_S = 20          # the drive over the magnets (SETLIM d); the slip's random walk grows with sqrt(speed)
ROUNDS = 2               # drives from a fresh HOME, averaged
ZIG_MM = 8.0             # the zig-zag's reach past a joint (beyond window + hysteresis + the estimate's error)
ACTION_S = 120.0         # the longest an action may take (board time)
# The two references' spreads that weigh them in the scale (fit): a magnet glued within
# +-1 mm of its joint, the far end cap printed within +-0.5 mm of l (docs/emulator.md's
# SPREADS, about 2 sd each).
MAGNET_SD_MM = 0.5
END_SD_MM = 0.2
RELAY_LOCO = (200, 3, 6)     # amp per mille, hyst mm/s, cycles
RELAY_ROT = (300, 5, 6)      # amp per mille, hyst mrad, cycles
RULE = "tyreus-luyben"


class _Actions:
    """MV/HOME one at a time, waiting for DONE; every MAGNET event kept with the
    way the MA was driving."""

    def __init__(self, client: Any) -> None:
        self.client = client
        self.wid = 100
        self.done: set[int] = set()
        self.fault: tuple | None = None
        self.edges: list[tuple[int, int, int]] = []      # (joint, count from home, way +-1)
        self.ends: list[int] = []                         # the far end stop's counts from home (END)
        self.relays: dict[int, tuple[int, int]] = {}
        self.way = 0
        self.prev = client.on_event

    def __enter__(self) -> "_Actions":
        def on_event(t, ev):
            try:
                if ev.kind == "DONE" and ev.args:
                    self.done.add(int(ev.args[0]))
                elif ev.kind == "MAGNET" and len(ev.args) >= 2:
                    self.edges.append((int(ev.args[0]), int(ev.args[1]), self.way))
                elif ev.kind == "ENDSTOP" and len(ev.args) >= 2:
                    self.ends.append(int(ev.args[1]))
                elif ev.kind == "FAULT":
                    self.fault = tuple(ev.args)
                elif ev.kind == "RELAY" and len(ev.args) >= 3:
                    self.relays[int(ev.args[0])] = (int(ev.args[1]), int(ev.args[2]))
            except ValueError:
                pass
            if self.prev is not None:
                self.prev(t, ev)

        self.client.on_event = on_event
        return self

    def __exit__(self, *exc) -> None:
        self.client.on_event = self.prev

    def run(self, verb: str, *args: int, way: int = 0) -> None:
        self.wid = self.wid + 1 if self.wid < 65000 else 100
        wid = self.wid
        self.way = way
        self.client.command(verb, wid, *args)
        self.client.drain(ACTION_S, until=lambda: wid in self.done or self.fault is not None)
        if self.fault is not None:
            reason = getattr(self.client, "fault_reason", None)
            raise ArmbridgeError(f"calibration: the board faulted during {verb} {' '.join(map(str, args))}: "
                                 f"{reason or ' '.join(self.fault)}")
        if wid not in self.done:
            raise ArmbridgeError(f"calibration: {verb} {' '.join(map(str, args))} did not complete "
                                 f"within {ACTION_S:g} s")

    def relay(self, j: int, amp: int, hyst: int, cycles: int, timeout_s: float = 30.0) -> tuple[int, int]:
        self.relays.pop(j, None)
        self.client.command("RELAY", j, amp, hyst, cycles)
        self.client.drain(timeout_s, until=lambda: j in self.relays or self.fault is not None)
        if j not in self.relays:
            raise ArmbridgeError(f"calibration: no RELAY event for joint {j} within {timeout_s:g} s")
        self.client.drain(3.0)            # the loop brings it back
        return self.relays[j]


def joints_mm(cfg: Any) -> np.ndarray:
    """r_1..r_{n-1} (mm): joint j at l_1 + ... + l_{j-1}."""
    links = np.asarray(cfg.LINK_LENGTHS_MM, float)
    return np.r_[0.0, np.cumsum(links[:-1])]


def drive_over_magnets(client: Any, cfg: Any, speed: float = SPEED_MM_S, rounds: int = ROUNDS,
                       zig: float = ZIG_MM) -> tuple[list[tuple[int, int, int]], list[int]]:
    """The drives of the magnets step -> every edge (joint, count from home, way), and
    the far end stop's count from home after each drive (END; none from a board
    that refuses END with VERB, a firmware older than it)."""
    n = int(cfg.N_JOINTS)
    r = joints_mm(cfg)
    lim = client.command("LIM", n).payload
    lo, hi, vmax = int(lim[1]), int(lim[2]), int(lim[3])
    if lo > 0 or hi < r[-1] + 2 * zig:
        raise ArmbridgeError(f"calibration: d's range [{lo}, {hi}] mm must hold the base and {r[-1] + 2 * zig:g} mm "
                             "(a SETLIM narrowed it)")
    edges: list[tuple[int, int, int]] = []
    ends: list[int] = []
    has_end = True
    with _Actions(client) as act:
        try:
            for _ in range(rounds):
                client.command("SETLIM", n, lo, hi, vmax)
                act.run("HOME")
                client.command("SETLIM", n, lo, hi, int(min(speed, vmax)))
                act.edges = []
                act.run("MV", int(round(zig)), way=1)
                act.run("MV", 0, way=-1)                          # onto magnet 1: its upper edge
                for rj in r[1:]:                                  # the lower edge (again: the last one's)
                    act.run("MV", int(round(rj + zig)), way=1)
                    act.run("MV", int(round(rj - zig)), way=-1)   # the upper edge
                act.run("MV", int(round(r[-1] + zig)), way=1)
                edges += act.edges
                if has_end:
                    has_end = _end(act)
            ends = act.ends
        finally:
            client.command("SETLIM", n, lo, hi, vmax)
    return edges, ends


def _end(act: _Actions) -> bool:
    """END onto the far stop -> False when the board has no END (refused VERB)."""
    try:
        act.run("END", way=1)
    except ArmbridgeError as exc:
        if f": {VERB} VERB" in str(exc):     # client.command's refusal: code, then name
            return False
        raise
    return True


def fit(edges: list[tuple[int, int, int]], r_mm: np.ndarray, nominal_mm_per_count: float,
        ends: Sequence[int] = (), length_mm: float = 0.0) -> dict[str, Any]:
    """Edges (joint, count from home, way) -> the wheel's mm per count, every magnet's
    centre and half window (mm), from neighbouring up/down edge pairs. `ends`: the far
    stop's counts from home, at length_mm (l). The scale q is weighted least squares
    over both references: minimise sum_j (c_j q - r_j)^2 / MAGNET_SD^2 + (e q - l)^2 /
    (END_SD^2 / k), c_j the centres' mean counts, e the k ends' mean, so
    q = (sum c_j r_j / MAGNET_SD^2 + e l k / END_SD^2) / (sum c_j^2 / MAGNET_SD^2 + e^2 k / END_SD^2). Pure."""
    nj = len(r_mm)
    centre_c = np.full(nj, np.nan)
    half_c = np.full(nj, np.nan)
    pairs: list[list[tuple[float, float]]] = [[] for _ in range(nj)]
    for a, b in zip(edges, edges[1:]):
        if a[0] == b[0] and a[2] != b[2] and a[2] and b[2]:
            up, down = (a, b) if a[2] > 0 else (b, a)
            pairs[a[0] - 1].append((up[1], down[1]))
    for k in range(1, nj):
        if not pairs[k]:
            raise ArmbridgeError(f"calibration: magnet {k + 1} was not crossed both ways")
        p = np.asarray(pairs[k], float)
        centre_c[k] = p.mean()
        half_c[k] = 0.5 * float(np.mean(p[:, 1] - p[:, 0]))
    upper1 = [c for j, c, w in edges if j == 1 and w < 0]
    if not upper1:
        raise ArmbridgeError("calibration: magnet 1's edge was not seen")
    c = centre_c[1:]
    num = float(np.dot(c, r_mm[1:])) / MAGNET_SD_MM ** 2
    den = float(np.dot(c, c)) / MAGNET_SD_MM ** 2
    if len(ends):
        e, k = float(np.mean(ends)), len(ends)
        num += e * length_mm * k / END_SD_MM ** 2
        den += e * e * k / END_SD_MM ** 2
    q = num / den
    if not abs(q / nominal_mm_per_count - 1.0) < 0.05:
        raise ArmbridgeError(f"calibration: the wheel's travel per count came out {q * 1e6:.0f} nm, more than 5 % "
                             f"off the config's {nominal_mm_per_count * 1e6:.0f} nm")
    centre = centre_c * q
    half = half_c * q
    half[0] = float(np.mean(half[1:]))
    u1 = float(np.mean(upper1)) * q
    centre[0] = u1 - half[0]
    if centre[0] < 0.0:
        centre[0], half[0] = 0.0, max(u1, q)
    return {"mm_per_count": q, "centre_mm": centre.tolist(), "half_window_mm": half.tolist(),
            "pairs": [len(p) for p in pairs], "residual_mm": (centre[1:] - r_mm[1:]).tolist(),
            "end_mm": [x * q for x in ends]}


def magnets_step(client: Any, cfg: Any, **kw) -> Found:
    r = joints_mm(cfg)
    edges, ends = drive_over_magnets(client, cfg, **kw)
    length = float(np.sum(cfg.LINK_LENGTHS_MM))
    f = fit(edges, r, float(cfg.WHEEL_MM_PER_COUNT), ends, length)
    q = f["mm_per_count"]
    found = Found()
    if ends:
        found.lines.append(f"far end stop: {np.mean(f['end_mm']):.3f} mm from home over {len(ends)} drives "
                           f"(l = {length:g} mm; weighed in the scale)")
    else:
        found.lines.append("far end stop: the board has no END (firmware older than it): the scale from the "
                           "magnets alone")
    for j, (c, h) in enumerate(zip(f["centre_mm"], f["half_window_mm"]), start=1):
        found.settings.append(("MAG", (j, int(round(c * 1000.0)), int(round(h * 1000.0)))))
        found.lines.append(f"magnet {j}: centre {c:.3f} mm ({c - r[j - 1]:+.3f} from r_{j}), "
                           f"half window {h:.3f} mm")
    found.settings.append(("WHEEL", (int(round(q * 1e6)),)))
    found.lines.append(f"wheel: {q * 1e6:.0f} nm per count ({q / cfg.WHEEL_MM_PER_COUNT - 1:+.3%} from the config's)")
    found.values["magnets"] = {"centre_mm": f["centre_mm"], "half_window_mm": f["half_window_mm"],
                               "pairs": f["pairs"]}
    found.values["wheel_nm_per_count"] = q * 1e6
    found.values["end_mm"] = f["end_mm"]
    return found


def gains_step(client: Any, cfg: Any, set_gains: bool = False) -> Found:
    """Relay experiments on the speed loop and every joint's angle loop."""
    n = int(cfg.N_JOINTS)
    r = joints_mm(cfg)
    found = Found()
    res: dict[str, Any] = {}
    with _Actions(client) as act:
        act.run("HOME")
        act.run("MV", int(round(0.5 * (r[1] if len(r) > 1 else cfg.LINK_LENGTHS_MM[0]))))
        amp, hyst, cyc = RELAY_LOCO
        tu_ms, a = act.relay(n, amp, hyst, cyc)
        rows = [(n, amp, hyst, tu_ms, a, 1.0)]                        # speed loop: mm/s, gains per mm/s
        for j in range(1, n):
            act.run("ROT", j, 0)                                       # onto the magnet (the joint to 0)
            amp, hyst, cyc = RELAY_ROT
            tu_ms, a = act.relay(j, amp, hyst, cyc)
            rows.append((j, amp, hyst, tu_ms, a, 1000.0))                # mrad -> gains per rad
    for j, amp, hyst, tu_ms, a, per in rows:
        if tu_ms <= 0 or a <= hyst:
            found.lines.append(f"loop {j}: no limit cycle (period {tu_ms} ms, amplitude {a})")
            res[str(j)] = {"period_ms": tu_ms, "amplitude": a}
            continue
        ku = ultimate(amp / 1000.0, float(a), float(hyst)) * per
        kp, ki, kd = pid_gains(ku, tu_ms / 1000.0, RULE)
        res[str(j)] = {"period_ms": tu_ms, "amplitude": a, "ku": ku, "tu_s": tu_ms / 1000.0,
                       "gains": [kp, ki, kd]}
        found.lines.append(f"loop {j}: Ku {ku:.4g}, Tu {tu_ms / 1000:.3f} s -> {RULE} kp {kp:.4g} ki {ki:.4g} "
                           f"kd {kd:.4g}" + ("" if set_gains else " (reported; the shipped gains kept)"))
        if set_gains:
            found.settings.append(("GAIN", (j, int(round(kp * 1000)), int(round(ki * 1000)), int(round(kd * 1000)))))
    found.values["relay"] = res
    return found


def calibrate(client: Any, cfg: Any, only: frozenset[str] = frozenset(), **kw) -> Found:
    """The MA's procedure (calibrate/base.py): magnets and wheel (measured together), then gains."""
    steps = set(only) or set(STEPS)
    found = Found()
    if steps & {"magnets", "wheel"}:
        f = magnets_step(client, cfg, **kw)
        keep = [s for s in f.settings if (s[0] == "MAG" and "magnets" in steps) or (s[0] == "WHEEL" and "wheel" in steps)]
        found = found.merge(Found(keep, f.values, f.lines))
    if "gains" in steps:
        found = found.merge(gains_step(client, cfg))
    return found
