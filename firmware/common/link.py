"""The common link layer of a MicroPython board: BoardLink(hal, cfg, board).

Everything a board does for the protocol (docs/protocol.md), whatever it
drives: the line reader and the e-stop byte, decode with the link epoch, the
session rules (session.py), the common verbs (HELLO LIM HOLD RESUME CLR RATE
WDOG STAT PING, and calstore.py's IDENT CALID), the states and their latches, persisted across resets, the
watchdog, telemetry pacing, events, and the control period's schedule. A board
(firmware/esp32/arm.py; the MASR actuator next) adds its own verbs and its
control tick through the small interface below, and reuses this file unchanged.

The board object gives the link:
  n, qsize                  joint count (argument checks, HELLO), queue slots
  lim                       [[min, max, vmax], ...] per joint now in force (LIM)
  verbs                     {verb: handler(values) -> payload list}: its own
                            verbs, arguments already checked by
                            proto.parse_command; a handler refuses by raising
                            proto.ProtocolError
  motion_verbs              those of its verbs refused LATCHED while latched
  free() -> int             free queue slots (every OK carries it)
  busy() -> bool            motion queued or under way (RUN vs IDLE)
  halt()                    drop all motion (queue, active move, hold); the set
                            point stays where it is
  hold_here()               halt(), then set point := measured position and
                            controllers reset: stops where the arm is, moves
                            nothing
  set_hold(on)              freeze / release motion (HOLD, RESUME)
  control(mode)             one control period: OFF (read sensors, write no
                            output), ZERO (write zero effort), DRIVE (advance the
                            motion, run the loops, check faults)
  telemetry() -> list       its fields of a T line, after `ms state done free`:
                            3n joint columns (measured, set point, output), then
                            any columns of its own (documented with its verbs)
  persist_extra() -> str    optional: one token (no spaces) of its own state to
                            persist with the link's record (the MA's position and
                            joint angles); restore(token or None) is called with it
                            at boot, before hold_here()

The config (cfg) gives it FW_NAME, FW_VERSION, PERIOD_MS, TELEMETRY_HZ, WDOG_MS
and UART_BAUD (the first line's window, _joining). The board calls back:
  link.event(kind, args)    an event: sent after the reply of the command that
                            caused it, at once otherwise
  link.completed(wid)       a waypoint completed (the last one of a tick): the
                            done id, persisted, and event `DONE wid free`
  link.fault(args, reason)  latch FAULT: outputs off, event `FAULT args...`;
                            `reason` (one token) is kept for STAT and persisted
  link.queued               set by the board to the id of its last accepted move
  link.ms()                 board time in ms
  link.save()               persist now (the record, with persist_extra())

Rules the link keeps for every board:
  * after any boot the outputs stay off until a HELLO is accepted, and while a
    latch that the board booted with holds, until CLR;
  * ESTOP, WDOG and FAULT latch, survive a reset (persisted) and refuse motion;
    only CLR releases them, never a HELLO;
  * the watchdog (RUN/HOLD only) is fed only by lines answered OK;
  * the persist record is `AB2 session epoch hello_seq done latch reason [extra]`
    (extra: the board's persist_extra()); anything else reads as power on;
  * the first line since boot is dropped without ER when it fails its framing
    or CRC and may be the tail of a line the receiver came up in (_joining).
"""

try:
    from micropython import const
except ImportError:
    def const(x):  # type: ignore[no-redef,misc]
        return x

import calstore
import proto
import protodef as P
import session as sess

IDLE = "IDLE"
RUN = "RUN"
HOLD = "HOLD"
ESTOP = "ESTOP"
WDOG = "WDOG"
FAULT = "FAULT"
LATCHED_STATES = P.LATCHED_STATES

# control(mode)
OFF = const(0)
ZERO = const(1)
DRIVE = const(2)

TICKS_MASK = P.TICKS_PERIOD - 1   # ticks_ms wraps at 2**30, so do board times
_PERSIST_TAG = "AB2"

# The first line since boot (BoardLink._joining): come and no tail; no byte read
# yet, the window still open; its bytes have come and it may be a tail.
_JOINED = const(0)
_JOIN_WAIT = const(1)
_JOIN_TAIL = const(2)


def wid(x: int):
    """A waypoint id for a line: "-" when there is none (-1)."""
    return "-" if x < 0 else x


def first_cause(state: str, reason: str) -> str:
    """The reason an e-stop latches with in `state` (docs/protocol.md section 9):
    "-" from an unlatched state; over a latch its own reason, or its name (WDOG)."""
    if state not in LATCHED_STATES:
        return "-"
    if reason != "-" or state == ESTOP:
        return reason
    return state


