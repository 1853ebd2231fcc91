"""Files no version references: what a writer killed mid-transaction leaves behind.

A Lance write (an append, a compaction, an index build) writes its data, deletion or index
files first and commits a manifest naming them last. A process killed between the two
(``kill -9`` of ``tactus maintain`` during a compaction) leaves files that no version
references: a compaction's output holds the rows it rewrote, deleted ones' neighbours and,
before the rewrite committed, rows deleted since, so erasure must remove them. Version
cleanup never does (it removes what *removed versions* referenced; Lance's own rule for
unreferenced files waits 7 days, and its ``delete_unverified`` removes them at any age,
which would delete the files of a writer that is mid-commit right now).

The rule (:func:`remove_orphans`, run by maintenance after version cleanup): a file under a
table's ``data/`` or ``_deletions/``, or an index folder under ``_indices/``, is removed when
no version still on disk references it **and** it was last modified more than
``grace_seconds`` ago (:data:`ORPHAN_GRACE_S` by default). The grace is longer than any
write transaction could take, so a file that young may belong to a writer mid-commit and
is kept; an older unreferenced file can only be a crashed writer's. The directory is listed
*before* the versions are read, so a commit that lands meanwhile either references files
already referenced by the version it supersedes (read too) or new, young ones.

Local tables only (an object store is left alone: its listing has no cheap mtime rule here).
"""

from __future__ import annotations

import logging
import os
import shutil
import time
from dataclasses import dataclass

from tactus_memory.policies import ORPHAN_GRACE_S

log = logging.getLogger(__name__)


#: least seconds between two sweeps of one table (each reads every kept manifest); the first
#: cleanup of a process always sweeps, so a maintainer restarted after a crash does at once
SWEEP_INTERVAL_S = 600.0

#: the folders of a table that hold row data (files) and index data (one folder per index)
FILE_DIRS = ("data", "_deletions")
INDEX_DIR = "_indices"


@dataclass
class OrphanSweep:
    """What one sweep removed (and kept because it was too young)."""

    removed: int = 0
    bytes_removed: int = 0
    young: int = 0


def local_path(uri: str) -> str | None:
    """The local directory of a table URI, or None for an object store."""
    if uri.startswith("file://"):
        return uri[len("file://") :]
    return None if "://" in uri else uri


def _candidates(root: str) -> dict[str, tuple[float, int]]:
    """Every data/deletion file and index folder of the table: relative path -> (mtime,
    bytes). An index folder's mtime is its newest file's (a build writes into it)."""
    out: dict[str, tuple[float, int]] = {}
    for sub in FILE_DIRS:
        top = os.path.join(root, sub)
        for dirpath, _dirs, files in os.walk(top):
            for name in files:
                path = os.path.join(dirpath, name)
                try:
                    st = os.stat(path)
                except OSError:
                    continue  # removed meanwhile
                out[os.path.relpath(path, root)] = (st.st_mtime, st.st_size)
    top = os.path.join(root, INDEX_DIR)
    for name in os.listdir(top) if os.path.isdir(top) else []:
        folder = os.path.join(top, name)
        newest, size = 0.0, 0
        for dirpath, _dirs, files in os.walk(folder):
            for fname in files:
                try:
                    st = os.stat(os.path.join(dirpath, fname))
                except OSError:
                    continue
                newest, size = max(newest, st.st_mtime), size + st.st_size
        newest = max(newest, os.stat(folder).st_mtime) if os.path.exists(folder) else newest
        out[os.path.join(INDEX_DIR, name)] = (newest, size)
    return out


def referenced(uri: str, storage_options: dict[str, str] | None = None) -> set[str]:
    """Relative paths of the data files, deletion files and index folders that any version
    still on disk references."""
    import lance

    latest = lance.dataset(uri, storage_options=storage_options or None)
    refs: set[str] = set()
    for v in latest.versions():
        ds = latest.checkout_version(int(v["version"]))
        for frag in ds.get_fragments():
            meta = frag.metadata
            for f in meta.files:
                refs.add(os.path.normpath(os.path.join("data", f.path)))
            if meta.deletion_file is not None:
                refs.add(os.path.normpath(meta.deletion_file.path(int(meta.id))))
        for desc in ds.describe_indices():
            for seg in desc.segments:
                refs.add(os.path.join(INDEX_DIR, str(seg.uuid)))
    return refs


def remove_orphans(
    uri: str,
    storage_options: dict[str, str] | None = None,
    grace_seconds: float = ORPHAN_GRACE_S,
) -> OrphanSweep:
    """Remove the table's unreferenced files older than ``grace_seconds`` (module doc).
    Run by the one maintainer, after version cleanup, never concurrently with it."""
    sweep = OrphanSweep()
    root = local_path(uri)
    if root is None or not os.path.isdir(root):
        return sweep
    listed = _candidates(root)  # first: see the module doc
    refs = referenced(uri, storage_options)
    cutoff = time.time() - grace_seconds
    for rel, (mtime, size) in sorted(listed.items()):
        if rel in refs:
            continue
        if mtime > cutoff:
            sweep.young += 1  # may be a writer's, mid-commit
            continue
        path = os.path.join(root, rel)
        try:
            if os.path.isdir(path):
                shutil.rmtree(path)
            else:
                os.remove(path)
        except FileNotFoundError:
            continue
        sweep.removed += 1
        sweep.bytes_removed += size
        log.info("removed %s of %s: no version references it (a crashed writer's)", rel, uri)
    return sweep
