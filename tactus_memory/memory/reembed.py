"""Re-embedding what is stored: every vector of a sense recomputed by a new encoder from the
stored raw input (``memory.reembed("touch", TactusEncoder(NEW))``, ``tactus reembed``).

How it stays safe:

1. **Staging, in batches.** New vectors are computed ``batch`` rows at a time and appended to
   a staging table ``reembed_<sense>`` (id, vector, tag) in the same LanceDB database, one
   commit per batch. ``tag`` is a hash of the new encoder's provenance (its checkpoint sha256
   for touch): a rerun with the same encoder skips every staged id, so a killed run resumes
   where it stopped; a rerun with another encoder drops the stale staging table first.
2. **One swap.** When every row is staged, the vectors go into the items table in ONE
   merge-insert commit on ``id`` (under the memory's write lock; rows written meanwhile are
   embedded first). A reader (this process or a replica) sees the version before that
   commit, every row the old encoder's, or the one after, every row the new one's: never a
   mix. Rows deleted meanwhile are simply not matched. Writes from *other processes* are
   not under this lock: run it where the store's writer runs (the service's process, or with
   the service stopped), else rows another process adds during the swap keep the old vectors
   (a rerun then redoes them).
3. **Provenance.** The sense's registration (provenance with the checkpoint sha256, query
   centroid) is replaced by the new encoder's right after the swap and its score calibration
   re-estimated; the provenance is per sense (no row carries its own), so after the swap
   every row's vector is the recorded checkpoint's. A kill between the swap and this step is
   mended by the rerun (the swap is idempotent).
4. **Servers already running on the store.** Every commit checks that the encoder that
   embedded its rows is the one the store records for their sense (the registration re-read
   at its latest version, ``SenseRegistry.check_embedded_by``): after a swap, a server
   still holding the old encoder refuses those writes (SenseSwappedError, HTTP 409
   ``sense-swapped``, nothing stored) and rebuilds the sense from the store's record (the
   new checkpoint), so the write sent again is embedded by the new encoder. Rows such a
   server committed between the swap and the new registration are embedded again right
   after the registration.
5. **Rows that cannot be redone.** A row whose raw input was not kept (no ``raw``, no
   ``text``) keeps its old vector: the report names them (count and ids), nothing is
   silently left.
"""

from __future__ import annotations

import hashlib
import json
import logging
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np
from pydantic import BaseModel

from tactus_memory.errors import InvalidInputError, SenseConflictError
from tactus_memory.names import validate_sense_name
from tactus_memory.senses.base import Sense
from tactus_memory.storage.codes import code_batches
from tactus_memory.storage.rows import options_for
from tactus_memory.storage.tables import items_schema
from tactus_memory.vectors import as_unit_rows
from tactus_memory.where import Where

if TYPE_CHECKING:
    import threading

    import pyarrow as pa

    from tactus_memory.senses.stored import SenseRegistry
    from tactus_memory.spaces.base import Space
    from tactus_memory.storage.store import Store

log = logging.getLogger(__name__)

#: rows embedded and staged per commit
REEMBED_BATCH = 256
#: the staging table of sense S is STAGING_PREFIX + S
STAGING_PREFIX = "reembed_"
#: ids listed in the report of rows that cannot be redone (the count is always exact)
MISSING_IDS_MAX = 10_000


class Reembeddable(Protocol):
    """What re-embedding needs from a memory (``Memory`` provides it)."""

    store: Store
    space: Space
    lock: threading.RLock
    registry: SenseRegistry


class ReembedReport(BaseModel):
    """What a re-embedding did. ``rows``: vectors swapped in; ``staged_before``: rows a killed
    earlier run had already staged (resumed); ``late``: rows written while staging, embedded
    at the swap; ``missing``: rows without a raw input, kept with their old vector
    (``missing_ids``: the first MISSING_IDS_MAX of them)."""

    sense: str
    provenance: dict[str, Any]
    rows: int
    staged_before: int
    batches: int
    late: int = 0
    missing: int
    missing_ids: list[str]
    seconds: float


def _tag(encoder: Sense) -> str:
    prov = json.dumps(encoder.provenance(), sort_keys=True, default=str)
    return hashlib.sha256(prov.encode()).hexdigest()[:32]


