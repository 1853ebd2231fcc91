"""LanceDB storage: schema, safely built filters, indexes and compaction.

One store is one LanceDB database (a directory or an object-storage prefix) with three tables:

``items``  one row per remembered thing (any sense), the columns in :func:`items_schema`::

    id str | session str | sense str | t float64 | t_end float64
    vector fixed_size_list<float32>[D] | meta str (JSON) | text str? | raw binary? (npy bytes)
    source str | episode int64? | created float64

``senses`` one row per sense ever registered: name, modality, dim, provenance (JSON), an
           optional ``query_centroid`` (npy bytes) and the score calibration (mu, sigma, calib_n).
``meta``   key/value strings: the space (name, dim) the store was created with, cached probe
           embeddings, index bookkeeping.

Filters: every SQL ``WHERE`` fragment is built here, by :class:`Where`, from values that first
pass a validator (ids and sense names by regex, numbers must be finite); string literals are
also quote-escaped. No user string reaches LanceDB any other way.

Indexes (:class:`IndexConfig`, defaults chosen with ``benchmarks/memory.py``): scalar
BTREE/BITMAP indexes on id, session, sense, t from 10k rows; an IVF_SQ cosine index from
20k rows (rows/4096 partitions, nprobes 20, refine 2), retrained when the table has grown
4x or incremental updates have left more than 8 index segments. Filters allowing at most
20k rows are answered by an exact flat scan of those rows. ``optimize`` (compaction plus
incremental index update) runs every 64 appends; rows not yet indexed are still searched.
"""

from __future__ import annotations

import json
import logging
import math
import re
import threading
import time
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from datetime import timedelta
from typing import TYPE_CHECKING, Any

import numpy as np

from tactus_memory.errors import (
    IdConflictError,
    InvalidIdError,
    InvalidInputError,
    SpaceMismatchError,
)
from tactus_memory.senses import validate_sense_name

if TYPE_CHECKING:  # heavy imports stay lazy
    import pyarrow as pa

log = logging.getLogger(__name__)

ID_RE = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._:-]{0,127}$")
ITEMS = "items"
SENSES = "senses"
META = "meta"
REMOTE_SCHEMES = ("s3://", "s3+ddb://", "gs://", "az://", "abfs://", "memory://")
#: columns returned by searches (everything except the vector and raw bytes)
HIT_COLUMNS = ["id", "session", "sense", "t", "t_end", "meta", "text", "source", "episode"]


# --------------------------------------------------------------------------- validation
def validate_id(value: Any, what: str = "id") -> str:
    """Session ids, item ids and source ids: 1-128 chars of ``[A-Za-z0-9._:-]``."""
    if not isinstance(value, str) or not ID_RE.fullmatch(value):
        shown = (
            repr(value)
            if not isinstance(value, str) or len(value) <= 60
            else repr(value[:60]) + "..."
        )
        raise InvalidIdError(
            f"invalid {what} {shown}: use 1-128 characters of [A-Za-z0-9._:-], "
            "starting with a letter or digit"
        )
    return value


def validate_source(value: Any) -> str:
    """A source (stream) id is an id or the empty string."""
    if value == "":
        return ""
    return validate_id(value, "source id")


def finite_float(value: Any, what: str) -> float:
    """A finite float (bools and non-numbers rejected)."""
    if isinstance(value, bool):
        raise InvalidInputError(f"{what} must be a number, got {value!r}")
    try:
        out = float(value)
    except (TypeError, ValueError):
        raise InvalidInputError(f"{what} must be a number, got {value!r}") from None
    if not math.isfinite(out):
        raise InvalidInputError(f"{what} must be finite, got {value!r}")
    return out


def _sql_str(value: str) -> str:
    return "'" + value.replace("'", "''") + "'"


def _sql_float(value: float) -> str:
    # ``repr`` gives the shortest round-tripping form; DataFusion parses 1e+20 and -0.0 too.
    return repr(float(value))


