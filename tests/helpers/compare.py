"""Comparing answers computed in two processes: equal, floats within a slack."""

from __future__ import annotations

from typing import Any


def alike(a: Any, b: Any, slack: float) -> bool:
    """``a == b`` for JSON-like answers, floats within ``slack`` of each other (a score
    computed in two processes can differ in its last bits, or fall on either side of a
    rounding boundary)."""
    if isinstance(a, float) and isinstance(b, float):
        return abs(a - b) <= slack
    if isinstance(a, dict) and isinstance(b, dict):
        return a.keys() == b.keys() and all(alike(a[k], b[k], slack) for k in a)
    if isinstance(a, list) and isinstance(b, list):
        return len(a) == len(b) and all(alike(x, y, slack) for x, y in zip(a, b, strict=True))
    return bool(a == b)