def _int_or_none(s: str) -> int:
    return -1 if s == "-" else int(s)


def parse_persist(data):
    """The persist record -> (session, epoch, hello_seq, done, latch, reason, extra),
    or None when it is not a valid AB2 record (power on). extra: None when absent."""
    try:
        parts = bytes(data).decode().split()
        if len(parts) not in (7, 8) or parts[0] != _PERSIST_TAG:
            return None
        sid = int(parts[1])
        epoch = int(parts[2])
        hseq = _int_or_none(parts[3])
        done = _int_or_none(parts[4])
        latch = parts[5]
    except Exception:
        return None
    if not (0 <= sid < P.SEQ_MOD and 0 <= epoch <= P.EPOCH_MAX
            and -1 <= hseq < P.SEQ_MOD and -1 <= done < P.SEQ_MOD):
        return None
    if latch != "-" and latch not in LATCHED_STATES:
        return None
    return sid, epoch, hseq, done, latch, parts[6], parts[7] if len(parts) == 8 else None


class LinkedBoard:
    """The entry points every board gives its main loop and the emulator, all the
    link's: a board class derives from this and sets self.link = BoardLink(...)."""

    link: "BoardLink" = None  # type: ignore[assignment]  # the board sets BoardLink(hal, cfg, self)

    def poll(self) -> bool:
        """One pass of the main loop (BoardLink.poll). -> True if bytes came."""
        return self.link.poll()

    def tick(self) -> None:
        """One control period (BoardLink.tick)."""
        self.link.tick()

    def estop(self) -> None:
        """What the e-stop byte does (BoardLink.estop)."""
        self.link.estop()

    @property
    def state(self) -> str:
        return self.link.state

    @property
    def done(self) -> int:
        return self.link.done


