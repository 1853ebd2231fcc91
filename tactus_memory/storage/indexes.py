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

import numpy as np

from tactus_memory.storage.tables import (
    UNMEASURED_NPROBES,
    IndexConfig,
    scalar_index_config,
    vector_index_config,
)
from tactus_memory.storage.vectors import as_unit_rows, vector_column

log = logging.getLogger(__name__)


class StoreIndexes:
    """Index state and builds of one store's items table (mixed into ``Store``)."""

    index: IndexConfig
    _indexed: bool
    _scalar_indexed: bool
    _partitions: int | None
    _probes: int | None

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

    def probes(self) -> int:
        """Partitions a search probes: ``IndexConfig.nprobes`` when set, else the fewest
        that reached ``IndexConfig.target_recall`` on this index when it was built
        (:meth:`measure_probes`, kept in the store's index record), else
        ``UNMEASURED_NPROBES`` (an index built before they were measured)."""
        if self.index.nprobes is not None:
            return self.index.nprobes
        if self._probes is None:
            info = json.loads(self.get_meta("index") or "{}")
            self._probes = int(info.get("nprobes") or UNMEASURED_NPROBES)
        return self._probes

    def measure_probes(self, k: int = 10) -> dict[str, Any]:
        """Recall@k of the ANN index at a ladder of probes (each with the configured refine
        factor), on ``tune_queries`` queries: stored rows with as much random direction added
        (cosine ~0.55 to their row, as far as a text query is from what it finds), each
        answered exactly by a flat scan. A hit counts when it is no farther than the exact
        k-th (ties count). Returns the fewest probes reaching ``target_recall`` (else the
        best), their recall, and the ladder."""
        cfg = self.index
        parts = self.partitions()
        ds = self.items.to_lance()
        n = ds.count_rows()
        rng = np.random.default_rng(0)
        rows = np.sort(rng.choice(n, size=min(cfg.tune_queries, n), replace=False))
        vecs = as_unit_rows(vector_column(ds.take(rows.tolist(), columns=["vector"]), self.dim()))
        noise = rng.standard_normal(vecs.shape).astype(np.float32)
        noise *= 1.5 / np.linalg.norm(noise, axis=1, keepdims=True)
        queries = as_unit_rows(vecs + noise)

        def search(q: np.ndarray, probes: int | None) -> np.ndarray:
            s = self.items.search(q, vector_column_name="vector").distance_type("cosine")
            if probes is None:
                s = s.bypass_vector_index()
            else:
                s = s.nprobes(probes)
                if cfg.refine_factor:
                    s = s.refine_factor(cfg.refine_factor)
                if cfg.ef:
                    s = s.ef(max(cfg.ef, k * (cfg.refine_factor or 1)))
            return np.asarray(s.select(["_distance"]).limit(k).to_arrow()["_distance"])

        kth = [search(q, None)[-1] + 1e-6 for q in queries]
        ladder: dict[int, float] = {}
        steps = [p for p in (4, 8, 12, 16, 24, 32, 48, 64, 96, 128, 192, 256) if p < parts]
        for p in [*steps, parts]:
            got = [int((search(q, p) <= t).sum()) for q, t in zip(queries, kth, strict=True)]
            ladder[p] = round(sum(got) / (k * len(queries)), 4)
            if ladder[p] >= cfg.target_recall:
                break
        best = next((p for p, r in ladder.items() if r >= cfg.target_recall), None)
        if best is None:
            best = max(ladder, key=lambda p: (ladder[p], -p))
        return {"nprobes": best, "recall": ladder[best], "ladder": ladder}

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
        self._partitions = parts
        built = time.perf_counter() - t0
        t0 = time.perf_counter()
        measured = self.measure_probes()
        info = {"rows": n, "type": cfg.index_type, "partitions": parts, **measured}
        info["ladder"] = {str(p): r for p, r in measured["ladder"].items()}
        self.set_meta("index", json.dumps(info))
        self._probes = measured["nprobes"]
        log.info(
            "built %s index on %d rows in %.1fs; %d of %d partitions probed reach recall@10 %.3f "
            "(measured in %.1fs)", cfg.index_type, n, built, measured["nprobes"], parts,
            measured["recall"], time.perf_counter() - t0,
        )  # fmt: skip
