"""`armbridge flash BOARD --port P`: put the firmware on a board and check that it runs (docs/flash.md).

One entry per board in `TARGETS`; its `kind` picks the procedure in
`FLASHERS` (kind -> "module:function"), so a board of another kind plugs in
as one entry and one module: the MicroPython boards are `micropython`
(`flash.micropython`: mpy-cross, mpremote over the raw REPL, sha256 on the
board, a manifest, reset and HELLO); the Arduino pump board will be `avrdude`
(its Makefile's .hex written through the Mega's stk500v2 bootloader, issue 14
§2), not here yet.
"""
from __future__ import annotations

from armbridge.flash.micropython import MicroPythonTarget

TARGETS: dict[str, MicroPythonTarget] = {
    "esp32": MicroPythonTarget("esp32"),
    "masr_ma": MicroPythonTarget("masr_ma"),
}

FLASHERS = {
    "micropython": "armbridge.flash.micropython:flash_micropython",
}

# Boards the emulator knows that armbridge cannot flash yet, and why (one line).
NOT_YET = {
    "arduino_pump": "the Arduino pump board is flashed with avrdude through its stk500v2 bootloader, "
                    "which armbridge flash does not do yet (issue 14 §2): build it with `make -C firmware/arduino_pump` and write the .hex with avrdude -c wiring",
}
