"""The session layer (link/arq.py, executor/handshake.py, executor/stream.py)
against a scripted board (tests/session_peer.py) on a fake clock: lost lines,
lost and held answers, epochs, STALE, PROTO, FAULT. No sleeping, no threads."""
from __future__ import annotations

import os
import signal

import pytest

from armbridge.errors import ArmbridgeError
from armbridge.executor.client import BoardClient
from armbridge.executor.signals import Stopped, stop_on_signals
from armbridge.executor.stream import Stream
from armbridge.link import protocol as P
from armbridge.link.arq import Arq, Cmd
from armbridge.link.recovery import MIN_WINDOW
from armbridge.link.rto import RTO_MAX_S, RetransmitTimer
from armbridge.robots import ARM3R
from session_peer import FakeClock, Peer

MID = [1571, -1571, 0]


def plan(k: int, base=MID):
    q = [[base[0] + 3 * i, base[1] - 2 * i, base[2] + (i % 7)] for i in range(k)]
    return [20] * k, q


def client_for(peer: Peer, robot=ARM3R, **kw) -> BoardClient:
    c = BoardClient(peer, robot, session=kw.pop("session", 42), clock=peer.clock, **kw)
    c.connect()
    return c


def test_a_clean_plan_runs_once_in_order_with_its_values():
    clock = FakeClock()
    peer = Peer(clock)
    c = client_for(peer)
    durs, q = plan(40)
    c.execute(durs, q)
    assert peer.executed == [(i, tuple(q[i])) for i in range(40)]
    s = c.stats
    assert (s.waypoints_sent, s.waypoints_acked, s.retransmissions, s.resyncs) == (40, 40, 0, 0)
    assert c.done_index == 39 and sorted(c.done_times) == list(range(40))
    assert peer.epoch == 1 and c.arq.epoch == 1  # a fresh board: the first epoch


