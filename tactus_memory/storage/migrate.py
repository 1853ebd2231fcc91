"""A store made before sense codes moved, in place, to the coded layout
(:mod:`tactus_memory.storage.codes`): each row's ``vector`` rewritten as ``[v, c(sense)]``,
so a search within one sense gets the codes' fast path (``tactus maintain --sense-codes``).

Only the vector column is written again; every other column and every row (ids, times,
places, provenance, raw inputs) stays as it is, in the same data files. Three Lance
schema-evolution commits, each atomic:

1. **Coding** (``add_columns``): the coded vectors are computed batch by batch
   (``MIGRATE_BATCH`` rows at a time, memory bounded) from each fragment's ``vector`` and
   ``sense`` and written as new data files of a column ``STAGED``; one commit adds it. The
   long step: killed before its commit, it leaves only files no version names (removed by
   maintenance's orphan sweep) and the store as it was.
2. **The swap** (``alter_columns``, one commit): ``vector`` renamed ``RETIRED`` and
   ``STAGED`` renamed ``vector``. Readers see the version before it (the old layout) or the
   one after (the coded one), never a mix.
3. ``RETIRED`` dropped (``drop_columns``); the old ANN index goes with it.

Then, when the store had an ANN index, it is built again on the coded rows
(:meth:`~tactus_memory.storage.indexes.StoreIndexes.build_indexes`), which re-measures the
probes each sense needs.

A process killed between two of these commits leaves the old layout with ``STAGED`` beside
it, or the coded one with ``RETIRED`` beside it (both searchable; writes are refused, as a
written row lacks that column), or the coded layout without its ANN index (searched exactly
until built): running the migration again finishes it from there.

Writers: this process's commits wait (the store's commit lock, its maintenance lock). A
commit of another process between the reading of the rows and a commit above makes Lance
refuse that commit (``CommitConflictError``; nothing lost, run it again); a process that
opened the store before the swap still holds the old layout and must be restarted. So run
it with the store's servers stopped.
"""

from __future__ import annotations

import json
import logging
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from tactus_memory.errors import NotFoundError
from tactus_memory.storage.codes import CODE_DIMS, codes_of, with_codes
from tactus_memory.storage.tables import items_schema

if TYPE_CHECKING:
    import pyarrow as pa

    from tactus_memory.storage.store import Store

log = logging.getLogger(__name__)

#: the coded vectors' column while they are written (step 1), until the swap
STAGED = "vector_coded"
#: the old vectors' column between the swap and its drop
RETIRED = "vector_uncoded"
#: rows read, coded and written per batch: 8192 x (384 + 16) float32 is 13 MB
MIGRATE_BATCH = 8192


@dataclass
class CodesReport:
    """What :func:`add_sense_codes` did. ``migrated``: the vectors were rewritten (False: the
    store had codes already; ``finished`` then names any step an interrupted run left, done
    now); ``rows``: rows rewritten; ``seconds``: the whole run, ``index_seconds`` of it
    building the ANN index again (``index_rebuilt``)."""

    uri: str
    migrated: bool
    codes: int
    rows: int
    seconds: float
    index_rebuilt: bool
    index_seconds: float = 0.0
    finished: list[str] | None = None

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)


def coded_field(dim: int) -> pa.Field:
    """The coded vector field of a ``dim`` store, named ``STAGED`` (its metadata records the
    codes, :func:`~tactus_memory.storage.codes.codes_of`)."""
    return items_schema(dim, CODE_DIMS).field("vector").with_name(STAGED)


