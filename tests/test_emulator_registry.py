"""Boards as data: the registry, a board variant that plugs in without copying
anything, and the choice of firmware runner (interpreter)."""
import dataclasses
import sys

import pytest

from armbridge.emulator import BOARDS, EmulatedBoard, PlantParams, board_spec
from armbridge.emulator.registry import BoardSpec, ElfFirmware, MicroPythonFirmware, servo_plant
from armbridge.emulator.simhal import SimHal
from armbridge.emulator.url import parse_emu_url
from armbridge.errors import ArmbridgeError
from test_emulator import Lockstep


@pytest.mark.parametrize("make", [
    lambda: board_spec("esp99"),
    lambda: EmulatedBoard("esp99", speed=0),
    lambda: parse_emu_url("emu:esp99?speed=2"),
])
def test_an_unknown_device_names_the_known_ones(make):
    with pytest.raises(ArmbridgeError) as exc:
        make()
    msg = str(exc.value)
    assert "'esp99'" in msg and all(name in msg for name in BOARDS)
    assert "\n" not in msg


@pytest.mark.parametrize("name", sorted(n for n, s in BOARDS.items() if isinstance(s.firmware, MicroPythonFirmware)))
def test_every_registered_board_boots_and_says_who_it_is(name):
    spec = BOARDS[name]
    emu = EmulatedBoard(name, speed=0)
    boot = Lockstep(emu).wait("BOOT", max_s=1.0)
    assert boot[2][0] == spec.identity
    assert emu.n == emu.cfg.N_JOINTS and emu.interpreter == spec.interpreters[0]
    assert emu.tick_us == spec.tick_us and emu.uart.baud == spec.baud and emu.persist.size == spec.persist_bytes


def slow_variant() -> BoardSpec:
    """esp32's firmware, untouched, on servos five times slower and a different start pose."""
    return dataclasses.replace(board_spec("esp32"), name="esp32-slow", description="test only",
                               q0=(0.5, -2.0, 0.3), plant_params=PlantParams(v_servo=1.0))


def move(spec):
    emu = EmulatedBoard(spec, speed=0)
    h = Lockstep(emu)
    first = h.wait("T")
    h.hello(3)
    assert h.request("W", 1, 500, 2000, -1500, 300)[1] == "OK"  # 1.5 rad on joint 1 in 0.5 s
    assert emu.run_until(lambda: h.find("EV", lambda a: a[1] in ("DONE", "FAULT")) is not None, 3.0)
    return emu, h, first


def test_a_board_variant_with_another_plant_plugs_in_without_a_copy():
    fast, _, first = move(board_spec("esp32"))
    assert [int(x) for x in first[2][4:7]] == pytest.approx([1571, -1571, 0], abs=3)  # mid-range start
    assert fast.state == "IDLE" and [(i, v) for _, i, v in fast.executed] == [(1, (2000, -1500, 300))]

    slow, h, first = move(slow_variant())
    # the firmware reads the variant's plant: its start pose, then a servo too slow to follow
    assert [int(x) for x in first[2][4:7]] == pytest.approx([500, -2000, 300], abs=3)
    fault = h.find("EV", lambda a: a[1] == "FAULT")
    assert fault[2][2] == "1" and slow.state == "FAULT" and slow.executed == []
    assert slow.device == "esp32-slow" and "esp32-slow" not in BOARDS  # no registration needed
    assert slow.modules["arm"].__file__ == fast.modules["arm"].__file__  # the same firmware file


def test_the_spec_factories_build_the_plant_and_the_hal():
    seen = {}

    def plant(cfg, params, q0, seed):
        seen["plant"] = (cfg.FW_NAME, params, q0, seed)
        return servo_plant(cfg, params, q0, seed)

    class CountingHal(SimHal):
        def uart_write(self, data):
            seen["written"] = seen.get("written", 0) + len(bytes(data))
            super().uart_write(data)

    spec = dataclasses.replace(board_spec("esp32"), name="esp32-probe", plant=plant, hal=CountingHal,
                               q0=(1.0, -1.0, 0.0))
    emu = EmulatedBoard(spec, speed=0, seed=5)
    assert seen["plant"] == ("arm3r", None, (1.0, -1.0, 0.0), 5)
    assert isinstance(emu.hal, CountingHal)
    emu.run_for(0.1)
    assert seen["written"] == len(emu.read_output()) > 0  # every byte the board sent went through the HAL


def test_interpreter_choice_is_checked():
    with pytest.raises(ArmbridgeError, match=r"'pypy' cannot run the esp32 firmware.*cpython, micropython"):
        EmulatedBoard("esp32", speed=0, interpreter="pypy")
    with pytest.raises(ArmbridgeError, match=r"interpreter.*'pypy'.*cpython, micropython"):
        parse_emu_url("emu:esp32?interpreter=pypy")
    assert parse_emu_url("emu:esp32?interpreter=micropython")[1] == {"interpreter": "micropython"}


def test_an_elf_board_is_data_too_and_says_what_it_lacks(tmp_path):
    (tmp_path / "pump").mkdir()
    (tmp_path / "pump" / "Makefile").write_text("all:\n\t@true\n")   # builds nothing
    pump = BoardSpec(name="pump", description="syringe pump (AVR)", identity="pump",
                     firmware=ElfFirmware(folder="pump", elf="build/pump.elf"))
    assert pump.interpreters == ("simavr",)
    with pytest.raises(ArmbridgeError, match="did not produce build/pump.elf|avr-gcc is missing"):
        EmulatedBoard(pump, speed=0, firmware_root=tmp_path)


def test_micropython_missing_is_one_clear_error(monkeypatch):
    monkeypatch.setitem(sys.modules, "armbridge.emulator.micropython", None)  # as if the module were absent
    with pytest.raises(ArmbridgeError, match=r"armbridge.emulator.micropython.*--interpreter cpython"):
        EmulatedBoard("esp32", speed=0, interpreter="micropython")


def test_interpreter_micropython_routes_to_the_micropython_runner():
    from armbridge.emulator import micropython as mp

    try:
        emu = EmulatedBoard("esp32", speed=0, interpreter="micropython")
    except mp.BridgeError as exc:  # node or the npm package missing: a setup problem
        from require import missing
        missing(str(exc))
    try:
        assert type(emu.runner) is mp.MicroPythonRunner and emu.interpreter == "micropython"
        assert emu.modules == {}  # the firmware's modules live in the MicroPython process
        assert Lockstep(emu).wait("BOOT", max_s=1.0)[2] == ["arm3r", "0.1.0", "2", "IDLE"]
    finally:
        emu.stop()