def test_a_line_cut_by_opening_the_port_is_not_a_damaged_line():
    """The tail of a line the board was sending when the port opened is not
    counted as damage; a damaged line later is."""
    clock = FakeClock()
    peer = Peer(clock)
    whole = P.encode(7, "T", 123, "IDLE", "-", 8, 1571, -1571, 0, 1571, -1571, 0, 0, 0, 0)
    peer.rx += whole[len(whole) // 2:]  # its tail: the frame is whole, the CRC is not its body's
    c = client_for(peer)
    durs, q = plan(5)
    c.execute(durs, q)
    assert c.stats.host_line_errors == 0
    peer.rx += whole[:-3] + b"00\n"  # a damaged CRC field
    c.drain(0.05)
    assert c.stats.host_line_errors == 1


def _telemetry(peer: Peer, k: int) -> list[bytes]:
    """k T lines the board sends next (board times 1000, 1001, ...)."""
    out = []
    for i in range(k):
        out.append(P.encode(peer.bseq % P.SEQ_MOD, "T", 1000 + i, "IDLE", "-", 8, 1571, -1571, 0, 1571, -1571, 0,
                            0, 0, 0))
        peer.bseq += 1
    return out


def test_a_stop_signal_as_the_port_hands_over_bytes_loses_none():
    """A stop signal is an exception between any two bytecodes (executor/signals.py).
    One that arrives as the port returns half a line must not lose those bytes: the
    e-stop's drain reads on, and the line they began is whole, not a damaged line
    (the read and the split run under the client's `holding`)."""
    clock = FakeClock()
    peer = Peer(clock)
    seen: list[int] = []
    c = client_for(peer, on_telemetry=lambda t, m: seen.append(m.ms))
    tel = _telemetry(peer, 3)
    half = len(tel[0]) // 2
    peer.rx += tel[0][:half]
    read = peer.read

    def read_then_signal(n: int = 1) -> bytes:
        data = read(n)
        if data:
            os.kill(os.getpid(), signal.SIGTERM)  # Python runs the handler at the next bytecode
        return data

    peer.read = read_then_signal  # type: ignore[method-assign]
    with stop_on_signals():
        with pytest.raises(Stopped):
            c.drain(0.05)
        peer.read = read  # type: ignore[method-assign]
        peer.rx += tel[0][half:] + tel[1] + tel[2]
        c.drain(0.05)
    assert c.stats.host_line_errors == 0 and seen == [1000, 1001, 1002]


def test_an_exception_in_a_callback_leaves_the_later_lines_for_the_next_read():
    """Lines split from one read are dispatched one at a time: a callback that raises
    (a stop signal in the recording) loses only its own line's remaining work."""
    clock = FakeClock()
    peer = Peer(clock)
    seen: list[int] = []

    def on_telemetry(t, m) -> None:
        seen.append(m.ms)
        if m.ms == 1001 and seen.count(1001) == 1:
            raise KeyboardInterrupt

    c = client_for(peer, on_telemetry=on_telemetry)
    peer.rx += b"".join(_telemetry(peer, 4))
    with pytest.raises(KeyboardInterrupt):
        c.drain(0.05)
    assert seen == [1000, 1001]
    c.drain(0.05)
    assert seen == [1000, 1001, 1002, 1003] and c.stats.host_line_errors == 0


def test_a_t_line_with_the_boards_own_columns_before_hello_is_not_a_damaged_line():
    """A board streams telemetry before our HELLO is answered (it booted, or serves an
    older session): with its own columns after the 3n (the pump's four) the joint
    columns cannot be split before HELLO tells n. Not read, not counted; after HELLO
    the same line is read by n."""
    clock = FakeClock()
    peer = Peer(clock)
    t = P.encode(7, "T", 123, "IDLE", "-", 8, 1571, -1571, 0, 1571, -1571, 0, 0, 0, 0, 250, 300, 350, 0)
    peer.rx += b"\n" + t  # after a whole line: not the first piece the port delivers
    seen = []
    c = client_for(peer, on_telemetry=lambda t, m: seen.append(m))
    assert c.stats.host_line_errors == 0 and seen == []
    peer.rx += P.encode(8, "T", 123, "IDLE", "-", 8, 1571, -1571, 0, 1571, -1571, 0, 0, 0, 0, 250, 300, 350, 0)
    c.drain(0.05)
    assert c.stats.host_line_errors == 0 and [m.extra for m in seen][-1:] == [(250, 300, 350, 0)]


def test_seq_is_the_command_number_mod_65536():
    assert [Cmd(n, "PING", (), 1).seq for n in (1, 65535, 65536, 65537)] == [1, 65535, 0, 1]


def test_every_line_after_hello_is_framed_with_the_epoch():
    clock = FakeClock()
    peer = Peer(clock)
    peer.epoch = 6  # a board that saw epochs up to 6 of another session
    sent = []
    real = peer.write
    peer.write = lambda data: (sent.append(data), real(data))[1]
    c = client_for(peer)
    c.command("PING")
    assert c.arq.epoch == 7
    hellos = [x for x in sent if b" HELLO " in x]
    others = [x for x in sent if b" HELLO " not in x]
    assert hellos and others
    for line in hellos:
        P.decode(line, P.MAX_HOST_LINE, epoch=12345)  # HELLO: always epoch 0, whatever the board's
    for line in others:
        P.decode(line, P.MAX_HOST_LINE, epoch=7)
        with pytest.raises(P.ProtocolError) as err:
            P.decode(line, P.MAX_HOST_LINE, epoch=6)
        assert err.value.code == P.CRC


def test_lost_lines_are_resent_go_back_n_and_run_once():
    clock = FakeClock()
    peer = Peer(clock)
    c = client_for(peer)
    first = peer.lines_in
    peer.drop_in = {first + 3, first + 4, first + 11, first + 30}  # W lines lost on the way
    durs, q = plan(40)
    c.execute(durs, q)
    assert peer.executed == [(i, tuple(q[i])) for i in range(40)]
    s = c.stats
    assert s.retransmissions > 0 and (s.seq_errors > 0 or s.timeouts > 0)
    assert s.waypoints_sent == 40 and s.waypoints_acked == 40 and s.waypoints_retransmitted > 0
    assert s.window_cuts >= 1 and c.arq.cwnd >= MIN_WINDOW


def test_lost_answers_are_replayed_not_executed_again():
    clock = FakeClock()
    peer = Peer(clock)
    c = client_for(peer)
    first = peer.answers_out
    peer.drop_out = {first + 2, first + 5, first + 6}
    durs, q = plan(20)
    c.execute(durs, q)
    assert [wid for wid, _ in peer.executed] == list(range(20))
    assert c.stats.retransmissions >= 1 and c.stats.waypoints_acked == 20


def test_timeout_backs_off_and_karn_takes_no_sample_from_a_retransmission():
    clock = FakeClock()
    peer = Peer(clock)
    peer.answer_delay = 0.02
    c = client_for(peer, robot=None)
    for _ in range(40):
        c.command("PING")
    timer = c.arq.timer
    assert timer.srtt == pytest.approx(0.02, abs=0.006)
    assert timer.min <= timer.rto <= timer.initial
    srtt = timer.srtt
    peer.drop_in = {peer.lines_in}  # the next PING is lost once: its answer comes to the resend
    c.command("PING")
    assert c.stats.timeouts == 1 and c.stats.retransmissions == 1
    assert timer.srtt == srtt  # Karn: no sample from the retransmitted line


def test_credits_hold_the_stream_at_the_boards_queue_size():
    clock = FakeClock()
    peer = Peer(clock, qsize=4)
    peer.auto_complete = False
    c = client_for(peer)
    durs, q = plan(10)
    stream = Stream(durs, q)
    c._stream = stream
    for _ in range(20):
        stream.fill(c.arq)
        c.arq.loop_once()
    assert len(peer.queue) == 4 and stream.next_wp == 4  # no FULL: the credit stopped it
    peer.step()
    for _ in range(20):
        c.arq.loop_once()
        stream.fill(c.arq)
    assert stream.next_wp == 5 and len(peer.queue) == 4


def test_a_new_epoch_before_seqs_would_repeat_mid_plan():
    clock = FakeClock()
    peer = Peer(clock)
    c = client_for(peer, max_epoch_commands=16)
    durs, q = plan(100)
    c.execute(durs, q)
    assert peer.executed == [(i, tuple(q[i])) for i in range(100)]
    s = c.stats
    assert s.resyncs == 0 and s.epoch_renewals >= 100 // 16 and s.epochs == s.epoch_renewals + 1
    assert c.arq.epoch == peer.epoch == s.epochs
    per_epoch: dict[int, list[int]] = {}
    for epoch, seq, verb in peer.seen:
        per_epoch.setdefault(epoch, []).append(seq)
    for epoch, seqs in per_epoch.items():
        assert len(seqs) <= 16 and len(set(seqs)) == len(seqs), epoch  # the HELLO included


def test_a_done_read_with_the_hello_reply_is_not_taken_back():
    """The board answers a resync HELLO (done = d) and completes d + 1 right after;
    both arrive in one read, so the host learns d + 1 before it reads the reply."""

    class Busy(Peer):
        def _hello(self, seq, args):
            super()._hello(seq, args)
            if self.session is not None and self.epoch > 1:
                self.step()

        def _execute(self, seq, verb, args):
            ans = super()._execute(seq, verb, args)
            if verb == "W" and len(self.queue) > 2:
                self.step()
            return ans

    clock = FakeClock()
    peer = Busy(clock)
    peer.auto_complete = False
    c = client_for(peer, max_epoch_commands=6)
    durs, q = plan(40)
    orig = peer.read

    def read(n=1):  # an idle host drains the queue, as time passes on a real board
        if not peer.rx and peer.queue:
            peer.step()
        return orig(n)

    peer.read = read
    c.execute(durs, q)
    assert peer.executed == [(i, tuple(q[i])) for i in range(40)]
    assert c.stats.epoch_renewals >= 5 and c.stats.resyncs == 0


def test_stale_epoch_second_client_with_the_same_session():
    clock = FakeClock()
    peer = Peer(clock)
    a = client_for(peer, session=9)
    for _ in range(3):
        a.arq.need_resync = "test"
        a._resync()
    assert peer.epoch == 4
    durs, q = plan(5)
    a.execute(durs, q)
    b = client_for(peer, session=9)  # a second run, same session: starts at epoch 1
    assert b.arq.epoch == 5 and peer.epoch == 5
    b.execute(durs, q)
    # b's ids follow on from the board's newest: its `done` 4 is not one of b's.
    assert [wid for wid, _ in peer.executed] == list(range(10))
    # The first client's lines are now from an old epoch: they fail the board's CRC.
    before = len(peer.executed)
    peer.write(P.encode(50, "W", 99, 20, *MID, epoch=4))
    assert len(peer.executed) == before and b"ER - 2 CRC" in bytes(peer.rx)


def test_a_held_hello_answer_does_not_rewind_the_board():
    """A copy of the HELLO that opened the epoch, arriving late, is answered afresh
    and changes nothing; an older one is STALE."""
    clock = FakeClock()
    peer = Peer(clock)
    sent = []
    real = peer.write
    peer.write = lambda data: (sent.append(data), real(data))[1]
    c = client_for(peer)
    durs, q = plan(10)
    c.execute(durs, q)
    expect = peer.expect
    opening = [x for x in sent if b" HELLO " in x][-1]
    peer.write(opening)
    assert peer.expect == expect and bytes(peer.rx).count(b" OK ") >= 1
    c.arq.need_resync = "test"
    c._resync()
    peer.rx.clear()
    peer.write(opening)  # the previous epoch's HELLO
    assert b" 11 STALE 2" in bytes(peer.rx)


def test_protocol_mismatch_names_both_versions():
    peer = Peer(FakeClock(), proto=3)
    c = BoardClient(peer, ARM3R, session=1, clock=peer.clock)
    with pytest.raises(ArmbridgeError, match="the board speaks protocol 3, this armbridge speaks protocol 2"):
        c.connect()


def test_a_protocol_1_board_is_named():
    class V1(Peer):
        def _handle(self, raw):  # a v1 board cannot parse v2 frames: ER - PARSE, framed with CRC-16
            self.rx += b"5 ER - 1 PARSE*1A2B\n"

    peer = V1(FakeClock())
    c = BoardClient(peer, ARM3R, session=1, clock=peer.clock, connect_timeout=1.0)
    with pytest.raises(ArmbridgeError, match="the board speaks protocol 1, this armbridge speaks protocol 2"):
        c.connect()


def test_robot_none_learns_the_limits_and_refuses_a_plan():
    peer = Peer(FakeClock(), fw="other", n=2, limits=((-10, 10, 5), (0, 0, 1)))
    c = client_for(peer, robot=None)
    assert c.info.fw == "other" and c.info.limits_milli == [(-10, 10, 5), (0, 0, 1)]
    with pytest.raises(ArmbridgeError, match="no robot"):
        c.execute([10], [[0, 0]])


def test_fault_names_the_joint_and_the_reason():
    clock = FakeClock()
    peer = Peer(clock)
    peer.auto_complete = False
    c = client_for(peer)
    durs, q = plan(10)
    peer.send("EV", 1234, "FAULT", 2, 412)
    peer.state, peer.reason = "FAULT", "FOLLOW:2"
    with pytest.raises(ArmbridgeError, match=r"FAULT latched, joint 2 \(elbow\): following error 412 mrad"):
        c.execute(durs, q)


@pytest.mark.parametrize("reason, args, words", [
    ("STALL:2", (2, 1000), r"joint 2 \(elbow\): drive stalled at 100 % effort \(no encoder count\)"),
    ("STALL:LOCO", (3, -600), r"the locomotion motor: drive stalled at 60 % effort"),
    ("MAGNET:MISSED", (3, 2), r"localisation lost: magnet 2 missed"),
    ("MAGNET:SPURIOUS", (3, 1), r"localisation lost: a magnet edge where none can be \(nearest magnet 1\)"),
    ("FOLLOW:3", (3, 31), r"joint 3 \(\w+\): following error 31 mrad"),
])
def test_each_fault_reason_has_its_own_words(reason, args, words):
    """A FAULT is worded by its reason (STAT's token: docs/protocol.md §3.2), not as a following
    error whatever it was: a missed magnet is no error in mrad, a stall's value is an effort."""
    clock = FakeClock()
    peer = Peer(clock)
    peer.auto_complete = False
    c = client_for(peer)
    durs, q = plan(10)
    peer.send("EV", 1234, "FAULT", *args)
    peer.state, peer.reason = "FAULT", reason
    with pytest.raises(ArmbridgeError, match="FAULT latched, " + words):
        c.execute(durs, q)
    assert "following error" not in c.fault_reason or reason.startswith("FOLLOW")


def test_keepalive_pings_on_the_clock():
    clock = FakeClock()
    peer = Peer(clock)
    c = client_for(peer, robot=None)
    pings = c.stats.pings
    c.drain(2.0)
    assert 13 <= c.stats.pings - pings <= 17  # every 0.125 s of the clock (watchdog 1000 ms / 8)


def test_a_boot_resyncs_and_resumes_after_done():
    clock = FakeClock()
    peer = Peer(clock)
    peer.auto_complete = False
    c = client_for(peer)
    c.set_rate(10)
    durs, q = plan(12)
    stream_done = []

    def on_progress(done):
        stream_done.append(done)

    orig_step = peer.step
    calls = {"n": 0}

    def step_and_reset():
        orig_step()
        calls["n"] += 1
        if calls["n"] == 5:  # a reset: queue lost, session, epoch and done persist
            peer.queue, peer.expect = [], -1
            peer.ring.clear()
            peer.send("BOOT", "arm3r", "0.1.0", 2, "IDLE")

    peer.auto_complete = True
    peer.step = step_and_reset
    c.execute(durs, q, on_progress=on_progress)
    assert [wid for wid, _ in peer.executed] == list(range(12))
    assert c.stats.resyncs == 1 and c.stats.boots == 1 and stream_done[-1] == 12


def test_the_timer_backs_off_only_while_the_board_is_silent():
    timer = RetransmitTimer(10 / 115200)
    assert timer.timeout() == timer.initial
    for _ in range(10):
        timer.expired_in_silence()
    assert timer.timeout() == RTO_MAX_S
    timer.answered()
    timer.sample(0.004)
    assert timer.timeout() == max(timer.min, 0.004 + 4 * 0.002)


def test_arq_refuses_to_issue_past_a_full_epoch():
    clock = FakeClock()
    peer = Peer(clock)
    arq = Arq(peer, clock=clock, max_epoch_commands=4)
    assert arq.epoch_left() == 4
    for _ in range(4):
        arq.issue("PING")
    assert not arq.can_issue()
    with pytest.raises(RuntimeError, match="epoch is full"):
        arq.issue("PING")


def _pings_until_answered(c: BoardClient, k: int, release_after_timeout: Peer | None = None):
    arq = c.arq
    cmds = [arq.issue("PING", keep=True) for _ in range(k)]
    answers: dict[int, object] = {}
    for _ in range(2000):
        if release_after_timeout is not None and arq.stats.timeouts:
            release_after_timeout.release()  # the board was only late: the first answers arrive now
        arq.loop_once()
        for cmd in cmds:
            a = arq.answer_of(cmd)
            if a is not None:
                answers[cmd.n] = a
        if len(answers) == k:
            return cmds, answers
    raise AssertionError(f"{len(answers)} of {k} answered")


def test_a_spurious_timeout_resends_one_line_not_the_window():
    """F-RTO: the board answers late (held answers), the timer runs out: only the
    oldest line goes again, and the late answers to the first copies end the
    probe; nothing else is resent."""
    clock = FakeClock()
    peer = Peer(clock)
    c = client_for(peer, robot=None)
    peer.hold_out = set(range(peer.answers_out, peer.answers_out + 6))
    cmds, answers = _pings_until_answered(c, 6, release_after_timeout=peer)
    assert all(isinstance(a, P.Ok) for a in answers.values())
    s = c.stats
    assert (s.timeouts, s.spurious_timeouts, s.retransmissions) == (1, 1, 1)
    assert c.arq.cwnd > MIN_WINDOW, "a spurious timeout does not cut the window"


def test_lines_lost_at_the_tail_are_resent_after_a_second_timeout():
    """F-RTO, a real loss: the last 3 of 6 lines never reach the board and no
    later line reveals it (no ER SEQ, no damaged line): the probe (the first lost line) is
    answered, the other two time out again and go back-N."""
    clock = FakeClock()
    peer = Peer(clock)
    c = client_for(peer, robot=None)
    peer.drop_in = {peer.lines_in + 3, peer.lines_in + 4, peer.lines_in + 5}
    cmds, answers = _pings_until_answered(c, 6)
    assert all(isinstance(a, P.Ok) for a in answers.values())
    s = c.stats
    assert (s.timeouts, s.spurious_timeouts, s.retransmissions) == (2, 0, 3)
    assert s.window_cuts == 1, "the real loss restarted the window (at MIN_WINDOW)"


def test_a_board_checking_another_epoch_is_resynchronised():
    """A board that reset, restored an older record and lost its BOOT answers every line of
    ours with a framing error (our CRCs start from the newer epoch): it talks, so it is not
    silent, but nothing of ours is answered; after silence_timeout the host says HELLO again
    (framed from epoch 0, which reaches it) and the plan finishes, each waypoint once."""
    clock = FakeClock()
    peer = Peer(clock)
    c = client_for(peer)
    durs, q = plan(6)
    peer.epoch -= 1  # the older record: every host line now fails its CRC on the board
    c.execute(durs, q)
    assert c.stats.resyncs >= 1
    assert [v for _, v in peer.executed] == [tuple(row) for row in q]  # each once, in order


def test_an_estop_the_board_did_not_report_is_sent_again_at_its_boot():
    """A byte that reached a board before its receiver was on (it was booting) is lost in
    the hardware (docs/protocol.md §2): until the board reports ESTOP, every BOOT that does
    not say ESTOP gets the byte again; once it has, a BOOT gets nothing more."""
    clock = FakeClock()
    peer = Peer(clock)
    c = client_for(peer)
    sent = []
    real = peer.write

    def write(data):
        if data == P.ESTOP_BYTE:
            sent.append(clock.t)
        return real(data)

    peer.write = write
    c.estop()
    peer.state = "IDLE"  # the byte was lost: the board was booting
    peer.send("BOOT", "arm3r", "1.0", 2, "IDLE")
    c.drain(0.05, resync=False)
    assert len(sent) == 2 and peer.state == "ESTOP"
    peer.send("T", int(clock.t * 1000), "ESTOP", "-", 8, *([0] * 9))
    c.drain(0.05, resync=False)
    peer.send("BOOT", "arm3r", "1.0", 2, "ESTOP")
    c.drain(0.05, resync=False)
    assert len(sent) == 2
