"""The MicroPython side of `--interpreter micropython` (docs/emulator.md).

Not imported by the emulator itself: `bridge.mjs` (a Node script) loads the
MicroPython WebAssembly interpreter, copies the firmware folders and the
MicroPython modules of this folder into its filesystem and serves the lockstep
line protocol of `armbridge.emulator.micropython`:

* `bridgehal.py`: the HAL the firmware sees there (time, UART, positions,
  outputs, persisted memory held as plain values that one round trip per
  emulator tick fills and drains) and the step functions `bridge.mjs` calls.
* `bridgerigs.py`: the HALs of the other rigs on the same protocol: the MASR
  actuator's (counts and hall edges in, loco/rot/grip out) and the PCA9685
  rig's (the firmware's own driver on a bridged I2C bus).
* `fwcost.py`: the firmware cost measurement (`armbridge bench firmware`); it
  runs unchanged under MicroPython and under CPython, for comparison;
  `fwcost_mp.py` is its entry under MicroPython (bridge.mjs, with the heap marks).
"""