@dataclass
class Where:
    """A conjunction of validated conditions, rendered to one LanceDB SQL filter.

    Build with the methods (each validates its input) and render with :meth:`sql`.
    Temporal operators reuse this: ``Where().session("s1").overlaps(10, 20).sql()``.
    """

    parts: list[str] = field(default_factory=list)

    def session(self, session: str | None) -> Where:
        if session is not None:
            self.parts.append(f"session = {_sql_str(validate_id(session, 'session id'))}")
        return self

    def sessions(self, sessions: Iterable[str] | None) -> Where:
        if sessions is not None:
            vals = [_sql_str(validate_id(s, "session id")) for s in sessions]
            self.parts.append(f"session IN ({', '.join(vals)})" if vals else "false")
        return self

    def sense(self, sense: str | None) -> Where:
        if sense is not None:
            self.parts.append(f"sense = {_sql_str(validate_sense_name(sense))}")
        return self

    def senses(self, senses: Iterable[str] | None) -> Where:
        if senses is not None:
            vals = [_sql_str(validate_sense_name(s)) for s in senses]
            self.parts.append(f"sense IN ({', '.join(vals)})" if vals else "false")
        return self

    def ids(self, ids: Iterable[str] | None) -> Where:
        if ids is not None:
            vals = [_sql_str(validate_id(i, "item id")) for i in ids]
            self.parts.append(f"id IN ({', '.join(vals)})" if vals else "false")
        return self

    def source(self, source: str | None) -> Where:
        if source is not None:
            self.parts.append(f"source = {_sql_str(validate_source(source))}")
        return self

    def episode(self, episode: int | None) -> Where:
        if episode is not None:
            if isinstance(episode, bool) or not isinstance(episode, (int, np.integer)):
                raise InvalidInputError(f"episode must be an int, got {episode!r}")
            self.parts.append(f"episode = {int(episode)}")
        return self

    def overlaps(self, after: float | None = None, before: float | None = None) -> Where:
        """Items whose interval ``[t, t_end]`` overlaps ``[after, before]`` (ends inclusive).

        ``after`` alone: items still going on at or after ``after`` (``t_end >= after``);
        ``before`` alone: items that started at or before ``before`` (``t <= before``).
        """
        if after is not None:
            self.parts.append(f"t_end >= {_sql_float(finite_float(after, 'after'))}")
        if before is not None:
            self.parts.append(f"t <= {_sql_float(finite_float(before, 'before'))}")
        if after is not None and before is not None and float(after) > float(before):
            raise InvalidInputError(f"after ({after}) is later than before ({before})")
        return self

    def t_range(self, start: float | None = None, end: float | None = None) -> Where:
        """Items that *start* in ``[start, end)`` (for ordering-style temporal queries)."""
        if start is not None:
            self.parts.append(f"t >= {_sql_float(finite_float(start, 'start'))}")
        if end is not None:
            self.parts.append(f"t < {_sql_float(finite_float(end, 'end'))}")
        return self

    def sql(self) -> str | None:
        return " AND ".join(f"({p})" for p in self.parts) if self.parts else None


# --------------------------------------------------------------------------- schema
def items_schema(dim: int) -> pa.Schema:
    import pyarrow as pa

    return pa.schema(
        [
            pa.field("id", pa.string(), nullable=False),
            pa.field("session", pa.string(), nullable=False),
            pa.field("sense", pa.string(), nullable=False),
            pa.field("t", pa.float64(), nullable=False),
            pa.field("t_end", pa.float64(), nullable=False),
            pa.field("vector", pa.list_(pa.float32(), dim), nullable=False),
            pa.field("meta", pa.string(), nullable=False),
            pa.field("text", pa.string()),
            pa.field("raw", pa.binary()),
            pa.field("source", pa.string(), nullable=False),
            pa.field("episode", pa.int64()),
            pa.field("created", pa.float64(), nullable=False),
        ]
    )


def senses_schema() -> pa.Schema:
    import pyarrow as pa

    return pa.schema(
        [
            pa.field("name", pa.string(), nullable=False),
            pa.field("modality", pa.string(), nullable=False),
            pa.field("dim", pa.int64(), nullable=False),
            pa.field("provenance", pa.string(), nullable=False),
            pa.field("query_centroid", pa.binary()),
            pa.field("mu", pa.float64()),
            pa.field("sigma", pa.float64()),
            pa.field("calib_n", pa.int64()),
            pa.field("updated", pa.float64(), nullable=False),
        ]
    )


def meta_schema() -> pa.Schema:
    import pyarrow as pa

    return pa.schema([pa.field("key", pa.string(), nullable=False), pa.field("value", pa.string())])


