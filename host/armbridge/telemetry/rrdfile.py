"""Whether a file is a Rerun recording, before anything hands it to rerun: one line otherwise."""
from __future__ import annotations

from pathlib import Path

from armbridge.errors import ArmbridgeError

#: the first bytes of a Rerun recording (RRF2 in rerun 0.41; RRF0/RRF1 before it)
RRD_MAGIC = b"RRF"


def check_rrd(path: Path) -> None:
    """One ArmbridgeError line unless `path` is an existing, non-empty file that starts as a
    Rerun recording (`armbridge view`, `armbridge report`)."""
    if not path.exists():
        raise ArmbridgeError(f"{path}: no such recording")
    if not path.is_file():
        raise ArmbridgeError(f"{path}: is not a file (a recording is an .rrd file)")
    try:
        with path.open("rb") as f:
            head = f.read(4)
    except OSError as exc:
        raise ArmbridgeError(f"{path}: cannot read: {exc.strerror}") from None
    if not head:
        raise ArmbridgeError(f"{path}: is empty (0 bytes), not a recording")
    if not head.startswith(RRD_MAGIC):
        raise ArmbridgeError(f"{path}: is not a Rerun recording (.rrd): it does not start with {RRD_MAGIC.decode()}")
