"""The 3R arm's jig step: where the joints really are, from printed marks (docs/drawing.md "Calibration").

Why a jig: a board's own sensors cannot say where its joints are. The
effort rig's pots and the pca9685 rig's servo horns sit on 25-tooth splines,
up to +-7.2 deg off; the pot reads that error too, so no measurement on the
board sees it. An external reference does: a printed sheet of marks, each a
dot with a short line through it, at known (x, y) in the arm's frame (the
base's axis at the sheet's origin mark) and a known direction theta. The
user jogs the arm until the pen's tip is on the dot and the pen link lies
along the line, and confirms; with the three link lengths the pose fixes all
three joint angles (the elbow bends one way, q2 < 0). The host records what
the board reads there (the pots, or on the pca9685 rig the pulse it sends),
and with two or more marks fits each joint's offset and gain.

`MARKS` is the sheet (`sheet_svg()` draws it at 1:1 for printing). A jig is
any object with `place(mark, arm) -> bool`: move `arm` (a `Jogger`) until the
pen is on `mark`, True when confirmed (False: this mark skipped).
`TerminalJig` is the real one (keys jog the joints, Enter confirms);
`EmuJig` plays the user against an emulated board: it looks at the plant's
hidden truth (what a user sees on the paper) to decide how to jog, and the
host code records only what the board reports, as with a real user.
"""
from __future__ import annotations

import math
import sys
from dataclasses import dataclass
from typing import Any, Callable

import numpy as np

from armbridge.errors import BoardFailure
from armbridge.ik.analytic3r import ik as ik3r
from armbridge.robots import ARM3R

@dataclass(frozen=True)
class Mark:
    """A printed mark: the dot at (x, y) m and the pen link's direction theta (rad)."""

    name: str
    x: float
    y: float
    theta: float


def ik(mark: Mark) -> np.ndarray:
    """The joint angles (rad) that put the pen on `mark` (the closed-form IK on arm3r's
    limits, where the elbow bends q2 < 0)."""
    q, ok = ik3r(ARM3R, [mark.x, mark.y, mark.theta])
    if not bool(ok):
        raise ValueError(f"mark {mark.name} is out of the arm's reach")
    return np.asarray(q, float)


def fk(q) -> tuple[float, float, float]:
    """(x, y, theta) of the pen at joint angles q."""
    x, y = np.asarray(ARM3R.ee_point(np.asarray(q, float)), float)[:2]
    return float(x), float(y), float(np.sum(q))


def _mark(name: str, q) -> Mark:
    x, y, th = fk(q)
    return Mark(name, round(x, 3), round(y, 3), round(th, 3))


#: the sheet: five marks whose poses spread every joint over most of its range
#: (at 1 mm and 1 mrad, as printed; the joints they give are `ik(mark)`)
MARKS: tuple[Mark, ...] = (
    _mark("A", (0.9, -1.5, 0.7)),
    _mark("B", (1.6, -0.6, -0.9)),
    _mark("C", (2.2, -2.1, 0.5)),
    _mark("D", (1.2, -2.4, 1.1)),
    _mark("E", (2.0, -1.2, -0.3)),
)


def sheet_svg(marks=MARKS) -> str:
    """The sheet to print at 1:1 (mm): each mark a dot, a 20 mm line along theta, its name;
    the arm's base axis on the cross at (0, 0)."""
    xs = [m.x * 1000 for m in marks] + [0.0]
    ys = [m.y * 1000 for m in marks] + [0.0]
    x0, y1 = min(xs) - 30, max(ys) + 30
    w, h = max(xs) + 30 - x0, y1 - (min(ys) - 30)
    out = [f'<svg xmlns="http://www.w3.org/2000/svg" width="{w:.0f}mm" height="{h:.0f}mm" '
           f'viewBox="0 0 {w:.0f} {h:.0f}">']

    def p(x, y):
        return x - x0, y1 - y
    bx, by = p(0, 0)
    out.append(f'<path d="M{bx - 5},{by} h10 M{bx},{by - 5} v10" stroke="black" stroke-width="0.3"/>')
    for m in marks:
        cx, cy = p(m.x * 1000, m.y * 1000)
        ex, ey = p(m.x * 1000 - 20 * math.cos(m.theta), m.y * 1000 - 20 * math.sin(m.theta))
        out.append(f'<circle cx="{cx:.2f}" cy="{cy:.2f}" r="0.6"/>')
        out.append(f'<line x1="{cx:.2f}" y1="{cy:.2f}" x2="{ex:.2f}" y2="{ey:.2f}" stroke="black" '
                   f'stroke-width="0.2"/>')
        out.append(f'<text x="{cx + 2:.1f}" y="{cy - 2:.1f}" font-size="4">{m.name}</text>')
    out.append("</svg>")
    return "\n".join(out) + "\n"