# --------------------------------------------------------------------------- index config
@dataclass
class IndexConfig:
    """Vector/scalar index policy. Defaults chosen by ``benchmarks/memory.py`` (see README)."""

    #: build the ANN index once the table has this many rows (flat search below it)
    threshold: int = 20_000
    #: build the scalar indexes (session, sense, t, id) from this many rows
    scalar_threshold: int = 10_000
    index_type: str = "IVF_SQ"
    #: rows per IVF partition (num_partitions = rows / this)
    rows_per_partition: int = 4096
    nprobes: int = 20
    refine_factor: int | None = 2
    ef: int | None = None
    #: filtered searches allowing at most this many rows scan them exactly (no ANN)
    flat_max: int = 20_000
    #: filtered ANN searches probe enough partitions to score about this many allowed rows
    min_candidates: int = 4096
    #: rebuild (retrain) the ANN index when the table has grown this many times since
    retrain_growth: float = 4.0
    #: retrain the ANN index when incremental updates have split it into more segments
    max_deltas: int = 8
    #: run ``optimize`` (compaction + incremental index update) after this many appends
    compact_every: int = 64
    #: versions older than this are removed by ``optimize``
    cleanup_older_than: timedelta = timedelta(hours=1)
    #: scalar index type per column
    scalar: dict[str, str] = field(
        default_factory=lambda: {"id": "BTREE", "session": "BTREE", "sense": "BITMAP", "t": "BTREE"}
    )