def staging_schema(dim: int) -> pa.Schema:
    import pyarrow as pa

    vector = items_schema(dim).field("vector")
    return pa.schema(
        [pa.field("id", pa.string(), nullable=False), vector, pa.field("tag", pa.string())]
    )


def _staging(store: Store, name: str, dim: int, tag: str) -> Any:
    """The staging table, emptied first when it holds another encoder's vectors."""
    db = store.db
    table = db.create_table(name, schema=staging_schema(dim), exist_ok=True)
    stale = table.count_rows(f"tag != '{tag}'")
    if stale:
        log.info("reembed: dropping %d staged vectors of another encoder", stale)
        db.drop_table(name)
        table = db.create_table(name, schema=staging_schema(dim), exist_ok=True)
    return table


def _ids(store: Store, where: Where) -> list[str]:
    return sorted(store.scan(where.sql(), ["id"]).column("id").to_pylist())


def _embed(store: Store, encoder: Sense, ids: Sequence[str], dim: int) -> np.ndarray:
    """(len(ids), D) new unit vectors from the stored raw inputs of ``ids`` (all present)."""
    rows = store.scan(Where().ids(ids).sql(), ["id", "raw", "text"]).to_pylist()
    by_id = {r["id"]: r for r in rows}
    return embed_rows(encoder, [by_id[i] for i in ids], dim)


def embed_rows(encoder: Sense, rows: Sequence[dict[str, Any]], dim: int) -> np.ndarray:
    """(len(rows), D) new unit vectors from stored rows (``raw``/``text`` columns)."""
    # what is stored is re-embedded as it is: a window kept idle on purpose too (keep_idle)
    opts = options_for(encoder, {"keep_idle": True})
    items = [encoder.validate(encoder.from_row(r), **opts) for r in rows]
    vecs = as_unit_rows(encoder.embed(items), dim, what=f"{encoder.name} embedding")
    if len(vecs) != len(rows):
        raise InvalidInputError(f"encoder returned {len(vecs)} vectors for {len(rows)} items")
    return vecs


def coded(store: Store, sense: str, staged: Any) -> pa.RecordBatchReader:
    """Staged (id, D vector) rows of ``sense`` (a table or a LanceDB query), streamed as
    the items table stores them: with the sense's code when the store keeps codes
    (:mod:`tactus_memory.storage.codes`)."""
    import pyarrow as pa

    field = store.schema.field("vector")
    reader = staged.to_reader() if isinstance(staged, pa.Table) else staged.to_batches()
    schema = reader.schema.set(reader.schema.get_field_index("vector"), field)
    return pa.RecordBatchReader.from_batches(schema, code_batches(reader, sense, field))


def vector_table(ids: Sequence[str], vecs: np.ndarray, tag: str | None = None) -> pa.Table:
    import pyarrow as pa

    cols: dict[str, Any] = {
        "id": pa.array(list(ids), pa.string()),
        "vector": pa.FixedSizeListArray.from_arrays(
            pa.array(vecs.reshape(-1), pa.float32()), vecs.shape[1]
        ),
    }
    if tag is not None:
        cols["tag"] = pa.array([tag] * len(ids), pa.string())
    return pa.table(cols)


@dataclass
class Staged:
    """A re-embedding under way: the staging table and what is in it (:func:`begin`)."""

    sense: str
    encoder: Sense
    tag: str
    dim: int
    table: Any  # the LanceDB staging table
    staged: set[str]
    staged_before: int
    redo: Where  # the rows of the sense that have a raw input
    started: float


