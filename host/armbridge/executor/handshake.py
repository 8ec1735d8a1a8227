"""The handshake of protocol v2 (docs/protocol.md): HELLO until answered, and the
checks that the board is the one the plan was made for.

`HELLO proto session epoch` opens a session or resynchronises one. The host
starts at epoch 1 and every later HELLO (a resync, a routine renewal) uses the
next epoch; a board opens only the epoch after its own (E + 1) and answers any
other `ER STALE E`, and the host tries again at once with E + 1 (a board keeps
its epoch across resets, so a second run with the same session starts past the
first). Only the next epoch opening means no HELLO, however buggy its epoch,
uses up the epochs the host needs (docs/protocol.md §6). Retransmissions of
one attempt keep its seq and its epoch: the board answers a copy of the HELLO
that opened its epoch afresh and changes nothing, so a lost answer costs only
a resend. A board of another protocol version answers `ER PROTO V`; a board of
protocol 1 cannot even parse our lines, so its CRC-16 lines are what tells.

A HELLO never releases a latch (only CLR does): its reply's `state` says
whether the board is latched, and the session layer applies the policy
(executor/session.py).
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

from armbridge.boards import boards_of_robot
from armbridge.errors import ArmbridgeError
from armbridge.link import protocol as P
from armbridge.link.arq import Arq

HELLO_INTERVAL_S = 0.25  # HELLO every 250 ms until answered


@dataclass
class BoardInfo:
    """The board's identity and settings from the HELLO reply and LIM."""

    fw: str
    version: str
    proto: int
    n: int
    qsize: int
    rate: int
    wdog_ms: int
    done: int | None
    queued: int | None
    state: str
    free: int
    limits_milli: list[tuple[int, int, int]] = field(default_factory=list)  # (min, max, vmax) per joint


def parse_hello(ok: P.Ok) -> BoardInfo:
    """The HELLO reply: fw fwver proto n qsize rate wdog_ms done queued state."""
    p = ok.payload
    if len(p) < 10:
        raise ArmbridgeError(f"the board's HELLO reply has {len(p)} fields, protocol {P.PROTOCOL_VERSION} has 10: "
                             f"{' '.join(p)}")
    try:
        return BoardInfo(
            fw=p[0], version=p[1], proto=int(p[2]), n=int(p[3]), qsize=int(p[4]), rate=int(p[5]),
            wdog_ms=int(p[6]), done=None if p[7] == "-" else int(p[7]),
            queued=None if p[8] == "-" else int(p[8]), state=p[9], free=ok.free,
        )
    except ValueError:
        raise ArmbridgeError(f"the board's HELLO reply is malformed: {' '.join(p)}") from None


def _versions(board: object) -> str:
    return f"the board speaks protocol {board}, this armbridge speaks protocol {P.PROTOCOL_VERSION}"


def _no_answer(arq: Arq, timeout: float) -> ArmbridgeError:
    if arq.stats.v1_lines:
        return ArmbridgeError(f"{_versions(1)} (its lines carry CRC-16): update the board's firmware")
    return ArmbridgeError(f"no answer to HELLO from the board in {timeout:.1f} s: is it powered, on this port, "
                          f"and speaking armbridge protocol {P.PROTOCOL_VERSION}?")


