"""Plug-in senses, installed as ``tactus_memory.adapters``: ``adapters.touch.TactusEncoder``
(the touch sense; importing it imports torch). The senses that need no model of their own
(text, image, precomputed vectors) live in :mod:`tactus_memory.senses`.
"""

from typing import Any

__all__ = ["TactusEncoder"]


def __getattr__(name: str) -> Any:
    """``from tactus_memory.adapters import TactusEncoder``, loaded on first use (torch)."""
    if name == "TactusEncoder":
        from tactus_memory.adapters.touch import TactusEncoder

        return TactusEncoder
    raise AttributeError(f"module 'tactus_memory.adapters' has no attribute {name!r}")
