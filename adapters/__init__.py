"""The sense adapters, installed as ``tactus_memory.adapters``: one file per sense, each an
implementation of the contract in :mod:`tactus_memory.senses.base` registered under its name
(``text``, ``image``, ``vector``, ``touch``), plus ``decode`` for the ROS 2 messages they
read from recordings. ``touch.TactusEncoder`` imports torch; the others need no model of their own.
"""

from typing import Any

__all__ = ["TactusEncoder"]


def __getattr__(name: str) -> Any:
    """``from tactus_memory.adapters import TactusEncoder``, loaded on first use (torch)."""
    if name == "TactusEncoder":
        from tactus_memory.adapters.touch import TactusEncoder

        return TactusEncoder
    raise AttributeError(f"module 'tactus_memory.adapters' has no attribute {name!r}")
