"""Rows in and out of the items table: the checks on a write batch (times, meta, ids), the
Arrow table one commit writes, session summaries. Nothing here calls a sense: embedding, a
sense's stored columns and the id checks that compare payloads are the write path's
(``tactus_memory.memory.writes``)."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from tactus_memory.batches import check_ids, check_times, meta_json, per_item
from tactus_memory.results import SessionSummary, Stored
from tactus_memory.senses.base import Sense
from tactus_memory.storage.codes import vector_array
from tactus_memory.storage.places import Placement, given_placement
from tactus_memory.storage.tables import FACET_COLUMNS
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
    payload: an idempotent repeat, written once), ``unchanged`` the rows the store already
    holds exactly (same id, session, sense and payload: acknowledged, not written again).
    """

    session: str
    sense: Sense
    canon: list[Any]
    batch: Batch
    source: str
    vectors: np.ndarray | None = None
    error: Exception | None = None
    dup: set[int] = field(default_factory=set)
    unchanged: set[int] = field(default_factory=set)
    #: (index in the caller's items, reason) of each item skipped, not stored
    skipped: list[tuple[int, str]] = field(default_factory=list)
    #: the sense's stored columns per item (``Sense.to_row``), filled in with ``vectors`` by
    #: the write path (``tactus_memory.memory.writes``): what :func:`writes_table` stores beside
    #: them
    extras: list[dict[str, Any]] = field(default_factory=list)

    @property
    def ids(self) -> list[str]:
        return self.batch.ids

    @property
    def left_out(self) -> set[int]:
        """The rows not written: repeats within the commit and rows stored as they are."""
        return self.dup | self.unchanged

    @property
    def written(self) -> int:
        """Rows this write adds to the commit."""
        return len(self) - len(self.left_out)

    def __len__(self) -> int:
        return len(self.canon)

    def stored(self) -> Stored:
        """What the write returns: its ids and the items it skipped."""
        return Stored(self.ids, self.skipped)


def items_table(
    schema: pa.Schema,
    batch: Batch,
    session: str,
    sense: str,
    source: str,
    vectors: np.ndarray,
    extras: Sequence[dict[str, Any]],
) -> pa.Table:
    """The Arrow table of one write: ``vectors`` (N, D) unit rows (stored with the sense's
    code when ``schema``'s vector is wider: :mod:`tactus_memory.storage.codes`),
    ``extras`` the sense's ``to_row`` columns per item (a touch sense's include its
    facets, :data:`FACET_COLUMNS`, stored where ``schema`` has them)."""
    import pyarrow as pa

    n = len(vectors)
    facets = {c: [e.get(c) for e in extras] for c in FACET_COLUMNS if c in schema.names}
    return pa.table(
        {
            "id": batch.ids,
            "session": [session] * n,
            "sense": [sense] * n,
            "t": batch.t,
            "t_end": batch.t_end,
            "vector": vector_array(vectors, sense, schema.field("vector").type.list_size),
            "meta": batch.meta,
            "text": [e.get("text") for e in extras],
            "raw": [e.get("raw") for e in extras],
            "source": [source] * n,
            "episode": pa.nulls(n, pa.int64()),
            "created": [batch.created] * n,
            **batch.place.columns(),
            **facets,
        },
        schema=schema,
    )


def writes_table(schema: pa.Schema, writes: Sequence[PreparedWrite]) -> pa.Table:
    """The Arrow table of several embedded writes (one commit), less their ``dup`` rows: each
    write's vectors and the sense's columns its write path gave it (``extras``); storage never
    calls the sense."""
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
                w.extras,
            )
            for w in writes
        ]
    )
    return table.take(_row_numbers(writes)) if any(w.left_out for w in writes) else table


def _row_numbers(writes: Sequence[PreparedWrite]) -> list[int]:
    out: list[int] = []
    at = 0
    for w in writes:
        out.extend(at + i for i in range(len(w)) if i not in w.left_out)
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
