"""Small stand-ins injected at the space seam for fast unit tests (the real path is tested too)."""

from __future__ import annotations

import hashlib
import re
from collections.abc import Sequence

import numpy as np

from tactus_memory.spaces.base import Space


class HashingSpace(Space):
    """Bag-of-words hashing embedder: texts sharing words get a high cosine. Deterministic."""

    def __init__(self, dim: int = 64, name: str = "fake-hash") -> None:
        self.dim = dim
        self.name = name
        self.calls = 0

    def embed_texts(self, texts: Sequence[str], *, query: bool = False) -> np.ndarray:
        self.calls += 1
        out = np.zeros((len(texts), self.dim), dtype=np.float32)
        for i, text in enumerate(texts):
            for word in re.findall(r"[a-z0-9]+", text.lower()):
                h = int.from_bytes(hashlib.sha1(word.encode()).digest()[:4], "little")
                out[i, h % self.dim] += 1.0 if (h >> 31) & 1 else -1.0
            out[i, -1] += 0.1  # never all-zero
        return out / np.linalg.norm(out, axis=1, keepdims=True)
