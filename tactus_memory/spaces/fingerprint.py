"""A cheap fingerprint of a local model folder: which model it is, not where it lives.

sha256 over ``config.json`` (whole) and, for every weight file (``*.safetensors``, ``*.bin``,
sorted by name), its name, its size and its first and last MiB. The first MiB of a
safetensors file holds its header (tensor names, shapes, offsets) and the first tensors'
bytes, the last MiB the last tensors' bytes: two folders with the same architecture but other
weights (another seed, a fine-tune) differ there, and reading 2 MiB per file costs
milliseconds even for the 4 GB Qwen3-VL-Embedding-2B file.
"""

from __future__ import annotations

import hashlib
import os
from pathlib import Path

#: bytes read from each end of a weight file
EDGE_BYTES = 1 << 20
WEIGHT_PATTERNS = ("*.safetensors", "*.bin")
FINGERPRINT_CHARS = 16  # 64 bits of sha256: plenty to tell model folders apart


def model_fingerprint(path: str | os.PathLike[str]) -> str:
    """The fingerprint of a model folder (16 hex chars). Raises FileNotFoundError when the
    folder has no config.json."""
    folder = Path(path)
    config = folder / "config.json"
    h = hashlib.sha256()
    h.update(b"config.json\0")
    h.update(config.read_bytes())
    weights = sorted({p for pattern in WEIGHT_PATTERNS for p in folder.glob(pattern)})
    for weight in weights:
        size = weight.stat().st_size
        h.update(f"\0{weight.name}\0{size}\0".encode())
        with weight.open("rb") as f:
            h.update(f.read(EDGE_BYTES))
            if size > EDGE_BYTES:
                f.seek(max(EDGE_BYTES, size - EDGE_BYTES))
                h.update(f.read(EDGE_BYTES))
    return h.hexdigest()[:FINGERPRINT_CHARS]
