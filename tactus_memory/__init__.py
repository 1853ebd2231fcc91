"""tactus-memory: a robot memory in which touch is a first-class, language-searchable sense.

Public names load lazily so ``import tactus_memory`` stays cheap (no torch, no LanceDB).
"""

from __future__ import annotations

from typing import Any

__version__ = "0.1.0"

_LAZY = {
    "Memory": "tactus_memory.memory.main",
    "Client": "tactus_memory.client.main",
    "Hit": "tactus_memory.results",
    "Sense": "tactus_memory.senses.base",
    "TextSense": "tactus_memory.adapters.text",
    "ImageSense": "tactus_memory.adapters.image",
    "VectorSense": "tactus_memory.adapters.vectors",
    "Space": "tactus_memory.spaces.base",
    "MiniLMSpace": "tactus_memory.spaces.minilm",
    "Qwen3VLSpace": "tactus_memory.spaces.qwen3vl",
    # the touch sense (imports torch when first used, not on ``import tactus_memory``)
    "TactusEncoder": "tactus_memory.adapters.touch",
}

__all__ = ["__version__", *_LAZY]


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        import importlib

        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'tactus_memory' has no attribute {name!r}")
