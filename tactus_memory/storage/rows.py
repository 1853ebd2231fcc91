"""Rows in and out of the items table: the checks on a write batch (times, meta, ids), the
Arrow table one commit writes, session summaries."""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from tactus_memory.batches import check_ids, check_times, meta_json, per_item
from tactus_memory.errors import IdConflictError, InvalidInputError
from tactus_memory.results import SessionSummary, Stored
from tactus_memory.sense import Sense
from tactus_memory.storage.places import Placement, given_placement
from tactus_memory.storage.store import Store
from tactus_memory.vectors import as_unit_rows
from tactus_memory.where import DEFAULT_FRAME, validate_frame

if TYPE_CHECKING:
    import pyarrow as pa


def options_for(sense: Sense, options: Mapping[str, Any] | None) -> dict[str, Any]:
    """The options ``sense.validate`` takes (its ``validate_options``): an option a sense
    does not declare does not apply to it (``calibrated`` means nothing to a text sense)."""
    return {k: v for k, v in (options or {}).items() if k in sense.validate_options}


@dataclass
class Batch:
    """A checked write batch of n items: times, meta JSON, ids, whether it upserts."""

    t: list[float]
    t_end: list[float]
    meta: list[str]
    ids: list[str]
    upsert: bool
    created: float
    place: Placement

    def without(self, drop: Sequence[int]) -> Batch:
        """This batch less the items ``drop`` (indices), the rest in order."""
        gone = set(drop)
        keep = [i for i in range(len(self.t)) if i not in gone]
        p = self.place
        place = Placement(
            p.position[keep], p.orientation[keep], [p.frame[i] for i in keep],
            [p.placed[i] for i in keep],
        )  # fmt: skip
        return Batch(
            [self.t[i] for i in keep], [self.t_end[i] for i in keep],
            [self.meta[i] for i in keep], [self.ids[i] for i in keep], self.upsert,
            self.created, place,
        )  # fmt: skip


def check_batch(
    n: int,
    t: Sequence[float | None] | float | None,
    t_end: Sequence[float | None] | float | None,
    meta: Sequence[dict[str, Any] | None] | dict[str, Any] | None,
    ids: Sequence[str] | None,
    position: Any = None,
    frame: str = DEFAULT_FRAME,
) -> Batch:
    """The per-item values of an ``add_many`` call, checked (``t`` defaults to now, ``t_end``
    to ``t``; ids, when given, make the write an upsert; ``position``: one ``(x, y, z)`` for
    every item or one per item (None: place it from the session's poses), in ``frame``)."""
    ts, ends, now = check_times(n, t, t_end)
    metas = [meta_json(m) for m in per_item(meta, n, "meta")]
    id_list = check_ids(n, ids)
    upsert = ids is not None
    place = given_placement(n, position, validate_frame(frame))
    return Batch(ts, ends, metas, id_list, upsert, now, place)


@dataclass(eq=False)
class PreparedWrite:
    """One validated write (one session, one sense), ready for ``Memory.commit_writes``.

    ``vectors`` ((n, D) unit rows) is filled in when the write is embedded; ``error`` when a
    group commit left this write out (its embedding failed, or its id clashed), ``dup`` the
    rows an earlier write of the same commit already stores (same id, session, sense and
    payload: an idempotent repeat, written once).
    """

    session: str
    sense: Sense
    canon: list[Any]
    batch: Batch
    source: str
    vectors: np.ndarray | None = None
    error: Exception | None = None
    dup: set[int] = field(default_factory=set)
    #: (index in the caller's items, reason) of each item skipped, not stored
    skipped: list[tuple[int, str]] = field(default_factory=list)

    @property
    def ids(self) -> list[str]:
        return self.batch.ids

    def __len__(self) -> int:
        return len(self.canon)

    def stored(self) -> Stored:
        """What the write returns: its ids and the items it skipped."""
        return Stored(self.ids, self.skipped)


def embed_groups(
    writes: Sequence[PreparedWrite],
    dim: int,
    embed: Callable[[Sense, list[Any]], np.ndarray] | None = None,
) -> None:
    """Embed the writes that have no vectors yet: ONE ``embed`` call per sense across all of
    them (``embed(sense, items)``, default ``sense.embed(items)``; the group committer's
    encoder process passes its own); each write gets its slice of (n, ``dim``) unit rows."""
    by_sense: dict[str, list[PreparedWrite]] = {}
    for w in writes:
        if w.vectors is None:
            by_sense.setdefault(w.sense.name, []).append(w)
    for name, group in by_sense.items():
        canon = [x for w in group for x in w.canon]
        sense = group[0].sense
        raw = sense.embed(canon) if embed is None else embed(sense, canon)
        vectors = as_unit_rows(raw, dim, what=f"{name} embedding")
        if vectors.shape[0] != len(canon):
            raise InvalidInputError(
                f"sense {name!r} returned {vectors.shape[0]} vectors for {len(canon)}"
            )
        at = 0
        for w in group:
            w.vectors = vectors[at : at + len(w)]
            at += len(w)


def embed_isolated(writes: Sequence[PreparedWrite], dim: int) -> None:
    """:func:`embed_groups`, but a failing embedding fails only its own write: when a sense's
    batch call raises, that sense's writes are embedded one by one and each culprit gets the
    exception as its ``error`` (no write is committed here, so nothing is written twice)."""
    try:
        embed_groups(writes, dim)
    except Exception:  # noqa: BLE001  (isolated below, write by write)
        for w in writes:
            if w.vectors is None:
                try:
                    embed_groups([w], dim)
                except Exception as exc:  # noqa: BLE001  (this write's own failure)
                    w.error = exc


