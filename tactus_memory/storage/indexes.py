"""The items table's indexes: the ANN index on ``vector`` and the scalar (BTREE/BITMAP)
indexes of the filters, when they are due and how they are built (``IndexConfig``,
:mod:`tactus_memory.storage.tables`). A part of :class:`~tactus_memory.storage.store.Store`, which
calls
:meth:`StoreIndexes.build_indexes` from its maintenance run."""

from __future__ import annotations

import json
import logging
import math
import time
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from tactus_memory.storage.codes import coded_query, embedding_distance, strip_table
from tactus_memory.storage.tables import (
    HIT_COLUMNS,
    UNMEASURED_NPROBES,
    IndexConfig,
    scalar_index_config,
    vector_index_config,
)
from tactus_memory.vectors import as_unit_rows, vector_column
from tactus_memory.where import Where, within_sessions

if TYPE_CHECKING:  # heavy imports stay lazy
    import pyarrow as pa

log = logging.getLogger(__name__)

#: probes measured in turn (then every partition); past 256 in steps of an eighth, for an
#: index of small partitions whose touch rows lie behind every note partition
LADDER = (4, 8, 12, 16, 24, 32, 40, 48, 64, 80, 96, 128, 160, 192, 224, 256) + tuple(
    int(256 * 1.125**i) // 8 * 8 for i in range(1, 30)
)