class Jogger:
    """The arm as a jig moves it: `setpoint` (rad, what the board was last sent),
    `move(q)` (a W waypoint at a gentle speed, then waits until the arm settled),
    `nudge(j, dq)`. `client`: a connected BoardClient. `side` (+1, -1; 0: none):
    every move ends coming from that side, from `approach` rad short of its
    target: a positional servo stops as soon as it is within its dead band, and
    the gear play lets the joint trail its shaft, both toward where it came
    from, so the place it rests at for a pulse depends on the side it came
    from; the pca9685 rig's jig step places each mark from both sides and
    takes the middle.

    The approach is wider than any servo's hysteresis (its dead band both ways
    and its play: up to about 36 mrad), so the joint comes from beyond it and
    the play is taken up, and it ends slowly (the last FINE rad at CREEP_SPEED,
    the rest of the approach at SLOW_SPEED): the board leads a moving
    positional servo's set point by SERVO_LEAD_MS along its velocity, so an
    approach at SPEED would overshoot the target by 20 mrad and the servo would
    come to rest from the other side (the width between the two sides measured
    6 mrad on a servo whose truth was 23); at CREEP_SPEED the lead is 0.2 mrad.
    `setpoint` is what the board was sent (whole mrad), so the pulse the host
    works out for it is the board's. `snap` (q -> q, optional): where a move
    really goes; the pca9685 rig's jig step moves to the middle of the PWM
    count the set point falls in, so that the creep's last lead cannot tip the
    pulse into the next count (a user's jogs end near a count's edge: on the
    count beyond it the servo rested a count inside its dead band, and the
    width read a count short on 2 of 5 marks)."""

    SPEED = 0.5       # rad/s of the fastest joint
    SLOW_SPEED = 0.1  # rad/s: the approach's middle (a lead of 4 mrad at 40 ms, within any dead band)
    CREEP_SPEED = 0.005    # rad/s: its last FINE rad (a lead of 0.2 mrad: the pulse that the
                           # servo ends on is, but for 7 % of a 200 Hz count, the one the host records)
    FINE = 0.005
    SETTLE_S = 0.4
    WID = 60000       # waypoint ids the jig uses (and counts up from)

    def __init__(self, client: Any, start, side: int = 0, approach: float = 0.05,
                 snap: Callable[[np.ndarray], np.ndarray] | None = None) -> None:
        self.client = client
        self.side = side
        self.approach = approach
        self.snap = snap
        self.setpoint = np.asarray(start, float).copy()
        self._wid = self.WID

    def next_id(self) -> int:
        self._wid = self.WID + (self._wid - self.WID + 1) % 5000
        return self._wid

    def wait(self, wid: int, seconds: float) -> None:
        """Until waypoint `wid` is done (STAT's done id, polled every 50 ms), then SETTLE_S more."""
        end = self.client.now() + seconds + 5.0
        while True:
            _, d, _, _ = self.client.stat()
            if d == wid:
                break
            if self.client.now() > end:
                raise BoardFailure(f"jog waypoint {wid} did not finish")
            self.client.drain(0.05)
        self.client.drain(self.SETTLE_S)

    def move(self, q) -> None:
        q = np.asarray(q, float)
        if self.snap is not None:
            q = np.asarray(self.snap(q), float)
        if self.side:
            self._go(q - self.side * self.approach)
            self._go(q - self.side * self.FINE, self.SLOW_SPEED)
            self._go(q, self.CREEP_SPEED)
        else:
            self._go(q)

    def _go(self, q, speed: float | None = None) -> None:
        from armbridge.link import protocol as P

        dur = max(50, int(1000 * float(np.max(np.abs(q - self.setpoint))) / (speed or self.SPEED)))
        wid = self.next_id()
        self.client.command("W", wid, dur, *P.to_milli(q))
        self.client.drain(dur / 1000.0)
        self.wait(wid, dur / 1000.0)
        self.setpoint = np.asarray(P.to_milli(q), float) / 1000.0     # as the board has it

    def nudge(self, j: int, dq: float) -> None:
        q = self.setpoint.copy()
        q[j] += dq
        self.move(q)


