"""A missing tool skips a test on a developer's machine but fails it in CI."""
import os

import pytest


def missing(reason: str) -> None:
    """Skip with `reason`, or fail when ARMBRIDGE_REQUIRE_HIL=1 (CI): nothing a
    user would meet may be skipped there."""
    if os.environ.get("ARMBRIDGE_REQUIRE_HIL") == "1":
        pytest.fail(reason + " (ARMBRIDGE_REQUIRE_HIL=1)")
    pytest.skip(reason, allow_module_level=True)


def require_micropython() -> None:
    """Node and the MicroPython WebAssembly package the emulated boards' interpreter
    mode needs, or `missing` (skip here, fail in CI)."""
    import shutil

    from armbridge.emulator.micropython import find_micropython
    from armbridge.errors import ArmbridgeError

    if shutil.which("node") is None:
        missing("node is not installed (the MicroPython interpreter mode needs Node.js)")
    try:
        find_micropython()
    except ArmbridgeError as exc:
        missing(str(exc))
