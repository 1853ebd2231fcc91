"""File hashing shared by the data fetcher, checkpoints and evaluation (torch-free)."""

from __future__ import annotations

import hashlib
import os

#: read size when hashing a file (1 MiB: a few reads for a checkpoint, bounded memory)
READ_BYTES = 1 << 20


def file_sha256(path: str | os.PathLike[str]) -> str:
    """Hex sha256 of a file's bytes, read in ``READ_BYTES`` blocks."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(READ_BYTES), b""):
            h.update(block)
    return h.hexdigest()