class EmuJig:
    """The user at an emulated board: it sees where the pen really is (the
    plant's joints: `truth()` -> rad) and jogs as a careful user does, by
    the difference it sees, until the pen is within `tol` (rad, each joint)
    of the mark's pose, or `tries` jogs are spent and it goes back to where it came
    closest (a pulse count, 11.5 mrad at 50 Hz, is coarser than `tol`)."""

    def __init__(self, truth: Callable[[], np.ndarray], tol: float = 0.002, tries: int = 8) -> None:
        self.truth = truth
        self.tol = tol
        self.tries = tries

    @classmethod
    def of_client(cls, client: Any, **kw: Any) -> "EmuJig":
        """The jig of the emulated board behind `client` (an in-process emu: port)."""
        emu = getattr(getattr(client, "port", None), "emulator", None)
        if emu is None:
            raise ValueError("the emulated jig needs an in-process emulated board (an emu: port)")
        return cls(lambda: np.asarray(emu.positions(), float), **kw)

    def place(self, mark: Mark, arm: Jogger) -> bool:
        want = ik(mark)
        arm.move(want)
        best = (np.inf, arm.setpoint)
        for _ in range(self.tries):
            off = want - self.truth()
            err = float(np.max(np.abs(off)))
            if err < best[0]:
                best = (err, arm.setpoint.copy())
            if err <= self.tol:
                return True
            arm.move(arm.setpoint + off)
        off = want - self.truth()
        if float(np.max(np.abs(off))) > best[0]:    # as a user does: back to the closest it came
            arm.move(best[1])
        return True


class TerminalJig:
    """The real user: jogs the joints with keys and confirms with Enter.
    Keys: 1/q, 2/w, 3/e: joint 1, 2, 3 up/down by the step; + and - change the
    step (1, 5, 20, 50 mrad); Enter: the pen is on the mark; s: skip it."""

    STEPS = (0.001, 0.005, 0.02, 0.05)

    def __init__(self, read: Callable[[], str] | None = None, write: Callable[[str], None] | None = None) -> None:
        self.read = read or (lambda: sys.stdin.readline())
        self.write = write or (lambda s: print(s, flush=True))

    def place(self, mark: Mark, arm: Jogger) -> bool:
        step = 2
        arm.move(ik(mark))
        self.write(f"mark {mark.name}: put the pen's tip on the dot at x {mark.x * 1000:.0f} mm, "
                   f"y {mark.y * 1000:.0f} mm with the pen link along its line; keys 1/q 2/w 3/e jog, "
                   f"+/- step, Enter confirms, s skips")
        keys = {"1": (0, 1), "q": (0, -1), "2": (1, 1), "w": (1, -1), "3": (2, 1), "e": (2, -1)}
        while True:
            self.write(f"step {self.STEPS[step] * 1000:g} mrad> ")
            line = self.read()
            if line == "":
                return False
            for ch in line.rstrip("\n") or "\n":
                if ch == "\n":
                    return True
                if ch == "s":
                    return False
                if ch == "+":
                    step = min(step + 1, len(self.STEPS) - 1)
                elif ch == "-":
                    step = max(step - 1, 0)
                elif ch in keys:
                    j, sign = keys[ch]
                    arm.nudge(j, sign * self.STEPS[step])


def make_jig(name: str | None, client: Any) -> Any:
    """`--jig`: "emu" (the emulated user; an emu: port), "terminal" (keys), None: none."""
    if name is None:
        return None
    if name == "emu":
        return EmuJig.of_client(client)
    if name == "terminal":
        return TerminalJig()
    raise ValueError(f"jig {name!r}: use emu or terminal")
