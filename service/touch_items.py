"""How a touch window from HTTP becomes the item the touch sense takes.

Windows arrive in raw sensor units by default; ``calibrated=true`` says they are already
calibrated (0-1). The service converts every window to float32, which would leave the touch
sense's auto-detection to guess (float values in [0, 1] would pass as calibrated), so the
flag is applied here, explicitly: a sense whose ``validate`` takes ``calibrated=`` (the
``TactusEncoder``) validates and calibrates the window now, with the client's flag (raw
values in [0, 1] are then a ``DynamicRangeError``, 422), and the memory receives the
calibrated window, which its own validation recognises as calibrated.
"""

from __future__ import annotations

import inspect
from functools import lru_cache
from typing import Any

import numpy as np


@lru_cache(maxsize=32)
def _takes_calibrated(validate_func: Any) -> bool:
    try:
        return "calibrated" in inspect.signature(validate_func).parameters
    except (TypeError, ValueError):
        return False


def touch_item(memory: Any, sense: str, window: np.ndarray, calibrated: bool) -> Any:
    """One (K, 32, 32) float32 window -> the item ``memory.add(..., sense, item)`` takes."""
    s = memory.senses.get(sense)
    if s is not None and _takes_calibrated(type(s).validate):
        return s.validate(window, calibrated=calibrated)
    return window
