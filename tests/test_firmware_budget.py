"""The MicroPython boards' memory against the budgets kept in firmware/budgets.json.

Each board's firmware runs `armbridge bench firmware`'s items under the real
MicroPython interpreter (the WebAssembly port, by Node) at the budget file's
repetitions; its live heap after the run and the most heap one control tick
allocates must stay within the board's budget. Allocation and live heap are
counted by the interpreter's own gc.mem_alloc(), not timed, so they repeat
run to run (to a few bytes) on any machine: a board that grows past its budget
fails here, whatever the machine's load. Without Node or the package the test
skips, or fails under ARMBRIDGE_REQUIRE_HIL=1 (tests/require.py).
"""
from __future__ import annotations

import json
from pathlib import Path

import pytest

from armbridge.bench import firmware_cost
from require import require_micropython

BUDGETS = Path(__file__).resolve().parents[1] / "firmware" / "budgets.json"


def budgets() -> dict:
    return json.loads(BUDGETS.read_text())


def test_every_micropython_board_has_a_budget():
    assert set(budgets()["boards"]) == set(firmware_cost.TARGETS)


@pytest.mark.parametrize("key", sorted(firmware_cost.TARGETS))
def test_the_firmware_stays_within_its_memory_budget(key):
    require_micropython()
    doc = budgets()
    budget = doc["boards"][key]
    mp = firmware_cost.under_micropython(key, int(doc["reps"]))
    m = firmware_cost.memory(mp)
    live, alloc = m["live_heap_after_run_bytes"], m["alloc_per_tick_bytes"]
    assert live > 20_000 and alloc > 0, m   # a measurement, not a zero that passes any budget
    assert live <= budget["max_live_heap_bytes"], (
        f"{key}: the firmware's live heap after the bench is {live:,} bytes, over its budget of "
        f"{budget['max_live_heap_bytes']:,} (firmware/budgets.json)")
    assert alloc <= budget["max_alloc_per_tick_bytes"], (
        f"{key}: a control tick allocates {alloc:,} bytes, over its budget of "
        f"{budget['max_alloc_per_tick_bytes']:,} (firmware/budgets.json): {mp['ticks']}")
    assert m["headroom_bytes"] == firmware_cost.CHIP_FREE_HEAP - live