class BoardLink:
    def __init__(self, hal, cfg, board) -> None:
        self.hal = hal
        self.cfg = cfg
        self.board = board
        self.period_ms = cfg.PERIOD_MS
        self.rate = cfg.TELEMETRY_HZ
        self.wdog_ms = cfg.WDOG_MS
        self.reader = proto.LineReader(P.MAX_HOST_LINE)
        rec = parse_persist(hal.load_persist())
        if rec is None:
            rec = (0, 0, -1, -1, "-", "-", None)
        self.session = sess.Session(rec[0], rec[1], rec[2])
        self.done = rec[3]
        self.state = IDLE if rec[4] == "-" else rec[4]
        self.reason = rec[5]              # latch reason for STAT ("-": none given)
        self.queued = -1                  # id of the last accepted move, -1: none
        self.outputs_allowed = False      # a HELLO accepted since boot (and CLR if booted latched)
        self._events: list = []
        self._in_command = False
        self._telem_acc = 0
        self._verbs = {
            "LIM": self._cmd_lim, "HOLD": self._cmd_hold,
            "RESUME": self._cmd_resume, "CLR": self._cmd_clr, "RATE": self._cmd_rate,
            "WDOG": self._cmd_wdog, "STAT": self._cmd_stat, "PING": self._cmd_ping,
        }
        for verb in board.verbs:
            self._verbs[verb] = board.verbs[verb]
        self.cal = calstore.CalStore(hal, board)   # IDENT, CALID; the saved settings before anything moves
        self.cal.load()
        self._verbs.update(self.cal.verbs)
        self._motion = ("HOLD", "RESUME") + tuple(board.motion_verbs)
        now = hal.ticks_ms()
        self.last_ok = now
        self.next_tick = now
        self._join = _JOIN_WAIT
        self._join_us = 2 * 10 * 1000000 // cfg.UART_BAUD   # two byte times at 8N1
        self._boot_us = hal.ticks_us()
        hal.outputs_off()
        restore = getattr(board, "restore", None)
        if restore is not None:
            restore(rec[6])
        board.hold_here()
        # The lone LF ends any line a reset cut short, so BOOT always decodes.
        hal.uart_write(b"\n")
        self._send(self.session.boot(cfg.FW_NAME, cfg.FW_VERSION, self.state))

    # ------------------------------------------------------------ main loop

    def poll(self) -> bool:
        """UART bytes in, lines handled, control period if due. -> True if bytes came."""
        data = self.hal.uart_read()
        tail = self._join != _JOINED and self._joining(data)   # the first line may be a tail
        if data:
            for item in self.reader.feed(data):
                kind = item[0]
                if kind == "estop":
                    self.estop()
                elif kind == "error":
                    if not tail:
                        self._send(self.session.er("-", item[1]))
                else:
                    self._on_line(item[1], tail)
                if tail:                  # its first item ends the first line
                    tail = False
                    self._join = _JOINED
        now = self.hal.ticks_ms()
        late = self.hal.ticks_diff(now, self.next_tick)
        if late >= 0:
            if late >= self.period_ms:   # too late: resync, no burst of ticks
                self.next_tick = (now + self.period_ms) & TICKS_MASK
            else:
                self.next_tick = (self.next_tick + self.period_ms) & TICKS_MASK
            self.tick()
        return bool(data)

    def _joining(self, data) -> bool:
        """-> True while the first line since boot may be the tail of a line the
        receiver came up in (docs/protocol.md section 8: the host never waits for
        BOOT). Such a line that fails its framing or CRC is dropped without ER. The
        HAL opens the UART before the link starts, and this board reads it in
        pieces: a byte counts as come within two byte times of the link starting
        unless a read found nothing after those had passed. poll() calls this only
        until the first line's first item, then clears _join."""
        if self._join == _JOIN_TAIL:
            return True
        if data:
            self._join = _JOIN_TAIL
            return True
        hal = self.hal
        if hal.ticks_diff(hal.ticks_us(), self._boot_us) > self._join_us:
            self._join = _JOINED          # nothing in time: the first line starts later
        return False

    def tick(self) -> None:
        """One control period: watchdog, the board's control, telemetry."""
        now = self.hal.ticks_ms()
        state = self.state
        if state in (RUN, HOLD) and self.hal.ticks_diff(now, self.last_ok) >= self.wdog_ms:
            self.board.halt()
            self._latch(WDOG, "-")
            self._send(self.session.ev(self.ms(), WDOG))
            state = WDOG
        if not self.outputs_allowed or state == ESTOP or state == FAULT:
            self.board.control(OFF)
        elif state == WDOG:
            self.board.control(ZERO)
        else:
            self.board.control(DRIVE)
            if self.state == RUN and not self.board.busy():
                self.state = IDLE
        self._telemetry(now)

    def estop(self) -> None:
        """E-stop byte: outputs off, motion dropped, ESTOP latched, at once. Over
        a latch it keeps the first cause as the reason (docs/protocol.md section
        9): FAULT's reason, or WDOG; ESTOP is the state (outputs off, where WDOG
        only writes zero effort)."""
        self.hal.outputs_off()
        self.board.halt()
        self._latch(ESTOP, first_cause(self.state, self.reason))
        self._send(self.session.ev(self.ms(), ESTOP))

    # ------------------------------------------------------------ board callbacks

    def ms(self) -> int:
        return self.hal.ticks_ms() & TICKS_MASK

    def event(self, kind: str, args=()) -> None:
        if self._in_command:
            self._events.append((kind, list(args)))
        else:
            self._send(self.session.ev(self.ms(), kind, args))

    def completed(self, w: int) -> None:
        self.done = w
        self._save()
        self._send(self.session.ev(self.ms(), "DONE", [w, self.board.free()]))

    def fault(self, args, reason: str) -> None:
        self.hal.outputs_off()
        self.board.halt()
        self._latch(FAULT, reason)
        self._send(self.session.ev(self.ms(), FAULT, args))

    # ------------------------------------------------------------ lines

    def _on_line(self, raw, tail=False) -> None:
        s = self.session
        try:
            seq, verb, args = proto.decode(raw, P.MAX_HOST_LINE, s.epoch)
        except proto.ProtocolError as e:
            if not tail:                  # a tail at boot (_joining) is dropped silently
                self._send(s.er("-", e.code))
            return
        self._in_command = True
        if verb == "HELLO":
            kind, fields = self._hello(seq, args)
        else:
            what = s.classify(seq, verb)
            if what == sess.EXEC:
                kind, fields = self._execute(seq, verb, args)
                s.record(seq, kind, fields)
            elif what == sess.REPLAY:
                kind, fields = s.replay(seq)
            elif what == sess.FRESH:
                kind, fields = self._execute(seq, verb, args)
            elif what == sess.NOSESSION:
                kind, fields = "ER", [seq, P.NOSESSION, "NOSESSION"]
            else:
                kind, fields = "ER", [seq, P.SEQ, "SEQ", s.expect]
        self._in_command = False
        if kind == "OK":                  # only a line answered OK feeds the watchdog
            self.last_ok = self.hal.ticks_ms()
        self._send(s.line(kind, fields))
        for ev in self._events:
            self._send(s.ev(self.ms(), ev[0], ev[1]))
        self._events = []

    def _execute(self, seq: int, verb: str, args):
        """Runs one command -> its answer (kind, fields) without the board seq."""
        try:
            values = proto.parse_command(verb, args, self.board.n)
            handler = self._verbs.get(verb)
            if handler is None:
                raise proto.ProtocolError(P.VERB)
            if verb in self._motion and self.state in LATCHED_STATES:
                raise proto.ProtocolError(P.LATCHED)
            payload = handler(values)
        except proto.ProtocolError as e:
            return "ER", _er_fields(seq, e)
        if self.state == IDLE and self.board.busy():
            self.state = RUN
        return "OK", [seq, self.board.free()] + payload

    def _hello(self, seq: int, args):
        """HELLO proto session epoch: the session rules of session.py."""
        s = self.session
        try:
            v = proto.parse_command("HELLO", args, self.board.n)
        except proto.ProtocolError as e:
            if args and args[0] != str(P.PROTOCOL_VERSION):
                # Another version's HELLO may take other arguments: its first, the
                # version, still gets the answer that names both versions.
                return "ER", [seq, P.PROTO, "PROTO", P.PROTOCOL_VERSION]
            return "ER", _er_fields(seq, e)
        what = s.classify(seq, "HELLO", v)
        if what == sess.BADPROTO:
            return "ER", [seq, P.PROTO, "PROTO", P.PROTOCOL_VERSION]
        if what == sess.STALE:
            return "ER", [seq, P.STALE, "STALE", s.epoch]
        if what != sess.FRESH:            # NEW or RESYNC
            if what == sess.NEW:
                self.done = -1
                self.queued = -1
                self.board.hold_here()
                if self.state in (RUN, HOLD):
                    self.state = IDLE
            s.accept(seq, v[1], v[2])
            if not self.outputs_allowed and self.state not in LATCHED_STATES:
                self.outputs_allowed = True
                self.board.hold_here()
            self._save()
        c = self.cfg
        b = self.board
        return "OK", [seq, b.free(), c.FW_NAME, c.FW_VERSION, P.PROTOCOL_VERSION, b.n,
                      b.qsize, self.rate, self.wdog_ms, wid(self.done), wid(self.queued),
                      self.state]

    # ------------------------------------------------------------ common verbs

    def _cmd_lim(self, v: list) -> list:
        return [v[0]] + self.board.lim[v[0] - 1]

    def _cmd_hold(self, v: list) -> list:
        if self.state != HOLD:
            self.state = HOLD
            self.board.set_hold(True)
            self.event("HOLD")
        return []

    def _cmd_resume(self, v: list) -> list:
        if self.state == HOLD:
            self.board.set_hold(False)
            self.state = RUN if self.board.busy() else IDLE
            self.event("RESUME")
        return []

    def _cmd_clr(self, v: list) -> list:
        if self.state in LATCHED_STATES:
            self.board.hold_here()
            self.outputs_allowed = True
            self._latch(IDLE, "-")
            self.event("CLEAR")
        return []

    def _cmd_rate(self, v: list) -> list:
        self.rate = v[0]
        self._telem_acc = 0
        return []

    def _cmd_wdog(self, v: list) -> list:
        self.wdog_ms = v[0]
        return []

    def _cmd_stat(self, v: list) -> list:
        return [self.state, wid(self.done), wid(self.queued), self.ms(),
                self.reason if self.state in LATCHED_STATES else "-"]

    def _cmd_ping(self, v: list) -> list:
        return [self.ms()]

    # ------------------------------------------------------------ state, output

    def _latch(self, state: str, reason: str) -> None:
        """Enters (or, with IDLE, leaves) a latched state and persists it."""
        self.state = state
        self.reason = reason
        self._save()

    def _telemetry(self, now: int) -> None:
        if self.rate <= 0:
            return
        self._telem_acc += self.rate * self.period_ms
        if self._telem_acc < 1000:
            return
        self._telem_acc -= 1000
        if self._telem_acc >= 1000:
            self._telem_acc = 0
        fields = [now & TICKS_MASK, self.state, wid(self.done), self.board.free()]
        self._send(self.session.line("T", fields + self.board.telemetry()))

    def _send(self, data: bytes) -> None:
        self.hal.uart_write(data)

    def save(self) -> None:
        s = self.session
        latch = self.state if self.state in LATCHED_STATES else "-"
        text = "%s %d %d %s %s %s %s" % (_PERSIST_TAG, s.session, s.epoch, wid(s.hello_seq),
                                         wid(self.done), latch, self.reason)
        extra = getattr(self.board, "persist_extra", None)
        if extra is not None:
            text += " " + extra()
        self.hal.save_persist(text.encode())

    _save = save


def _er_fields(seq: int, e) -> list:
    fields = [seq, e.code, e.name]
    if e.detail:
        fields.append(e.detail)
    return fields
