"""Link state of a board (docs/protocol.md section 6) and board line formatting.

Session.classify(seq, verb) tells the board what to do with a well-formed line:
  EXEC     execute it, then record(seq, kind, fields) its answer
  REPLAY   a retransmit: send session.replay(seq) again, do not execute
  FRESH    a retransmitted read-only verb: execute and answer, do not record
  SEQERR   answer ER SEQ 7 SEQ expect
  NOSESSION no HELLO since boot (HELLO itself is always EXEC)
"""

try:
    from micropython import const
except ImportError:
    def const(x):  # type: ignore[no-redef,misc]
        return x

import proto

RING = const(32)

EXEC = const(0)
REPLAY = const(1)
FRESH = const(2)
SEQERR = const(3)
NOSESSION = const(4)


class Session:
    def __init__(self) -> None:
        self.expect = -1          # next seq to execute; -1: no HELLO since boot
        self.bseq = 0             # board line counter (mod 65536)
        self._ring_seq = [-1] * RING
        self._ring_ans: list = [None] * RING  # (kind, fields) answered for that seq

    # ------------------------------------------------------------ sequence rules

    @property
    def open(self) -> bool:
        return self.expect >= 0

    def hello(self, seq: int) -> None:
        """A HELLO (accepted at any seq): forget old answers, expect seq + 1."""
        for i in range(RING):
            self._ring_seq[i] = -1
            self._ring_ans[i] = None
        self.expect = (seq + 1) & 0xFFFF

    def classify(self, seq: int, verb: str, same_session: bool = False) -> int:
        """`same_session`: a HELLO naming the session already open. A stale copy
        of that HELLO must not rewind `expect`, or later commands would run twice."""
        if verb == "HELLO":
            return REPLAY if same_session and self._answered(seq) else EXEC
        if self.expect < 0:
            return NOSESSION
        if seq == self.expect:
            return EXEC
        if self._answered(seq):
            return FRESH if verb in proto.READ_ONLY else REPLAY
        behind = (self.expect - seq) & 0xFFFF
        if 1 <= behind <= RING and verb in proto.READ_ONLY:
            return FRESH
        return SEQERR

    def _answered(self, seq: int) -> bool:
        """seq is at most RING behind expect and its answer is in the ring."""
        behind = (self.expect - seq) & 0xFFFF
        return self.expect >= 0 and 1 <= behind <= RING and self._ring_seq[seq % RING] == seq

    def record(self, seq: int, kind: str, fields: list) -> None:
        """Stores the answer of an executed seq and advances expect."""
        i = seq % RING
        self._ring_seq[i] = seq
        self._ring_ans[i] = (kind, fields)
        self.expect = (seq + 1) & 0xFFFF

    def replay(self, seq: int):
        """(kind, fields) first answered for seq (classify said REPLAY)."""
        return self._ring_ans[seq % RING]

    # ------------------------------------------------------------ board lines

    def line(self, kind: str, fields) -> bytes:
        """One board line with the next board seq, at most 192 bytes (fields
        are dropped from the end if it would be longer; never happens for the
        lines this firmware sends)."""
        fields = list(fields)
        data = proto.encode(self.bseq, kind, fields)
        while len(data) > proto.MAX_BOARD_LINE and fields:
            fields.pop()
            data = proto.encode(self.bseq, kind, fields)
        self.bseq = (self.bseq + 1) & 0xFFFF
        return data

    def ok(self, seq: int, free: int, payload=()) -> bytes:
        return self.line("OK", [seq, free] + list(payload))

    def er(self, seq, code: int, detail=None) -> bytes:
        fields = [seq, code, proto.ERROR_NAMES.get(code, "ERR")]
        if detail is not None and detail != "":
            fields.append(detail)
        return self.line("ER", fields)

    def ev(self, ms: int, kind: str, args=()) -> bytes:
        return self.line("EV", [ms, kind] + list(args))

    def boot(self, fw: str, fwver: str, proto_version: int) -> bytes:
        return self.line("BOOT", [fw, fwver, proto_version])
