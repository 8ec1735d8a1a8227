"""`armbridge flash BOARD --port P`: put the firmware on a board and check that it runs (docs/flash.md).

One entry per board in `TARGETS`; its `kind` picks the procedure in
`FLASHERS` (kind -> "module:function"), so a board of another kind plugs in
as one entry and one module: the MicroPython boards are `micropython`
(`flash.micropython`: mpy-cross, mpremote over the raw REPL, sha256 on the
board, a manifest, reset and HELLO); the Arduino pump board is `avrdude`
(`flash.avrdude`: its Makefile's .hex written and verified through the Mega's
stk500v2 bootloader, then HELLO, issue 14 §2).
"""
from __future__ import annotations

from typing import Union

from armbridge.flash.avrdude import AvrTarget
from armbridge.flash.micropython import MicroPythonTarget

TARGETS: dict[str, Union[MicroPythonTarget, AvrTarget]] = {
    "esp32": MicroPythonTarget("esp32"),
    "masr_ma": MicroPythonTarget("masr_ma"),
    "arduino_pump": AvrTarget("arduino_pump"),
}

FLASHERS = {
    "micropython": "armbridge.flash.micropython:flash_micropython",
    "avrdude": "armbridge.flash.avrdude:flash_avrdude",
}

# Boards the emulator knows that armbridge cannot flash yet, and why (one line).
NOT_YET: dict[str, str] = {}