class StoreIndexes:
    """Index state and builds of one store's items table (mixed into ``Store``)."""

    index: IndexConfig
    _indexed: bool
    _scalar_indexed: bool
    _partitions: int | None
    _probes: int | None
    _sense_probes: dict[str, int] | None

    items: Any  # the LanceDB table (Store.items)
    #: ((id of the items table, its version), its lance dataset at that version): nearest()
    _lance: tuple[tuple[int, int], Any] | None = None
    _meta: Any  # the store's meta table (Store._meta), None before it exists
    _schema: Any  # the items table's schema as first read (Store.schema)

    if TYPE_CHECKING:  # Store's, used here

        def count(self, where: str | None = None) -> int: ...
        def dim(self) -> int: ...
        def codes(self) -> int: ...
        def version(self) -> int: ...
        def present(self, columns: Sequence[str]) -> list[str]: ...
        def get_meta(self, key: str) -> str | None: ...
        def set_meta(self, key: str, value: str) -> None: ...

    def vector_search(
        self,
        vector: np.ndarray,
        k: int,
        where: str | None,
        *,
        allowed: int | None = None,
        total: int | None = None,
        columns: Sequence[str] = HIT_COLUMNS,
        flat: bool = True,
        senses: Sequence[str] | None = None,
    ) -> pa.Table:
        """vector: (D,) unit float32 -> up to k rows with ``_distance`` = 1 - cosine.

        ``allowed``: how many rows pass ``where`` (``total``: rows in the table). A selective
        filter (allowed <= ``flat_max``) is answered by an exact flat scan of the allowed
        rows (unless ``flat`` is False); otherwise the ANN index is probed, with more
        partitions the more selective the filter, so that about ``min_candidates`` allowed
        rows are scored. ``senses``: the senses searched (None: all; several: ``where``
        keeps them); one sense is added to ``where`` here and asked with its sense code
        (:mod:`tactus_memory.storage.codes`), so the index's partitions nearest the query
        are that sense's own.
        """
        cfg = self.index
        sense = senses[0] if senses is not None and len(senses) == 1 else None
        where = within_sessions(where)
        knn: dict[str, Any] = {"column": "vector", "q": vector, "k": k, "metric": "cosine"}
        indexed = self.has_vector_index()
        narrowed = where is not None or sense is not None
        if indexed and narrowed and flat and allowed is not None and allowed <= cfg.flat_max:
            knn["use_index"] = False
        elif indexed:
            nprobes = self.probes(senses)  # ``where`` keeps these senses (None: all)
            if allowed and total and allowed < total:
                per_part = allowed / self.partitions()  # the index's own partitions
                nprobes = max(nprobes, math.ceil(cfg.min_candidates / max(per_part, 1e-9)))
            knn["nprobes"] = min(nprobes, self.partitions())
            if cfg.refine_factor:
                knn["refine_factor"] = cfg.refine_factor
            if cfg.ef:  # HNSW needs ef >= the candidates it returns
                knn["ef"] = max(cfg.ef, k * (cfg.refine_factor or 1))
        cols = [*self.present(columns), "_distance"]
        return self.nearest(knn, where, cols, sense=sense)

    def nearest(
        self,
        knn: dict[str, Any],
        where: str | None,
        columns: list[str],
        sense: str | None = None,
    ) -> pa.Table:
        """One KNN query (lance's ``nearest`` parameters ``knn``, its ``q`` a (D,) unit
        embedding), prefiltered by ``where``, on the items' lance dataset at the table's
        current version; ``_distance`` is 1 - the embeddings' cosine and ``vector`` the D
        embedding columns, whether or not the store keeps sense codes. ``sense``: only that
        sense's rows are asked for (added to ``where``), with its code. Asked of the
        dataset, not through LanceDB's query builder: 2-3 ms less per search at 1M rows
        (two queries; benchmarks/search_1m.py, docs/operations/speed.md)."""
        codes, dim = self.codes(), self.dim()
        if sense is not None:
            only = Where().sense(sense).sql()
            where = f"({where}) AND {only}" if where else only
        if codes:
            knn = {**knn, "q": coded_query(knn["q"], sense, codes)}
        kw: dict[str, Any] = {"filter": where, "prefilter": True} if where else {}
        tbl = self._dataset().to_table(columns=columns, nearest=knn, **kw)
        if not codes:
            return tbl
        if "_distance" in tbl.column_names:
            import pyarrow as pa

            at = tbl.schema.get_field_index("_distance")
            d = embedding_distance(tbl.column(at).to_numpy(), sense is not None)
            tbl = tbl.set_column(at, tbl.schema.field(at), pa.array(d, pa.float32()))
        return strip_table(tbl, dim)

    def _dataset(self) -> Any:
        """The items' lance dataset at the version the LanceDB table reads now (its read
        consistency), kept between searches: a newer version is checked out of the one
        kept, which keeps its session, so the index stays cached (a dataset opened anew
        reads it again: its first search at 1M rows took 150 ms instead of 10-15)."""
        items = self.items
        key = (id(items), self.version())
        kept = self._lance
        if kept is not None and kept[0] == key:
            return kept[1]
        if kept is not None and kept[0][0] == key[0]:
            ds = kept[1].checkout_version(key[1])
        else:
            ds = items.to_lance()
        self._lance = (key, ds)
        return ds

    def partitions(self) -> int:
        """IVF partitions of the current vector index (from the store's bookkeeping)."""
        if self._partitions is None:
            info = json.loads(self.get_meta("index") or "{}")
            self._partitions = int(info.get("partitions", 1))
        return self._partitions

    def probes(self, senses: Sequence[str] | None = None) -> int:
        """Partitions a search probes: ``IndexConfig.nprobes`` when set, else the fewest
        that reached ``IndexConfig.target_recall`` on this index when it was built
        (:meth:`measure_probes`, kept in the store's index record): for a search within
        ``senses``, the most any of them needed on its own (a text query finds notes in
        the few partitions nearest to it, touch windows only many partitions further); for
        an unfiltered search or a sense not measured, the most any part needed; an index
        built before they were measured: ``UNMEASURED_NPROBES``."""
        if self.index.nprobes is not None:
            return self.index.nprobes
        if self._probes is None or self._sense_probes is None:
            info = json.loads(self.get_meta("index") or "{}")
            self._probes = int(info.get("nprobes") or UNMEASURED_NPROBES)
            self._sense_probes = {str(s): int(p) for s, p in info.get("by_sense", {}).items()}
        if senses and all(s in self._sense_probes for s in senses):
            return max(self._sense_probes[s] for s in senses)
        return self._probes

    def measure_probes(self, k: int = 10) -> dict[str, Any]:
        """Recall@k of the ANN index at a ladder of probes (each with the configured refine
        factor), unfiltered and within each sense (``sense = X``, as a search asks per sense),
        each query answered exactly by a flat scan; a hit counts when it is no farther than
        the exact k-th (ties count). The hard case is a text query searching a touch sense:
        its nearest touch rows lie in partitions far from the query (the nearest partitions
        hold notes). So the queries are the store's text probe bank when a search has cached
        it, else, within a sense, rows of the other senses (unfiltered: rows with random
        direction added). Returns the fewest probes at which every part reaches
        ``target_recall`` (else the best), the worst part's recall, and the ladder."""
        cfg = self.index
        parts = self.partitions()
        dim = self.dim()
        ds = self.items.to_lance()
        rng = np.random.default_rng(0)
        bank = self._probe_bank(dim)[: cfg.tune_queries]
        senses = ds.to_table(columns=["sense"]).column("sense").to_numpy(zero_copy_only=False)
        names, counts = np.unique(senses, return_counts=True)

        def rows(pool: np.ndarray, noise: float) -> np.ndarray:
            """``tune_queries`` rows of ``pool`` with ``noise`` times as much random
            direction added (the cached text probe bank instead, when there is one)."""
            if len(bank):
                return bank
            take = rng.choice(pool, size=min(cfg.tune_queries, len(pool)), replace=False)
            vecs = as_unit_rows(vector_column(ds.take(sorted(take), columns=["vector"]), dim))
            jitter = as_unit_rows(rng.standard_normal(vecs.shape).astype(np.float32))
            return as_unit_rows(vecs + noise * jitter)

        # unfiltered: rows moved away from themselves (cosine ~0.55 to their row); within a
        # sense: the other senses' rows, a note standing for a text query
        everything = np.arange(len(senses))
        checks: list[tuple[str | None, np.ndarray]] = [(None, rows(everything, 1.5))]
        for name, count in zip(names, counts, strict=True):
            others = np.flatnonzero(senses != name)
            if count >= k and len(others):
                checks.append((str(name), rows(others, 0.0)))

        def search(q: np.ndarray, probes: int | None, sense: str | None) -> np.ndarray:
            """The k nearest distances, as a search asks them (Store.vector_search)."""
            knn: dict[str, Any] = {"column": "vector", "q": q, "k": k, "metric": "cosine"}
            if probes is None:
                knn["use_index"] = False
            else:
                knn["nprobes"] = probes
                if cfg.refine_factor:
                    knn["refine_factor"] = cfg.refine_factor
                if cfg.ef:
                    knn["ef"] = max(cfg.ef, k * (cfg.refine_factor or 1))
            return np.asarray(self.nearest(knn, None, ["_distance"], sense)["_distance"])

        exact = [[search(q, None, sense)[-1] + 1e-6 for q in qs] for sense, qs in checks]
        # each part (unfiltered, each sense) climbs the ladder until it reaches the target
        ladders: dict[str | None, dict[int, float]] = {sense: {} for sense, _ in checks}
        steps = [p for p in LADDER if p < parts]
        for p in [*steps, parts]:
            for (sense, qs), kth in zip(checks, exact, strict=True):
                if any(r >= cfg.target_recall for r in ladders[sense].values()):
                    continue
                hits = [search(q, p, sense) <= t for q, t in zip(qs, kth, strict=True)]
                ladders[sense][p] = round(sum(int(h.sum()) for h in hits) / (k * len(qs)), 4)
        chosen = {sense: self._fewest(ladder) for sense, ladder in ladders.items()}
        best = max(chosen.values())
        # the worst part's recall at each step it was measured (a reached part: its own)
        ladder = {
            p: min(
                ls.get(p, next((r for q, r in ls.items() if q >= chosen[s]), 1.0))
                for s, ls in ladders.items()
            )
            for p in sorted({p for ls in ladders.values() for p in ls})
            if p <= best
        }
        by_sense = {s: p for s, p in chosen.items() if s is not None}
        return {"nprobes": best, "recall": ladder[best], "ladder": ladder, "by_sense": by_sense}

    def _fewest(self, ladder: dict[int, float]) -> int:
        """The fewest probes of ``ladder`` (probes -> recall) that reach the target recall,
        else the best measured."""
        reached = [p for p, r in ladder.items() if r >= self.index.target_recall]
        return min(reached) if reached else max(ladder, key=lambda p: (ladder[p], -p))

    def _probe_bank(self, dim: int) -> np.ndarray:
        """The text probe bank a search cached in the store (``probes:<space>:<n>``, the
        registry's calibration queries), or none."""
        if self._meta is not None:
            rows = self._meta.search().where("key LIKE 'probes:%'").limit(16).to_arrow()
            for value in rows.column("value").to_pylist():
                bank = np.asarray(json.loads(value or "[]"), dtype=np.float32)
                if bank.ndim == 2 and bank.shape[1] == dim and len(bank):
                    return as_unit_rows(bank, dim)
        return np.zeros((0, dim), np.float32)

    def reread_layout(self) -> None:
        """Forget what was read of the items table's schema, indexes and index record, and
        read its latest version: after its columns changed (:mod:`.migrate`)."""
        self.items.checkout_latest()
        self._schema = None
        self._indexed = self._scalar_indexed = False
        self._partitions = self._probes = self._sense_probes = None
        self._lance = None

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
        self._sense_probes = measured["by_sense"]
        log.info(
            "built %s index on %d rows in %.1fs; %d of %d partitions probed reach recall@10 %.3f "
            "(measured in %.1fs)", cfg.index_type, n, built, measured["nprobes"], parts,
            measured["recall"], time.perf_counter() - t0,
        )  # fmt: skip
