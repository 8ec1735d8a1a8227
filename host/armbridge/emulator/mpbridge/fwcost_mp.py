"""The MicroPython entry of `armbridge bench firmware` (bridge.mjs, mode "bench:"):
fwcost.py's items run one call each from JS, the heap measured between them
(MicroPython only: it reads gc.mem_alloc() and imports jsclock, which bridge.mjs
registers)."""

import gc

import bridgehal  # type: ignore[import-not-found]
import fwcost  # type: ignore[import-not-found]

_heap: dict = {}
_heap_items: list = []
_bench_items: tuple = ()


def heap_mark(what):
    """The heap in use now (bridge.mjs calls it after a collection, in a call of its own):
    `base` with the bridge's modules loaded, before the firmware is imported;
    `after_boot`, `after_run`: less `base`, the firmware's (and the bench's few objects)."""
    used = gc.mem_alloc()
    _heap[what] = used if what == "base" else used - _heap["base"]
    if what == "after_run":
        fwcost.result()["heap_live_after_bench"] = used


def heap_mark_item():
    """heap_mark after each item, in item order (no name: a string in the call's source
    would be interned for good and counted in the live heap)."""
    _heap_items.append(gc.mem_alloc() - _heap["base"])


def mp_start(params):
    """params: JSON {"reps": N, "rig": R} -> JSON list of item names."""
    import json

    import jsclock  # type: ignore[import-not-found]

    p = json.loads(params)
    cfg = __import__(bridgehal._modules[1])
    board_mod = __import__(bridgehal._modules[0])
    proto = __import__("proto")
    protodef = __import__("protodef")
    global _bench_items
    _bench_items = fwcost.start(board_mod.Board, cfg, proto, protodef.PROTOCOL_VERSION, jsclock.us, int(p["reps"]),
                         p.get("rig", "arm"))
    return json.dumps(list(_bench_items))


def mp_run(name):
    """One item -> JSON [group, name, stats]; kept by bridge.mjs, not in this heap."""
    import json

    group, st = fwcost.measure(name)
    return json.dumps([group, name, st])


def mp_result():
    """The heap marks (heap_mark) and what the interpreter is."""
    import json
    import sys

    result = fwcost.result()
    _heap["after_each_item"] = dict(zip(_bench_items, _heap_items))
    result["heap"] = _heap
    result["interpreter"] = "MicroPython %d.%d.%d (WebAssembly)" % sys.implementation.version[:3]
    return json.dumps(result)
