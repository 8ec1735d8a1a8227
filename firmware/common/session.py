"""Session rules of a board (docs/protocol.md: sessions, epochs, sequence
numbers) and board line formatting. Pure: no I/O; link.py drives it.

State kept here, and why:
  session    the id of the session the board serves (0: none since power on)
  epoch      E, the link epoch opened by the latest accepted HELLO (0: none).
             Every host line but HELLO carries a CRC started from E, so a copy
             of a line from an earlier epoch fails its CRC: it can never run.
  hello_seq  the seq of the HELLO that opened E: a copy of that HELLO is
             recognised at any delay and answered without rewinding anything.
  expect     the next seq to execute in this epoch; -1 until a HELLO has been
             accepted since boot (session, epoch and hello_seq survive a reset
             in persisted memory, expect and the replay ring do not).

Session.classify(seq, verb, hello) -> what to do with a well-formed line.
`hello` is (proto, session, epoch) of a HELLO line, None for other verbs.
The rules, first match wins:

  verb   condition                                              -> action
  HELLO  proto != PROTOCOL_VERSION                              -> BADPROTO (ER 12 PROTO version)
  HELLO  epoch == E + 1, session != stored session              -> NEW      (open a new session)
  HELLO  epoch == E + 1, session == stored session              -> RESYNC   (queue and motion kept)
  HELLO  epoch == E, session == stored, seq == hello_seq        -> FRESH    (copy of the HELLO that
                                                                             opened E: answer afresh,
                                                                             change nothing)
  HELLO  otherwise                                              -> STALE    (ER 11 STALE E)
  other  no HELLO accepted since boot, read-only verb           -> FRESH
  other  no HELLO accepted since boot                           -> NOSESSION
  other  seq == expect                                          -> EXEC     (execute, then record)
  other  1..RING behind expect, read-only verb                  -> FRESH    (execute, do not record)
  other  1..RING behind expect, its answer in the ring          -> REPLAY   (send replay(seq) again)
  other  otherwise (ahead, far behind, never answered)          -> SEQERR   (ER 7 SEQ expect)

Only the next epoch opens (not any newer one): a HELLO that jumped ahead, to
1073741823 say, would leave no epoch for a later resync (issue 21); refused
STALE E, a host retries at once with E + 1, so the epochs last 2**30 HELLOs.

NEW and RESYNC: the caller does its part (a new session flushes the queue),
then accept(seq, session, epoch) and persists. Nothing else changes state:
in particular no HELLO copy, however late, moves `expect` back, and within an
epoch no seq repeats (the host opens a new epoch first), so no copy of any
line executes anything twice.
"""

try:
    from micropython import const
except ImportError:
    def const(x):  # type: ignore[no-redef,misc]
        return x

import proto
import protodef as P

EXEC = const(0)
REPLAY = const(1)
FRESH = const(2)
SEQERR = const(3)
NOSESSION = const(4)
NEW = const(5)
RESYNC = const(6)
STALE = const(7)
BADPROTO = const(8)

_RING = P.RING
_SEQ_MASK = P.SEQ_MOD - 1


class Session:
    def __init__(self, session: int = 0, epoch: int = 0, hello_seq: int = -1) -> None:
        self.session = session
        self.epoch = epoch
        self.hello_seq = hello_seq
        self.expect = -1
        self.bseq = 0             # board line counter (mod 65536)
        self._ring_seq = [-1] * _RING
        self._ring_ans: list = [None] * _RING  # (kind, fields) answered for that seq

    # ------------------------------------------------------------ sequence rules

    @property
    def open(self) -> bool:
        """A HELLO has been accepted since boot."""
        return self.expect >= 0

    def classify(self, seq: int, verb: str, hello=None) -> int:
        """The action for a well-formed line: see the table in the module docstring."""
        if hello is not None:
            proto_v, sid, epoch = hello
            if proto_v != P.PROTOCOL_VERSION:
                return BADPROTO
            if epoch == self.epoch + 1:
                return RESYNC if sid == self.session else NEW
            if epoch == self.epoch and sid == self.session and seq == self.hello_seq:
                return FRESH
            return STALE
        ro = verb in P.READ_ONLY
        if self.expect < 0:
            return FRESH if ro else NOSESSION
        if seq == self.expect:
            return EXEC
        behind = (self.expect - seq) & _SEQ_MASK
        if 1 <= behind <= _RING:
            if ro:
                return FRESH
            if self._ring_seq[seq % _RING] == seq:
                return REPLAY
        return SEQERR

    def accept(self, seq: int, session: int, epoch: int) -> None:
        """A HELLO classified NEW or RESYNC: E := epoch, expect seq + 1, ring cleared."""
        self.session = session
        self.epoch = epoch
        self.hello_seq = seq
        for i in range(_RING):
            self._ring_seq[i] = -1
            self._ring_ans[i] = None
        self.expect = (seq + 1) & _SEQ_MASK

    def record(self, seq: int, kind: str, fields: list) -> None:
        """Stores the answer of an executed seq (OK or ER) and advances expect."""
        i = seq % _RING
        self._ring_seq[i] = seq
        self._ring_ans[i] = (kind, fields)
        self.expect = (seq + 1) & _SEQ_MASK

    def replay(self, seq: int):
        """(kind, fields) first answered for seq (classify said REPLAY)."""
        return self._ring_ans[seq % _RING]

    # ------------------------------------------------------------ board lines

    def line(self, kind: str, fields) -> bytes:
        """One board line with the next board seq (CRC from epoch 0, as every
        board line), at most MAX_BOARD_LINE bytes (fields are dropped from the
        end if it would be longer; never happens for the lines firmware sends)."""
        fields = list(fields)
        data = proto.encode(self.bseq, kind, fields)
        while len(data) > P.MAX_BOARD_LINE and fields:
            fields.pop()
            data = proto.encode(self.bseq, kind, fields)
        self.bseq = (self.bseq + 1) & _SEQ_MASK
        return data

    def er(self, seq, code: int, detail=None) -> bytes:
        fields = [seq, code, P.ERROR_NAMES.get(code, "ERR")]
        if detail is not None and detail != "":
            fields.append(detail)
        return self.line("ER", fields)

    def ev(self, ms: int, kind: str, args=()) -> bytes:
        return self.line("EV", [ms, kind] + list(args))

    def boot(self, fw: str, fwver: str, state: str) -> bytes:
        return self.line("BOOT", [fw, fwver, P.PROTOCOL_VERSION, state])
