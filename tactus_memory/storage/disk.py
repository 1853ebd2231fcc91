"""Disk accounting: what a table's files take on disk (live data, old versions, indexes),
measured for ``tactus maintain``'s report and the disk benchmarks."""

from __future__ import annotations

import contextlib
import math
import os
from dataclasses import dataclass

from tactus_memory.storage.compaction import fragment_infos


# --------------------------------------------------------------------------- measuring
@dataclass
class Footprint:
    """Disk use of one local table: everything on disk vs what the latest version needs."""

    disk_bytes: int
    live_bytes: int
    versions: int
    fragments: int
    rows: int

    @property
    def ratio(self) -> float:
        return self.disk_bytes / self.live_bytes if self.live_bytes else math.inf


def dir_bytes(path: str) -> int:
    total = 0
    for root, _dirs, files in os.walk(path):
        for name in files:
            with contextlib.suppress(OSError):  # removed while walking (cleanup ran)
                total += os.path.getsize(os.path.join(root, name))
    return total


def footprint(table_path: str) -> Footprint:
    """Footprint of a local Lance table directory. Live bytes: the data files, deletion
    files and index files the latest version references (manifests not counted)."""
    import lance

    ds = lance.dataset(table_path)
    frags = fragment_infos(ds)
    live = sum(f.bytes for f in frags)
    live += sum(int(ix.total_size_bytes or 0) for ix in ds.describe_indices())
    versions_dir = os.path.join(table_path, "_versions")
    n_versions = len(os.listdir(versions_dir)) if os.path.isdir(versions_dir) else 0
    return Footprint(
        dir_bytes(table_path), live, n_versions, len(frags), sum(f.rows - f.deleted for f in frags)
    )
