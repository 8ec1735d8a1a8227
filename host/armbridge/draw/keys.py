"""Pause and resume from the keyboard: moved to executor/keys.py (below draw in the layer
contract, so that `armbridge run` uses it too); kept here for its importers."""
from __future__ import annotations

from armbridge.executor.keys import POLL_S, TOGGLE_KEYS, PauseKeys, is_toggle

__all__ = ["POLL_S", "TOGGLE_KEYS", "PauseKeys", "is_toggle"]
