"""The store's tables: their Arrow schemas and the index settings (vector and scalar)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from tactus_memory.errors import InvalidInputError

if TYPE_CHECKING:
    import pyarrow as pa


# --------------------------------------------------------------------------- schema
#: columns returned by searches (everything except the vector and raw bytes)
#: a touch row's facets (:mod:`tactus_memory.touch.facets`), computed at write time; null on
#: other senses' rows. ``regions``: the active regions as ``",thumb,index,"`` (a filter asks
#: ``strpos(regions, ',thumb,') > 0``); ``facets``: every facet of the window as JSON
FACET_COLUMNS = ("force", "area", "peak", "grip", "regions", "facets")
HIT_COLUMNS = [
    *("id", "session", "sense", "t", "t_end", "meta", "text", "source", "episode"),
    *("x", "y", "z", "frame"),
    *FACET_COLUMNS,
]


def items_schema(dim: int, codes: int = 0) -> pa.Schema:
    """The items table: ``vector`` holds each row's D embedding and, in a store made with
    sense codes, ``codes`` more dimensions (:mod:`tactus_memory.storage.codes`; recorded
    in the field's metadata)."""
    import pyarrow as pa

    from tactus_memory.storage.codes import FIELD_KEY

    return pa.schema(
        [
            pa.field("id", pa.string(), nullable=False),
            pa.field("session", pa.string(), nullable=False),
            pa.field("sense", pa.string(), nullable=False),
            pa.field("t", pa.float64(), nullable=False),
            pa.field("t_end", pa.float64(), nullable=False),
            pa.field(
                "vector",
                pa.list_(pa.float32(), dim + codes),
                nullable=False,
                metadata={FIELD_KEY: str(codes).encode()} if codes else None,
            ),
            pa.field("meta", pa.string(), nullable=False),
            pa.field("text", pa.string()),
            pa.field("raw", pa.binary()),
            pa.field("source", pa.string(), nullable=False),
            pa.field("episode", pa.int64()),
            pa.field("created", pa.float64(), nullable=False),
            *place_fields(),
            *facet_fields(),
        ]
    )


def check_facet_columns(schema: pa.Schema) -> None:
    """Raise InvalidInputError when the items table has no facet columns (a store made
    before facets): a facet filter or order needs ``tactus maintain --facets`` first."""
    if "facets" not in schema.names:
        raise InvalidInputError(
            "this store was made before touch facets: filtering or sorting by a facet needs "
            "its facet columns; run `tactus maintain --facets` on it first"
        )


def facet_fields() -> list[pa.Field]:
    """A touch row's facets (:data:`FACET_COLUMNS`; null on other rows and on rows stored
    before facets, until ``tactus maintain --facets``)."""
    import pyarrow as pa

    return [
        pa.field("force", pa.float64()),
        pa.field("area", pa.float64()),
        pa.field("peak", pa.float64()),
        pa.field("grip", pa.string()),
        pa.field("regions", pa.string()),
        pa.field("facets", pa.string()),
    ]


def place_fields() -> list[pa.Field]:
    """Where an item happened (all null when unplaced): ``x, y, z`` in ``frame``, the
    orientation quaternion (x, y, z, w) when known, and ``placed``: ``"given"`` (passed with
    the item) or ``"poses"`` (interpolated from the session trajectory, redone on backfill)."""
    import pyarrow as pa

    return [
        pa.field("x", pa.float64()),
        pa.field("y", pa.float64()),
        pa.field("z", pa.float64()),
        pa.field("orientation", pa.list_(pa.float64(), 4)),
        pa.field("frame", pa.string()),
        pa.field("placed", pa.string()),
    ]


def poses_schema() -> pa.Schema:
    """The ``poses`` table: one row per pose of a session trajectory (time on the session
    clock, position in ``frame``, optional orientation quaternion (x, y, z, w))."""
    import pyarrow as pa

    return pa.schema(
        [
            pa.field("session", pa.string(), nullable=False),
            pa.field("t", pa.float64(), nullable=False),
            pa.field("x", pa.float64(), nullable=False),
            pa.field("y", pa.float64(), nullable=False),
            pa.field("z", pa.float64(), nullable=False),
            pa.field("orientation", pa.list_(pa.float64(), 4)),
            pa.field("frame", pa.string(), nullable=False),
            pa.field("source", pa.string(), nullable=False),
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


def keys_schema() -> pa.Schema:
    """The ``keys`` table (:mod:`tactus_memory.storage.keys`): one row per key, its secret
    only as a salted scrypt hash."""
    import pyarrow as pa

    required = {"key_id": pa.string(), "tenant": pa.string(), "scope": pa.string()}
    required |= {"salt": pa.binary(), "hash": pa.binary(), "created": pa.float64()}
    times = ("expires", "revoked", "last_used")  # null: never expires, not revoked, unused
    return pa.schema(
        [pa.field(name, kind, nullable=False) for name, kind in required.items()]
        + [pa.field(name, pa.float64()) for name in times]
        + [pa.field("sessions", pa.string())]  # a session-id prefix; null: every session
    )


def audit_schema() -> pa.Schema:
    """The ``audit`` table (:mod:`tactus_memory.storage.audit`): one row per write, delete
    or key change."""
    import pyarrow as pa

    kinds = {"t": pa.float64(), "key_id": pa.string(), "tenant": pa.string()}
    kinds |= {"route": pa.string(), "status": pa.int64(), "count": pa.int64()}
    return pa.schema([pa.field(name, kind, nullable=False) for name, kind in kinds.items()])


# --------------------------------------------------------------------------- index config
#: partitions probed on an index recorded without a measurement: 80 of a 1M table's 244
#: reached recall@10 1.0 for text queries over realistic touch + note vectors (20: 0.90;
#: benchmarks/search_1m.py, results/search_1m.json)
UNMEASURED_NPROBES = 80


@dataclass
class IndexConfig:
    """Vector/scalar index policy. Defaults chosen by ``benchmarks/memory.py``
    (benchmarks/README.md)."""

    #: build the ANN index once the table has this many rows (flat search below it)
    threshold: int = 20_000
    #: build the scalar indexes (session, sense, t, id) from this many rows
    scalar_threshold: int = 10_000
    index_type: str = "IVF_SQ"
    #: rows per IVF partition (num_partitions = rows / this). 1024 (976 partitions at 1M):
    #: each sense's query scores fewer rows (notes 48 probes of 1024 rows against 24 of
    #: 4096; a touch query's sense filter skips the note partitions cheaply): search p50
    #: 7-14 % lower than with 4096 at load ~2 (a tie at load 6), recall@10 0.999
    #: (benchmarks/search_1m.py, results/search_1m_pq.json)
    rows_per_partition: int = 1024
    #: partitions probed; None (the default): the fewest that reached ``target_recall`` on
    #: the index when it was built (recorded with it: StoreIndexes.probes), or
    #: ``UNMEASURED_NPROBES`` for an index built before; a number pins it (benchmark sweeps)
    nprobes: int | None = None
    #: recall@10 an index's probes are chosen for, measured when it is built
    target_recall: float = 0.98
    #: queries (stored rows, jittered) that measurement asks, each also answered exactly
    tune_queries: int = 24
    #: candidates re-scored with full vectors: SQ's error decides between near-equal touch
    #: windows (recall 0.83 without it, at every nprobes; search_1m.json)
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
    #: run maintenance (size-tiered compaction, incremental index update, version cleanup:
    #: :mod:`tactus_memory.storage.compaction`) after this many appends by this process
    compact_every: int = 64
    #: scalar index type per column (x, y: a ``near=`` filter's box is answered from the
    #: indexes, not a scan; z is not indexed, see Where.near; benchmarks/places.py)
    scalar: dict[str, str] = field(
        default_factory=lambda: {
            "id": "BTREE",
            "session": "BTREE",
            "sense": "BITMAP",
            "t": "BTREE",
            "x": "BTREE",
            "y": "BTREE",
        }
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
    if kind == "IVF_RQ":  # RaBitQ, 1 bit per dimension (needs a refine factor)
        return ix.IvfRq(**common)
    if kind == "IVF_FLAT":
        return ix.IvfFlat(**common)
    raise InvalidInputError(f"unsupported vector index type {cfg.index_type!r}")


def scalar_index_config(kind: str) -> Any:
    from lancedb import index as ix

    return {"BTREE": ix.BTree, "BITMAP": ix.Bitmap}[kind.upper()]()
