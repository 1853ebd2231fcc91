"""A memory for the index and maintenance tests: HashingSpace, a 64-d "motion" VectorSense
(random vectors spread well, unlike text), and the given index thresholds."""

from __future__ import annotations

from pathlib import Path

from tactus_memory.adapters.vectors import VectorSense
from tactus_memory.memory.main import Memory
from tactus_memory.storage.tables import IndexConfig
from tests.helpers.fakes import HashingSpace

#: the motion sense's vector size (each item: (MOTION_DIM,) float32)
MOTION_DIM = 64


def motion_memory(path: Path, index: IndexConfig, *, background: bool) -> Memory:
    """A fresh memory at ``path`` with ``index`` thresholds and the motion sense registered."""
    mem = Memory.open(str(path), space=HashingSpace(), index=index, background=background)
    mem.add_sense(VectorSense("motion", dim=MOTION_DIM))
    return mem
