"""How a touch window from HTTP becomes the item the touch sense takes.

Windows arrive in raw sensor units by default; ``calibrated=true`` says they are already
calibrated. The touch sense decides what that means (see ``TactusEncoder``); this module is
the one place the service tells it.
"""

from __future__ import annotations

from typing import Any

import numpy as np


def touch_item(memory: Any, sense: str, window: np.ndarray, calibrated: bool) -> Any:
    """One (K, 32, 32) float32 window -> the item ``memory.add(..., sense, item)`` takes."""
    s = memory.senses.get(sense)
    make = getattr(s, "make_item", None)
    if make is not None:
        return make(window, calibrated=calibrated)
    return window