def hello(arq: Arq, session: int, timeout: float) -> P.Ok:
    """HELLO every 250 ms until answered (sooner after a damaged line or a BOOT); on
    STALE again at once with the board's epoch + 1. The accepted HELLO opens its
    epoch in `arq`. Everything before the answer is ignored except events, BOOT and
    (in a resync, once n is known) telemetry, handed up by `arq`."""
    epoch = arq.epoch + 1
    cmd = arq.new_hello(P.PROTOCOL_VERSION, session, epoch)
    end = arq.now() + timeout
    next_send = 0.0
    st = arq.stats
    damaged_at_send = 0
    while True:
        now = arq.now()
        if now > end:
            arq.abandon()
            raise _no_answer(arq, timeout)
        # Every 250 ms; at once when a damaged line arrives after our HELLO
        # reached the board (likely our HELLO or its answer), or a BOOT does (the
        # board was still booting, its receiver not yet listening: it lost our HELLO).
        damaged = st.host_line_errors + st.board_framing_errors + st.boots
        if now >= next_send or (damaged > damaged_at_send and now >= cmd.arrive_at):
            arq.send_hello(cmd)
            damaged_at_send = damaged
            next_send = now + HELLO_INTERVAL_S
        arq.pump(max(0.0, next_send - arq.now()))
        ans = arq.answer_of(cmd)
        if isinstance(ans, P.Ok):
            arq.open_epoch(cmd, ans)
            return ans
        if ans is None:
            continue
        detail = " ".join(ans.detail)
        if ans.code == P.STALE:
            try:
                epoch = int(ans.detail[0]) + 1
            except (IndexError, ValueError):
                raise ArmbridgeError(f"the board refused HELLO: STALE with a malformed epoch {detail!r}") from None
            if epoch > P.EPOCH_MAX:   # 2**30 - 1 HELLOs opened it, one epoch at a time
                raise ArmbridgeError(f"the board's epoch {epoch - 1} is the last one: its persisted memory must "
                                     "be cleared (a power cycle on an ESP32 board) to start again from epoch 1")
            cmd = arq.new_hello(P.PROTOCOL_VERSION, session, epoch)
            next_send = 0.0
            continue
        arq.abandon()
        if ans.code == P.PROTO:
            raise ArmbridgeError(f"{_versions(detail or '?')}: the board refused HELLO")
        raise ArmbridgeError(f"the board refused HELLO {session}: {ans.code} {ans.name} {detail}".rstrip())


def check_identity(info: BoardInfo, robot) -> None:
    """Protocol version, and (with a robot) firmware name and joint count."""
    if info.proto != P.PROTOCOL_VERSION:
        raise ArmbridgeError(f"{_versions(info.proto)} (firmware {info.fw} {info.version})")
    if robot is None:
        return
    if info.fw != robot.name and info.fw not in boards_of_robot(robot.name):
        raise ArmbridgeError(f"the board runs firmware {info.fw!r} {info.version}, the plan is for robot "
                             f"{robot.name!r}")
    if info.n != robot.dof:
        raise ArmbridgeError(f"the board has {info.n} joints, robot {robot.name} has {robot.dof}")


def read_limits(command: Callable[..., P.Ok], n: int) -> list[tuple[int, int, int]]:
    """LIM j for every joint -> [(min, max, vmax)] in milli-units."""
    limits = []
    for j in range(1, n + 1):
        ans = command("LIM", j)
        try:
            jj, lo, hi, vmax = (int(x) for x in ans.payload[:4])
        except ValueError:
            jj = 0
        if jj != j:
            raise ArmbridgeError(f"the board's LIM {j} reply is malformed: {' '.join(ans.payload)}")
        limits.append((lo, hi, vmax))
    return limits


def check_limits(limits: list[tuple[int, int, int]], robot) -> None:
    """The board's limits must be the robot's (1 milli-unit of rounding allowed);
    the ArmbridgeError names every joint and value that differs."""
    want = zip(P.to_milli(robot.q_min), P.to_milli(robot.q_max), P.to_milli(robot.v_max))
    problems = []
    for j, ((lo, hi, vmax), (w_lo, w_hi, w_v)) in enumerate(zip(limits, want)):
        name = robot.joint_names[j]
        for what, board_v, w in (("min", lo, w_lo), ("max", hi, w_hi), ("vmax", vmax, w_v)):
            if abs(board_v - w) > 1:
                unit = "mrad/s" if what == "vmax" else "mrad"
                problems.append(f"joint {j + 1} ({name}) {what}: board {board_v} {unit}, robot {w} {unit}")
    if problems:
        raise ArmbridgeError(f"the board's limits differ from robot {robot.name}: " + "; ".join(problems))
