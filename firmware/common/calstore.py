"""A board's calibration, persisted and named: the IDENT and CALID verbs (docs/calibration.md).

Why: `armbridge calibrate` measures a board (gains by relay auto-tune, magnet
centres, bend curves) and sets what it found with the ordinary verbs (GAIN,
CAL, BEND, DBAND, MAG, WHEEL), which live in RAM. CALID id then writes every
setting the calibration covers to the board's flash filesystem, as Klipper's
SAVE_CONFIG does, and names it: the host keeps the same id in its calibration
file, and a run refuses a board whose IDENT does not match (a board swapped,
re-flashed or calibrated elsewhere).

The board object gives:
  cal_text() -> list        its calibrated settings as tokens (no spaces in one)
  cal_apply(tokens)         sets them back at boot; raises ValueError (or
                            IndexError) when they do not fit this firmware
and the HAL: uid() -> str (the chip's unique id, hex), read_file(name),
write_file(name, data).

The file is `ABC1 id token...` on one line. A missing, foreign or unreadable
file leaves the firmware's defaults in force and IDENT reports cal 0, so the
host sees "not calibrated" rather than half a calibration.
"""

import protodef as P
import proto

CAL_FILE = "cal.txt"
TAG = "ABC1"


class CalStore:
    def __init__(self, hal, board) -> None:
        self.hal = hal
        self.board = board
        self.id = 0
        self.verbs = {"IDENT": self._ident, "CALID": self._calid}

    def load(self) -> None:
        """At boot, before anything moves: the saved settings, if they are whole."""
        data = self.hal.read_file(CAL_FILE)
        if not data:
            return
        try:
            toks = bytes(data).decode().split()
            if len(toks) < 2 or toks[0] != TAG:
                return
            cal_id = int(toks[1])
            apply = getattr(self.board, "cal_apply", None)
            if apply is not None:
                apply(toks[2:])
            self.id = cal_id
        except (ValueError, IndexError, UnicodeError):
            self.id = 0

    def _ident(self, v: list) -> list:
        return [self.hal.uid(), self.id]

    def _calid(self, v: list) -> list:
        text = getattr(self.board, "cal_text", None)
        toks = [TAG, str(v[0])] + (list(text()) if text is not None else [])
        try:
            self.hal.write_file(CAL_FILE, (" ".join(toks) + "\n").encode())
        except OSError:
            raise proto.ProtocolError(P.RANGE, "", "fs")
        self.id = v[0]
        return []
