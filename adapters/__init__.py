"""Plug-in senses, installed as ``tactus_memory.adapters``.

``TactusEncoder`` (touch) loads lazily so importing this package does not import torch.
"""

from __future__ import annotations

from typing import Any

from tactus_memory.senses import ImageSense, VectorSense

__all__ = ["TactusEncoder", "ImageSense", "VectorSense"]


def __getattr__(name: str) -> Any:
    if name == "TactusEncoder":
        from tactus_memory.adapters.touch import TactusEncoder

        return TactusEncoder
    raise AttributeError(name)