def stage(ds: Any, dim: int, on_batch: Callable[[int], None] | None = None) -> None:
    """Step 1: the coded vectors of every row of the lance dataset ``ds`` (at the version
    read) added as the column ``STAGED``, in one commit. ``on_batch(rows)``: after each
    batch is coded (rows so far; progress)."""
    import lance
    import pyarrow as pa

    field = coded_field(dim)
    schema = pa.schema([field])
    done = 0

    @lance.batch_udf(output_schema=schema)
    def code_rows(batch: pa.RecordBatch) -> pa.RecordBatch:
        nonlocal done
        vectors = np.asarray(batch.column("vector").flatten(), np.float32).reshape(-1, dim)
        senses = batch.column("sense").to_numpy(zero_copy_only=False)
        coded = with_codes(vectors, senses, CODE_DIMS)
        flat = pa.array(coded.reshape(-1), pa.float32())
        column = pa.FixedSizeListArray.from_arrays(flat, dim + CODE_DIMS)
        done += batch.num_rows
        if on_batch is not None:
            on_batch(done)
        return pa.RecordBatch.from_arrays([column], schema=schema)

    ds.add_columns(code_rows, read_columns=["vector", "sense"], batch_size=MIGRATE_BATCH)


def swap(ds: Any) -> None:
    """Step 2, one commit: ``vector`` becomes ``RETIRED``, ``STAGED`` becomes ``vector``."""
    ds.alter_columns({"path": "vector", "name": RETIRED}, {"path": STAGED, "name": "vector"})


def _staged_ok(field: pa.Field, dim: int) -> bool:
    """Whether a ``STAGED`` column left by an interrupted run is what step 1 writes now."""
    want = coded_field(dim)
    return field.type == want.type and codes_of(field) == CODE_DIMS


def _rebuild(store: Store, report: CodesReport) -> None:
    """The ANN index built again on the coded rows (its probes measured anew)."""
    t1 = time.perf_counter()
    store.build_indexes()
    report.index_rebuilt = True
    report.index_seconds = round(time.perf_counter() - t1, 3)


def add_sense_codes(store: Store, *, on_batch: Callable[[int], None] | None = None) -> CodesReport:
    """Move ``store`` (made before sense codes) to the coded layout in place, and build its
    ANN index again if it had one (the module docstring says how, and what a crash leaves).
    A store with codes already is left as it is (``migrated`` False), bar finishing what an
    interrupted run left. ``on_batch(rows)``: progress of the coding step.

    Raises NotFoundError when the store has no items table, StoreDamagedError when it fails
    its integrity check, and Lance's CommitConflictError when another process committed to
    the items table meanwhile (nothing changed; run it again)."""
    t0 = time.perf_counter()
    if not store.exists:
        raise NotFoundError(f"no memory at {store.uri!r} (no items table)")
    store.integrity.require()
    report = CodesReport(store.uri, False, codes=0, rows=0, seconds=0.0, index_rebuilt=False)
    finished: list[str] = []
    # no maintenance pass (compaction, index refresh) and no write of this process between
    # the reading of the rows and the commits: each would make a commit conflict
    with store._maintenance, store.commit_lock:
        store.reread_layout()
        ds = store.items.to_lance()
        names = ds.schema.names
        vector = ds.schema.field("vector")
        codes = codes_of(vector)
        dim = vector.type.list_size - codes
        had_index = store.has_vector_index()
        if not codes:
            staged = ds.schema.field(STAGED) if STAGED in names else None
            if staged is not None and not _staged_ok(staged, dim):
                ds.drop_columns([STAGED])  # another layout's leftover: coded again
                staged = None
            if staged is None:
                stage(ds, dim, on_batch)
            else:
                finished.append(f"coded vectors staged before (column {STAGED})")
            swap(ds)
            report.migrated, report.rows = True, ds.count_rows()
            names = ds.schema.names
        if RETIRED in names:
            ds.drop_columns([RETIRED])
            if not report.migrated:
                finished.append(f"old vectors dropped (column {RETIRED})")
        store.reread_layout()
        report.codes = store.codes()
    # the index the store had (dropped with the old vectors), or one an interrupted run
    # dropped before building it again (the store's index record says there was one)
    dropped = store.get_meta("index") is not None and not store.has_vector_index()
    if (report.migrated and had_index) or dropped:
        with store._maintenance:
            _rebuild(store, report)
        if not report.migrated:
            finished.append("ANN index built on the coded vectors")
    report.finished = finished or None
    report.seconds = round(time.perf_counter() - t0, 3)
    log.info("sense codes: %s", json.dumps(report.as_dict()))
    return report