def begin(memory: Reembeddable, sense: str, encoder: Sense, batch: int) -> Staged:
    """Check ``encoder`` against the stored sense and open the staging table (emptied when it
    holds another encoder's vectors). Raises SenseConflictError when ``encoder`` is another
    sense, modality, dim or space."""
    t0 = time.perf_counter()
    sense = validate_sense_name(sense)
    if encoder.name != sense:
        raise SenseConflictError(f"encoder is sense {encoder.name!r}, not {sense!r}")
    if batch < 1:
        raise InvalidInputError(f"batch must be >= 1, got {batch}")
    stored = memory.registry.search_sense(sense)  # UnknownSenseError for an unknown sense
    if stored.modality != encoder.modality or stored.dim != encoder.dim:
        raise SenseConflictError(
            f"sense {sense!r} is stored as {stored.modality} (dim {stored.dim}); the encoder "
            f"is {encoder.modality} (dim {encoder.dim})"
        )
    encoder.bind(memory.space)  # SenseConflictError for another space
    dim, tag = memory.space.dim, _tag(encoder)
    table = _staging(memory.store, STAGING_PREFIX + sense, dim, tag)
    redo = Where().sense(sense)
    redo.parts.append("(raw IS NOT NULL OR text IS NOT NULL)")
    staged = set(table.search().select(["id"]).limit(None).to_arrow().column("id").to_pylist())
    return Staged(sense, encoder, tag, dim, table, staged, len(staged), redo, t0)


def reembed(
    memory: Reembeddable,
    sense: str,
    encoder: Sense,
    *,
    batch: int = REEMBED_BATCH,
    on_batch: Callable[[int], None] | None = None,
    on_rows: Callable[[int, int], None] | None = None,
) -> ReembedReport:
    """Recompute every stored vector of ``sense`` with ``encoder`` (see the module docstring).

    ``on_batch(n)`` is called after the n-th staged batch is committed (tests kill the run
    there); ``on_rows(staged, total)`` before the first batch and after each (rows of the
    sense staged so far, a resumed run's included, of those to redo: progress). Raises
    SenseConflictError when ``encoder`` is another sense or space."""
    job = begin(memory, sense, encoder, batch)
    store, dim = memory.store, job.dim
    every = _ids(store, job.redo)
    todo = [i for i in every if i not in job.staged]
    if on_rows is not None:
        on_rows(len(every) - len(todo), len(every))
    batches = 0
    for s in range(0, len(todo), batch):
        chunk = todo[s : s + batch]
        job.table.add(vector_table(chunk, _embed(store, encoder, chunk, dim), job.tag))
        job.staged.update(chunk)
        batches += 1
        if on_batch is not None:
            on_batch(batches)
        if on_rows is not None:
            on_rows(len(every) - len(todo) + s + len(chunk), len(every))
    return swap(memory, job, batches)


def swap(memory: Reembeddable, job: Staged, batches: int) -> ReembedReport:
    """Every staged vector into the items table in ONE merge-insert commit (rows written
    since staging are embedded first), the encoder's registration, the staging table
    dropped."""
    store, encoder = memory.store, job.encoder
    missing_where = Where().sense(job.sense)
    missing_where.parts.append("raw IS NULL AND text IS NULL")
    with memory.lock:  # no write of this process between the last staging and the swap
        current = _ids(store, job.redo)
        late = [i for i in current if i not in job.staged]
        if late:
            job.table.add(vector_table(late, _embed(store, encoder, late, job.dim), job.tag))
        if current:
            # streamed from the staging table (memory stays bounded), one commit
            new = coded(store, job.sense, job.table.search().select(["id", "vector"]))
            with store.commit_lock:  # THE swap
                store.items.merge_insert("id").when_matched_update_all().execute(new)
        memory.registry.replace_sense(encoder)
        # rows another process committed between the swap and the new registration carry
        # the old encoder's vectors (a writer checks the registration as it commits, and
        # refuses from now on): embedded here too, so none is left behind
        store.items.checkout_latest()
        done = set(current)
        after = [i for i in _ids(store, job.redo) if i not in done]
        if after:
            vecs = _embed(store, encoder, after, job.dim)
            redo = coded(store, job.sense, vector_table(after, vecs))
            with store.commit_lock:
                store.items.merge_insert("id").when_matched_update_all().execute(redo)
        missing = _ids(store, missing_where)
    store.db.drop_table(STAGING_PREFIX + job.sense)
    return ReembedReport(
        sense=job.sense,
        provenance=encoder.provenance(),
        rows=len(current),
        staged_before=job.staged_before,
        batches=batches,
        late=len(late) + len(after),
        missing=len(missing),
        missing_ids=missing[:MISSING_IDS_MAX],
        seconds=round(time.perf_counter() - job.started, 3),
    )