def _payload(w: PreparedWrite, i: int) -> tuple[Any, ...]:
    """What an item id stores but its vector and ``created``: a repeat of it is idempotent."""
    row = w.sense.to_row(w.canon[i])
    b = w.batch
    return (w.session, w.sense.name, w.source, b.t[i], b.t_end[i], b.meta[i], sorted(row.items()))


def resolve_shared_ids(writes: Sequence[PreparedWrite]) -> None:
    """Two writes of one commit naming the same item id (say two clients retrying the same
    note in one tick): the later one is an idempotent repeat when its session, sense and
    payload match the earlier row (its row is marked ``dup`` and written once), else it fails
    alone with :class:`IdConflictError`. The rest of the commit is not affected."""
    first: dict[str, tuple[PreparedWrite, int]] = {}
    for w in writes:
        w.dup.clear()  # (re-)resolved from scratch: a write may have failed since
        if w.error is not None or not w.batch.upsert:
            continue  # generated ids never clash
        for i, item_id in enumerate(w.ids):
            seen = first.get(item_id)
            if seen is not None and _payload(*seen) != _payload(w, i):
                w.error = IdConflictError(
                    f"item id {item_id!r} is written by two requests at once with different "
                    "content (or session, sense); the other one was stored, send this one again "
                    "to replace it"
                )
                w.dup.clear()
                break
            if seen is not None:
                w.dup.add(i)
        if w.error is None:
            for i, item_id in enumerate(w.ids):
                first.setdefault(item_id, (w, i))


def claim_ids(store: Store, writes: Sequence[PreparedWrite], isolate: bool) -> dict[int, int]:
    """Rows each upsert replaces (of its own session and sense), by ``id(write)``. An id of
    another session or sense raises IdConflictError (``isolate``: that write's ``error``).
    Call it under the memory's commit lock, just before the store write."""
    replaced: dict[int, int] = {}
    for w in writes:
        if w.batch.upsert and w.error is None:
            try:
                replaced[id(w)] = store.owned_count(w.ids, w.session, w.sense.name)
            except IdConflictError as exc:
                if not isolate:
                    raise
                w.error = exc
                resolve_shared_ids(writes)  # a repeat of its ids is no longer a repeat
    return replaced


def items_table(
    schema: pa.Schema,
    batch: Batch,
    session: str,
    sense: str,
    source: str,
    vectors: np.ndarray,
    extras: Sequence[dict[str, Any]],
) -> pa.Table:
    """The Arrow table of one write: ``vectors`` (N, D) unit rows, ``extras`` the sense's
    ``to_row`` columns per item."""
    import pyarrow as pa

    n, dim = vectors.shape
    return pa.table(
        {
            "id": batch.ids,
            "session": [session] * n,
            "sense": [sense] * n,
            "t": batch.t,
            "t_end": batch.t_end,
            "vector": pa.FixedSizeListArray.from_arrays(
                pa.array(vectors.reshape(-1), pa.float32()), dim
            ),
            "meta": batch.meta,
            "text": [e.get("text") for e in extras],
            "raw": [e.get("raw") for e in extras],
            "source": [source] * n,
            "episode": pa.nulls(n, pa.int64()),
            "created": [batch.created] * n,
            **batch.place.columns(),
        },
        schema=schema,
    )


def writes_table(schema: pa.Schema, writes: Sequence[PreparedWrite]) -> pa.Table:
    """The Arrow table of several embedded writes (one commit), less their ``dup`` rows."""
    import pyarrow as pa

    table = pa.concat_tables(
        [
            items_table(
                schema,
                w.batch,
                w.session,
                w.sense.name,
                w.source,
                np.asarray(w.vectors),
                [w.sense.to_row(x) for x in w.canon],
            )
            for w in writes
        ]
    )
    return table.take(_row_numbers(writes)) if any(w.dup for w in writes) else table


def _row_numbers(writes: Sequence[PreparedWrite]) -> list[int]:
    out, at = [], 0
    for w in writes:
        out.extend(at + i for i in range(len(w)) if i not in w.dup)
        at += len(w)
    return out


def summarise(tbl: pa.Table) -> list[SessionSummary]:
    """Rows (session, sense, t, t_end) -> one summary per session, sorted by id."""
    if tbl.num_rows == 0:
        return []
    agg = tbl.group_by(["session", "sense"]).aggregate(
        [("t", "min"), ("t_end", "max"), ("t", "count")]
    )
    by: dict[str, dict[str, Any]] = {}
    for r in agg.to_pylist():
        d = by.setdefault(r["session"], {"counts": {}, "t_min": math.inf, "t_max": -math.inf})
        d["counts"][r["sense"]] = int(r["t_count"])
        d["t_min"] = min(d["t_min"], r["t_min"])
        d["t_max"] = max(d["t_max"], r["t_end_max"])
    return [
        SessionSummary(
            id=sid,
            n=sum(d["counts"].values()),
            counts=dict(sorted(d["counts"].items())),
            t_min=d["t_min"],
            t_max=d["t_max"],
        )
        for sid, d in sorted(by.items())
    ]