def vector_index_config(cfg: IndexConfig, partitions: int, dim: int) -> Any:
    """The LanceDB index config for ``cfg.index_type`` (cosine metric)."""
    from lancedb import index as ix

    kind = cfg.index_type.upper()
    common: dict[str, Any] = {"distance_type": "cosine", "num_partitions": partitions}
    if kind == "IVF_PQ":
        return ix.IvfPq(num_sub_vectors=max(1, dim // 8), **common)
    if kind == "IVF_SQ":
        return ix.IvfSq(**common)
    if kind == "IVF_HNSW_SQ":
        return ix.IvfHnswSq(**common)
    if kind == "IVF_FLAT":
        return ix.IvfFlat(**common)
    raise InvalidInputError(f"unsupported vector index type {cfg.index_type!r}")


def scalar_index_config(kind: str) -> Any:
    from lancedb import index as ix

    return {"BTREE": ix.BTree, "BITMAP": ix.Bitmap}[kind.upper()]()


def is_remote_uri(uri: str) -> bool:
    return uri.startswith(REMOTE_SCHEMES)


def normalise_uri(uri: str) -> str:
    """Local paths and ``file://`` URIs -> a local path; object-storage URIs pass through.

    Unknown ``scheme://`` prefixes are rejected (InvalidInputError).
    """
    if not isinstance(uri, str) or not uri.strip():
        raise InvalidInputError(f"memory location must be a non-empty string, got {uri!r}")
    if uri.startswith("file://"):
        return uri[len("file://") :]
    if "://" in uri:
        if is_remote_uri(uri) and len(uri.split("://", 1)[1].strip("/")) > 0:
            return uri
        raise InvalidInputError(
            f"unsupported memory location {uri!r}: use a local path, file://, s3://, gs:// or az://"
        )
    return uri


# --------------------------------------------------------------------------- store
class Store:
    """Thin wrapper around one LanceDB connection. Not thread-safe for writes on its own:
    :class:`~tactus_memory.memory.Memory` serialises writes with a lock."""

    def __init__(
        self,
        uri: str,
        *,
        storage_options: dict[str, str] | None = None,
        read_consistency_interval: timedelta | None = None,
        index: IndexConfig | None = None,
    ) -> None:
        import lancedb

        self.uri = normalise_uri(uri)
        self.index = index or IndexConfig()
        self.storage_options = dict(storage_options or {})
        self.db = lancedb.connect(
            self.uri,
            storage_options=storage_options,
            read_consistency_interval=read_consistency_interval,
        )
        self._items: Any = None
        self._senses: Any = None
        self._meta: Any = None
        self._maintenance = threading.Lock()
        self._appends = 0
        self._schema: pa.Schema | None = None
        self._indexed = False
        self._scalar_indexed = False
        self._partitions: int | None = None
        self._open_existing()

    # ----------------------------------------------------------- tables
    def _table_names(self) -> set[str]:
        res = self.db.list_tables()
        names = getattr(res, "tables", res)
        return set(names)

    def _open_existing(self) -> None:
        names = self._table_names()
        if ITEMS in names:
            self._items = self.db.open_table(ITEMS)
        if SENSES in names:
            self._senses = self.db.open_table(SENSES)
        if META in names:
            self._meta = self.db.open_table(META)

    @property
    def items(self) -> Any:
        if self._items is None:
            raise RuntimeError("store has no items table yet; call bind_space first")
        return self._items

    @property
    def schema(self) -> pa.Schema:
        """The items table's schema (cached: reading it is a LanceDB round trip)."""
        if self._schema is None:
            self._schema = self.items.schema
        return self._schema

    def bind_space(self, name: str, dim: int) -> None:
        """Record the space on creation; on reopen raise SpaceMismatchError if it differs."""
        if self._meta is None:
            self._meta = self.db.create_table(META, schema=meta_schema(), exist_ok=True)
        stored = self.get_meta("space")
        if stored is not None:
            info = json.loads(stored)
            if info["name"] != name or int(info["dim"]) != int(dim):
                raise SpaceMismatchError(
                    f"this memory was created with space {info['name']!r} (dim {info['dim']}), "
                    f"but was opened with space {name!r} (dim {dim}); open it with "
                    f"{info['name']!r} or use another directory"
                )
        else:
            self.set_meta("space", json.dumps({"name": name, "dim": int(dim)}))
        if self._items is None:
            # Lance file format 2.1: ~1.5x faster random access to the hit columns than 2.0
            # (measured at 1M rows, benchmarks/README.md)
            self._items = self.db.create_table(
                ITEMS,
                schema=items_schema(dim),
                exist_ok=True,
                storage_options={**self.storage_options, "new_table_data_storage_version": "2.1"},
            )
        if self._senses is None:
            self._senses = self.db.create_table(SENSES, schema=senses_schema(), exist_ok=True)

    # ----------------------------------------------------------- meta
    def get_meta(self, key: str) -> str | None:
        if self._meta is None:
            return None
        rows = self._meta.search().where(f"key = {_sql_str(key)}").limit(1).to_arrow()
        return None if rows.num_rows == 0 else rows.column("value")[0].as_py()

    def set_meta(self, key: str, value: str) -> None:
        import pyarrow as pa

        data = pa.table({"key": [key], "value": [value]}, schema=meta_schema())
        (
            self._meta.merge_insert("key")
            .when_matched_update_all()
            .when_not_matched_insert_all()
            .execute(data)
        )

    # ----------------------------------------------------------- senses registry
    def sense_rows(self) -> list[dict[str, Any]]:
        if self._senses is None:
            return []
        return self._senses.search().limit(None).to_arrow().to_pylist()

    def put_sense_row(self, row: dict[str, Any]) -> None:
        import pyarrow as pa

        data = pa.Table.from_pylist([row], schema=senses_schema())
        (
            self._senses.merge_insert("name")
            .when_matched_update_all()
            .when_not_matched_insert_all()
            .execute(data)
        )

    # ----------------------------------------------------------- writes
    def write(self, data: pa.Table, *, upsert: bool) -> None:
        """One LanceDB commit: append, or merge-insert on ``id`` (idempotent upsert)."""
        if upsert:
            (
                self.items.merge_insert("id")
                .when_matched_update_all()
                .when_not_matched_insert_all()
                .execute(data)
            )
        else:
            self.items.add(data)
        self._appends += 1

    def owned_ids(self, ids: Sequence[str], session: str, sense: str) -> list[str]:
        """The senses of the rows an upsert of ``ids`` into (``session``, ``sense``) replaces.

        Raises IdConflictError, naming the first offending id, when any id already belongs to
        another session or another sense: an upsert never overwrites or moves another
        session's row. Call it under the memory's commit lock, just before :meth:`write`.
        """
        if self._items is None or not ids:
            return []
        rows = self.scan(Where().ids(ids).sql(), ["id", "session", "sense"]).to_pylist()
        for row in rows:
            if row["session"] != session or row["sense"] != sense:
                raise IdConflictError(
                    f"item id {row['id']!r} already belongs to another session or sense "
                    f"(not {sense!r} in session {session!r}); use another id, or delete "
                    "that item first"
                )
        return [row["sense"] for row in rows]

    def delete(self, where: str) -> None:
        self.items.delete(where)

    def count(self, where: str | None = None) -> int:
        if self._items is None:
            return 0
        return int(self.items.count_rows(where))

    # ----------------------------------------------------------- reads
    def vector_search(
        self,
        vector: np.ndarray,
        k: int,
        where: str | None,
        *,
        allowed: int | None = None,
        total: int | None = None,
        columns: Sequence[str] = HIT_COLUMNS,
    ) -> pa.Table:
        """vector: (D,) unit float32 -> up to k rows with ``_distance`` = 1 - cosine.

        ``allowed``: how many rows pass ``where`` (``total``: rows in the table). A selective
        filter (allowed <= ``flat_max``) is answered by an exact flat scan of the allowed
        rows; otherwise the ANN index is probed, with more partitions the more selective the
        filter, so that about ``min_candidates`` allowed rows are scored.
        """
        cfg = self.index
        q = self.items.search(vector, vector_column_name="vector").distance_type("cosine")
        if where:
            q = q.where(where, prefilter=True)
        indexed = self.has_vector_index()
        if indexed and where and allowed is not None and allowed <= cfg.flat_max:
            q = q.bypass_vector_index()
        elif indexed:
            nprobes = cfg.nprobes
            if allowed and total and allowed < total:
                per_part = cfg.rows_per_partition * allowed / total
                nprobes = max(nprobes, math.ceil(cfg.min_candidates / max(per_part, 1e-9)))
            q = q.nprobes(min(nprobes, self.partitions()))
            if cfg.refine_factor:
                q = q.refine_factor(cfg.refine_factor)
            if cfg.ef:  # HNSW needs ef >= the candidates it returns
                q = q.ef(max(cfg.ef, k * (cfg.refine_factor or 1)))
        return q.select([*columns, "_distance"]).limit(k).to_arrow()

    def partitions(self) -> int:
        """IVF partitions of the current vector index (from the store's bookkeeping)."""
        if self._partitions is None:
            info = json.loads(self.get_meta("index") or "{}")
            self._partitions = int(info.get("partitions", 1))
        return self._partitions

    def scan(self, where: str | None, columns: Sequence[str], limit: int | None = None) -> pa.Table:
        q = self.items.search()
        if where:
            q = q.where(where)
        return q.select(list(columns)).limit(limit).to_arrow()

    # ----------------------------------------------------------- indexes & compaction
    def has_vector_index(self) -> bool:
        if not self._indexed:
            self._indexed = any("vector" in ix.columns for ix in self.items.list_indices())
        return self._indexed

    def vector_deltas(self) -> int:
        """How many index segments the ANN index has (each ``optimize`` adds a delta for the
        rows appended since; every search probes all of them)."""
        for ix in self.items.list_indices():
            if "vector" in ix.columns:
                stats = self.items.index_stats(ix.name)
                return int(stats.num_indices or 1) if stats is not None else 1
        return 0

    def has_scalar_indexes(self) -> bool:
        if not self._scalar_indexed:
            have = {c for ix in self.items.list_indices() for c in ix.columns}
            self._scalar_indexed = set(self.index.scalar) <= have
        return self._scalar_indexed

    def index_due(self, rows: int) -> bool:
        """Whether ``rows`` rows call for an index that does not exist yet."""
        cfg = self.index
        return (rows >= cfg.scalar_threshold and not self.has_scalar_indexes()) or (
            rows >= cfg.threshold and not self.has_vector_index()
        )

    def build_scalar_indexes(self) -> None:
        """BTREE/BITMAP indexes for filters, deletes and upserts (``IndexConfig.scalar``)."""
        for column, kind in self.index.scalar.items():
            self.items.create_index(column, config=scalar_index_config(kind), replace=True)
        self._scalar_indexed = True

    def build_indexes(self) -> None:
        """Create the ANN index on ``vector`` and the scalar indexes (replacing old ones)."""
        cfg = self.index
        n = self.count()
        parts = max(1, n // cfg.rows_per_partition)
        t0 = time.perf_counter()
        self.items.create_index("vector", config=vector_index_config(cfg, parts, self.dim()))
        self.build_scalar_indexes()
        self._indexed = True
        self.set_meta("index", json.dumps({"rows": n, "type": cfg.index_type, "partitions": parts}))
        self._partitions = parts
        log.info("built %s index on %d rows in %.1fs", cfg.index_type, n, time.perf_counter() - t0)

    def dim(self) -> int:
        return int(self.items.schema.field("vector").type.list_size)

    def maintain(self, *, force: bool = False) -> bool:
        """Build/retrain indexes past the threshold and compact small appends.

        Returns True when something ran. Safe to call from a background thread: writes may
        go on meanwhile (LanceDB commits are optimistic and compaction rebases).
        """
        if not self._maintenance.acquire(blocking=force):
            return False
        try:
            cfg = self.index
            n = self.count()
            if cfg.scalar_threshold <= n < cfg.threshold and not self.has_scalar_indexes():
                self.build_scalar_indexes()
            if n >= cfg.threshold:
                info = json.loads(self.get_meta("index") or "{}")
                grown = n >= cfg.retrain_growth * int(info.get("rows", n))
                if not self.has_vector_index() or grown or self.vector_deltas() > cfg.max_deltas:
                    self.build_indexes()
            self.items.optimize(cleanup_older_than=cfg.cleanup_older_than)
            self._appends = 0
            return True
        finally:
            self._maintenance.release()

    def needs_maintenance(self) -> bool:
        return self._appends >= self.index.compact_every
