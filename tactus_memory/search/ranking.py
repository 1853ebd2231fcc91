"""The one ranked search path: a (1, D) unit query -> per-sense query transform, prefiltered
ANN (or exact flat) search in the store, calibrated scores, merged top k (or, ``each=True``,
every sense's own top k). ``Memory.search`` (every group), ``search_vector``, ``search_like``
and every temporal question end here, each in one :meth:`Ranker.rank` call: the senses in
scope are asked at once, in one pass (grasps are grouped after it,
:mod:`tactus_memory.search.evidence`).
"""

from __future__ import annotations

import contextvars
import math
import threading
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor
from typing import Any

import numpy as np

from tactus_memory.results import Hit, hit_from_row
from tactus_memory.search.captions import Captions
from tactus_memory.search.scoring import Calibration
from tactus_memory.senses.stored import SenseRegistry
from tactus_memory.storage.spans import Spans
from tactus_memory.storage.store import Store
from tactus_memory.vectors import as_unit_rows
from tactus_memory.where import Where

#: the modality whose windows are also found by their captions (search.captions)
CAPTIONED = "touch"

_POOL: ThreadPoolExecutor | None = None
_POOL_LOCK = threading.Lock()


def _group_pool() -> ThreadPoolExecutor:
    """The threads that ask a search's groups at once (shared by every Ranker)."""
    global _POOL
    with _POOL_LOCK:
        if _POOL is None:
            _POOL = ThreadPoolExecutor(max_workers=8, thread_name_prefix="tactus-ann")
        return _POOL


