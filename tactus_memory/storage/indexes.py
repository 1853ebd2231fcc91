"""The items table's indexes: the ANN index on ``vector`` and the scalar (BTREE/BITMAP)
indexes of the filters, when they are due and how they are built (``IndexConfig``,
:mod:`tactus_memory.storage.tables`). A part of :class:`~tactus_memory.storage.store.Store`, which
calls
:meth:`StoreIndexes.build_indexes` from its maintenance run."""

from __future__ import annotations

import json
import logging
import time
from typing import TYPE_CHECKING, Any

from tactus_memory.storage.tables import IndexConfig, scalar_index_config, vector_index_config

log = logging.getLogger(__name__)


class StoreIndexes:
    """Index state and builds of one store's items table (mixed into ``Store``)."""

    index: IndexConfig
    _indexed: bool
    _scalar_indexed: bool
    _partitions: int | None

    items: Any  # the LanceDB table (Store.items)

    if TYPE_CHECKING:  # Store's, used here

        def count(self, where: str | None = None) -> int: ...
        def dim(self) -> int: ...
        def get_meta(self, key: str) -> str | None: ...
        def set_meta(self, key: str, value: str) -> None: ...

    def partitions(self) -> int:
        """IVF partitions of the current vector index (from the store's bookkeeping)."""
        if self._partitions is None:
            info = json.loads(self.get_meta("index") or "{}")
            self._partitions = int(info.get("partitions", 1))
        return self._partitions

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
