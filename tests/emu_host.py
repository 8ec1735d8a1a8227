"""The host side of the emulator tests: protocol v2 lines from the host codec
(armbridge.link.protocol), with the seq counter and the link epoch a host
keeps. The real host client lives in armbridge.executor; these tests talk to
the board byte by byte so they can inject what a client never would."""
from __future__ import annotations

from armbridge.link import protocol as P


class Codec:
    """Frames host lines (seq, epoch) and cuts board bytes into decoded lines:
    (seq, verb, [args]) or (None, "BAD", [raw]) for a line that does not decode."""

    def __init__(self) -> None:
        self.seq = 0
        self.epoch = 0
        self._buf = b""

    def line(self, verb: str, *args) -> bytes:
        self.seq = (self.seq + 1) % P.SEQ_MOD
        return P.encode(self.seq, verb, *args, epoch=self.epoch)

    def hello(self, session: int) -> bytes:
        """HELLO proto session epoch, opening the next epoch (contract §2)."""
        self.epoch += 1
        return self.line("HELLO", P.PROTOCOL_VERSION, session, self.epoch)

    def feed(self, data: bytes) -> list[tuple]:
        self._buf += data
        *done, self._buf = self._buf.split(b"\n")
        out = []
        for raw in done:
            if not raw:  # the lone LF a board sends before BOOT
                continue
            try:
                line = P.decode(raw, P.MAX_BOARD_LINE)
                out.append((line.seq, line.verb, list(line.args)))
            except P.ProtocolError:
                out.append((None, "BAD", [raw]))
        return out


def is_reply(line: tuple, seq: int) -> bool:
    return line[1] in ("OK", "ER") and bool(line[2]) and line[2][0] == str(seq)


def done_ev(i: int):
    return lambda a: a[1] == "DONE" and a[2] == str(i)