class Ranker:
    """Ranked search over one store, with the registry's transforms and calibrations."""

    #: ask the ANN queries of a search's groups (senses with different query vectors) at
    #: once; False: one after the other (benchmarks/search_1m.py compares both)
    parallel_groups: bool = True
    #: with an ANN index, ask each sense on its own (at the probes its own recall needed,
    #: StoreIndexes.probes) rather than one query for the senses sharing a query vector:
    #: a text query's nearest notes lie in the few partitions nearest to it, its best
    #: touch windows (by calibrated score) many partitions further, so the shared query
    #: would probe them all and then still ask touch again (benchmarks/search_1m.py)
    split_senses: bool = True

    def __init__(self, store: Store, registry: SenseRegistry) -> None:
        self.store = store
        self.registry = registry
        self.space = registry.space
        #: the longest item, to narrow a time window to the t index (Where.narrowed)
        self.spans = Spans()
        #: ``(q, sense, transformed) -> (1, D)``: the taught labels' steering of a text query
        #: (:meth:`tactus_memory.search.teaching.Teachings.steer`); None: none
        self.steer: Any = None
        #: touch windows found in words by their captions (a text query's, ``transform``)
        self.captions = Captions(store, registry.space, registry)

    def rank(
        self,
        q: np.ndarray,
        k: int,
        senses: Sequence[str],
        base: Where,
        *,
        transform: bool,
        each: bool = False,
    ) -> list[Hit]:
        """The one search path: q (1, D) unit query -> per-sense query transform, prefiltered
        ANN (or exact flat) search, calibrated scores, merged top k. ``base`` holds the
        non-sense conditions (session, time, source, ...); temporal operators reuse this.
        ``each=True``: every sense's own top k (up to ``k * len(senses)`` hits, best first),
        each sense asked on its own (the temporal questions' candidates, a bar per sense),
        all in the same concurrent pass.

        With an ANN index each sense is asked on its own, at its own probes, the senses at
        once (``split_senses``, ``parallel_groups``). Otherwise (exact flat scans) senses
        whose transformed query vectors coincide (e.g. identity transforms) share one
        LanceDB query fetching ``k * len(group)`` candidates; a sense with fewer than k of
        them gets its own query unless its best possible missing z-score (bounded by the
        lowest candidate cosine) cannot reach the current k-th score. Either way the merge
        is that of one query per sense.
        """
        counts = self.registry.counts(exact=False)
        active = [name for name in senses if counts.get(name, 0) > 0]
        if active and base.after is not None:  # rows exist: so does the items table
            base = base.narrowed(self.spans.longest(self.store.items))
        groups: list[tuple[np.ndarray, list[str]]] = []
        for name in active:
            qs = self.query_for(q, name) if transform else q
            for vec, names in groups:
                if np.array_equal(vec, qs):
                    names.append(name)
                    break
            else:
                groups.append((qs, [name]))
        if each or (self.split_senses and self.store.has_vector_index()):
            groups = [(vec, [name]) for vec, names in groups for name in names]
        calib = {name: self.registry.calibration(name) for name in active}
        scored: list[tuple[float, float, dict[str, Any]]] = []
        if len(groups) > 1 and self.parallel_groups:
            # the groups' ANN queries at once (LanceDB runs each on its own threads, without
            # the interpreter lock): a search costs its slowest group, not their sum. Each
            # group prunes its follow-ups on its own candidates only, which may ask more
            # but never changes the merge.
            # each job in a copy of this context: the session scope (``sessions_under``, a
            # tenant's prefix) is a context variable and must hold in the pool's threads
            pool = _group_pool()
            search = self._search_group
            jobs = [
                pool.submit(
                    contextvars.copy_context().run, search, vec[0], k, ns, base, counts, calib, []
                )
                for vec, ns in groups
            ]
            for job in jobs:
                scored.extend(job.result())
        else:
            for vec, names in groups:
                scored.extend(self._search_group(vec[0], k, names, base, counts, calib, scored))
        touch = [n for n in active if self.registry.search_sense(n).modality == CAPTIONED]
        if transform and touch:
            scored = self.captions.merge(scored, q, k, touch, base)
        scored.sort(key=lambda x: -x[0])  # stable: a sense's hits keep their order among ties
        if each:  # every sense's own top k (its captions' windows among them)
            kept: dict[str, int] = {}
            top = []
            for item in scored:
                sense = item[2]["sense"]
                if kept.get(sense, 0) < k:
                    kept[sense] = kept.get(sense, 0) + 1
                    top.append(item)
        else:
            top = scored[:k]
        return [hit_from_row(row, score, cos) for score, cos, row in top]

    def query_for(self, q: np.ndarray, name: str) -> np.ndarray:
        """The (1, D) text query ``q`` as sense ``name`` compares it: its query transform."""
        s = self.registry.search_sense(name)
        out = as_unit_rows(s.query_transform(q), self.space.dim, what="query")
        if self.steer is not None:
            out = as_unit_rows(self.steer(q, name, out), self.space.dim, what="query")
        return out

    def _search_group(
        self,
        vec: np.ndarray,
        k: int,
        names: list[str],
        base: Where,
        counts: dict[str, int],
        calib: dict[str, Calibration],
        found: list[tuple[float, float, dict[str, Any]]],
    ) -> list[tuple[float, float, dict[str, Any]]]:
        """One ANN query for senses sharing a query vector (D,), plus follow-ups if needed."""
        total = sum(counts.values())
        every = {name for name, c in counts.items() if c > 0}
        where = base.copy()
        if set(names) != every:
            where.senses(names)
        sql = where.sql()
        # a place or time filter's rows are estimated from the scalar indexes alone: enough
        # to size the search, and it spares a scan (the sphere test, the items' ends)
        allowed = self._allowed(base, where, names, counts)
        if allowed == 0:
            return []
        want = k * len(names)
        flat = not base.scattered  # scattered rows: the prefiltered ANN search is cheaper
        # one sense: storage adds its condition itself, with the sense's code
        # (StoreIndexes.vector_search)
        asked = base.sql() if len(names) == 1 else sql
        rows = self.store.vector_search(
            vec, want, asked, allowed=allowed, total=total, flat=flat, senses=names
        )
        out = [self._scored(row, calib) for row in rows.to_pylist()]
        if len(names) == 1 or len(out) < want:
            return out  # complete: every allowed row was a candidate or one sense only
        floor = min(cos for _, cos, _ in out)
        have = {name: sum(1 for _, _, r in out if r["sense"] == name) for name in names}
        for name in names:
            if have[name] >= k:
                continue
            ranked = sorted([z for z, _, _ in found] + [z for z, _, _ in out], reverse=True)
            kth = ranked[k - 1] if len(ranked) >= k else -math.inf
            if calib[name].score(floor) <= kth:
                continue  # nothing of this sense below the floor can enter the top k
            one = base.copy().sense(name)
            n_one = self._allowed(base, one, [name], counts)
            extra = self.store.vector_search(
                vec, k, base.sql(), allowed=n_one, total=total, flat=flat, senses=[name]
            )
            out = [x for x in out if x[2]["sense"] != name]
            out.extend(self._scored(row, calib) for row in extra.to_pylist())
        return out

    def _allowed(self, base: Where, where: Where, names: list[str], counts: dict[str, int]) -> int:
        """About how many rows of senses ``names`` pass ``where`` (``base`` and a sense
        condition), to size the search: the senses' row counts when ``base`` has no
        condition, else the scalar indexes' estimate (Where.count_sql), or the exact count
        when the estimate is 0 (a time window's leaves out items that began before it)."""
        if not base.parts:
            return sum(counts[n] for n in names)
        return self.store.count(where.count_sql()) or self.store.count(where.sql())

    @staticmethod
    def _scored(
        row: dict[str, Any], calib: dict[str, Calibration]
    ) -> tuple[float, float, dict[str, Any]]:
        cos = 1.0 - float(row.pop("_distance"))
        return float(calib[row["sense"]].score(cos)), cos, row
