"""Optional dependencies (pyproject's extras): one line naming the extra when one is missing.

The runtime (emulate, run, demo, plan, smm --method learned) needs none of them;
torch, onnx and scipy are the `train` extra, used by training and by the
nullspace SMM ground truth.
"""
from __future__ import annotations

import importlib
from types import ModuleType

from armbridge.errors import ArmbridgeError


def require(module: str, extra: str, what: str) -> ModuleType:
    """Import `module`, or raise an ArmbridgeError: "<what> needs the <extra> extra: pip install ...".

    Only the missing module itself is translated: an ImportError from inside an
    installed package is a real fault and propagates.
    """
    try:
        return importlib.import_module(module)
    except ModuleNotFoundError as exc:
        if exc.name is None or module.split(".")[0] != exc.name.split(".")[0]:
            raise
        raise ArmbridgeError(f"{what} needs the {extra} extra: pip install 'armbridge[{extra}]'") from None
