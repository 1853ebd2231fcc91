"""Retention: expiry (``retain_days``) and stale-duplicate thinning, run by maintenance.

The policy lives in the maintenance policy, so in the one settings object
(:class:`~tactus_memory.policies.MaintenanceConfig` fields ``retain_days``,
``thin_after_days``, ``thin_cosine``, ``retention_interval`` and the rule list
``retention``; ``TACTUS_<FIELD>`` or the TOML file, docs/operations/retention.md). A
:class:`RetentionRule` narrows it to a tenant, a session (an id, or a prefix ending in ``*``)
and/or a sense; for one item the most specific matching rule wins field by field (session id
over session prefix over sense over tenant; among equals, the later rule), and a field no
matching rule sets keeps the store-wide value.

* **Expiry.** An item whose ``created`` (the wall-clock time it was written, not its session
  time ``t``) is more than ``retain_days`` ago is deleted.
* **Thinning** (ReMEmbR-style: a robot parked in one place must not fill its memory with one
  view). Among the items created more than ``thin_after_days`` ago, per session, sense and
  source in time order, a *run* starts at a kept item (its anchor) and holds every following
  item whose vector is within ``thin_cosine`` of the anchor; the first and the last item of
  each run are kept, the ones between are deleted. The default bar was measured on real
  touch and text (``benchmarks/thinning.py``, ``benchmarks/results/thinning.json``).

Both are plain deletes; compaction then rewrites the fragments that held them and version
cleanup removes the old files (``erase_deleted``, :mod:`tactus_memory.storage.compaction`),
so expired and thinned data leave the store's files like a deleted session does.
"""

from __future__ import annotations

import json
import logging
import math
import threading
import time
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np

from tactus_memory.policies import RetentionRule
from tactus_memory.where import Where, _sql_float

if TYPE_CHECKING:
    import pyarrow as pa


class RetentionSettings(Protocol):
    """The retention fields of :class:`tactus_memory.policies.MaintenanceConfig`: all that
    retention reads of the policy."""

    retain_days: float | None
    thin_after_days: float | None
    thin_cosine: float
    retention: list[RetentionRule]
    retention_interval: float


class RetentionStore(Protocol):
    """What retention uses of :class:`tactus_memory.storage.store.Store` (which owns a
    :class:`Retention`)."""

    maintenance: Any  # a MaintenanceConfig

    @property
    def exists(self) -> bool: ...
    def scan(
        self, where: str | None, columns: Sequence[str], limit: int | None = None
    ) -> pa.Table: ...
    def count(self, where: str | None = None) -> int: ...
    def delete(self, where: str) -> None: ...
    def get_meta(self, key: str) -> str | None: ...
    def set_meta(self, key: str, value: str) -> None: ...
    def meta_items(self, prefix: str) -> dict[str, str]: ...
    def delete_meta(self, key: str) -> None: ...


log = logging.getLogger(__name__)

DAY_S = 86_400.0
#: the meta key of the last thinning pass's wall-clock time (rows aged past the bar since
#: then are the ones the next pass looks at)
THINNED_AT = "retention:thinned_at"
#: the meta rows of taught spans (tactus_memory/search/teaching.py writes them: JSON with
#: session, sense, t, t_end): a teaching dies with the last stored window of its span
TAUGHT_PREFIX = "taught/"
#: deletes name at most this many ids or (session, sense) pairs each
_CHUNK = 256
#: the policy fields a rule may set
POLICY_FIELDS = ("retain_days", "thin_after_days", "thin_cosine")


@dataclass(frozen=True)
class Policy:
    """The retention of one (session, sense) of one tenant."""

    retain_days: float | None
    thin_after_days: float | None
    thin_cosine: float


def resolve(cfg: RetentionSettings, tenant: str | None, session: str, sense: str) -> Policy:
    """The policy of ``session``/``sense`` in ``tenant``'s store under ``cfg``."""
    values: dict[str, Any] = {f: getattr(cfg, f) for f in POLICY_FIELDS}
    rules = sorted(
        (r for r in cfg.retention if r.matches(tenant, session, sense)),
        key=RetentionRule.specificity,
    )
    for rule in rules:  # least specific first: the most specific (then the later) wins
        for name in POLICY_FIELDS:
            if name in rule.model_fields_set:
                values[name] = getattr(rule, name)
    if values["thin_cosine"] is None:
        values["thin_cosine"] = cfg.thin_cosine
    return Policy(**values)


def _all_values(cfg: RetentionSettings, name: str) -> list[float]:
    given = [getattr(r, name) for r in cfg.retention if name in r.model_fields_set]
    return [v for v in [getattr(cfg, name), *given] if v is not None]


def thin_run_drops(vectors: np.ndarray, cosine: float) -> np.ndarray:
    """vectors: (N, D) unit rows in time order -> (N,) bool, True for the rows thinning
    drops: inside each run (an anchor and the rows after it within ``cosine`` of it), every
    row but the first and the last."""
    n = int(vectors.shape[0])
    drop = np.zeros(n, dtype=bool)
    i = 0
    while i < n:
        sims = vectors[i + 1 :] @ vectors[i]  # (N - i - 1,) cosine to the anchor
        below = np.flatnonzero(sims < cosine)
        end = i + 1 + (int(below[0]) if below.size else sims.size)  # first row of the next run
        if end - 1 > i + 1:
            drop[i + 1 : end - 1] = True
        i = end
    return drop


@dataclass
class RetentionReport:
    """What retention did to one store (this pass, and in this process so far)."""

    #: items the last pass expired and thinned, and the groups it thinned
    expired: int = 0
    thinned: int = 0
    groups_thinned: int = 0
    #: items expired and thinned by this process so far
    expired_total: int = 0
    thinned_total: int = 0
    #: when the last pass ran (unix seconds) and how long it took
    last_run: float | None = None
    seconds: float = 0.0


class Retention:
    """Applies the retention policy of one tenant's store (``Store.maintain`` calls
    :meth:`run` before compacting, at most every ``retention_interval`` seconds)."""

    def __init__(self, store: RetentionStore, tenant: str | None = None) -> None:
        self.store = store
        self.tenant = tenant
        self.report = RetentionReport()
        self._last = -math.inf
        self._lock = threading.Lock()
        self._owner: int | None = None  # the thread running a pass

    @property
    def cfg(self) -> RetentionSettings:
        return self.store.maintenance

    def enabled(self) -> bool:
        return any(_all_values(self.cfg, name) for name in ("retain_days", "thin_after_days"))

    def due(self) -> bool:
        return self.enabled() and time.monotonic() - self._last >= self.cfg.retention_interval

    def run(self, now: float | None = None, *, force: bool = False) -> RetentionReport:
        """Expire, then thin (when due, or ``force``); returns the report (counts of this
        pass and this process's totals)."""
        if self._owner == threading.get_ident():
            return self.report  # called back by the maintenance its own deletes scheduled
        if not self._lock.acquire(blocking=force):  # one pass at a time
            return self.report
        try:
            self._owner = threading.get_ident()
            if not (force or self.due()) or not self.store.exists:
                return self.report
            return self._run(time.time() if now is None else float(now))
        finally:
            self._owner = None
            self._lock.release()

    def _run(self, now: float) -> RetentionReport:
        rep = self.report
        rep.expired = rep.thinned = rep.groups_thinned = 0
        t0 = time.perf_counter()
        self._last = time.monotonic()
        rep.expired = self._expire(now)
        rep.thinned = self._thin(now)
        if rep.expired or rep.thinned:  # as a session delete: no teaching outlives its windows
            drop_orphaned_teachings(self.store)
        rep.expired_total += rep.expired
        rep.thinned_total += rep.thinned
        rep.last_run = now
        rep.seconds = time.perf_counter() - t0
        if rep.expired or rep.thinned:
            log.info("retention: %d expired, %d thinned", rep.expired, rep.thinned)
        return rep

    # ----------------------------------------------------------- expiry
    def _expire(self, now: float) -> int:
        days = _all_values(self.cfg, "retain_days")
        if not days:
            return 0
        if not self.cfg.retention:  # one store-wide age: one delete, no rows read
            return self._delete(f"created < {_sql_float(now - days[0] * DAY_S)}")
        oldest_bar = now - min(days) * DAY_S
        rows = self.store.scan(f"created < {_sql_float(oldest_bar)}", ["session", "sense"])
        sessions, senses = (rows.column(c).to_pylist() for c in ("session", "sense"))
        pairs = set(zip(sessions, senses, strict=True))
        by_cut: dict[float, list[tuple[str, str]]] = {}
        for session, sense in pairs:
            keep = resolve(self.cfg, self.tenant, session, sense).retain_days
            if keep is not None:
                by_cut.setdefault(now - keep * DAY_S, []).append((session, sense))
        removed = 0
        for cut, group in by_cut.items():
            for part in _chunks(sorted(group)):
                removed += self._delete(f"created < {_sql_float(cut)} AND ({_pairs_sql(part)})")
        return removed

    # ----------------------------------------------------------- thinning
    def _thin(self, now: float) -> int:
        after = _all_values(self.cfg, "thin_after_days")
        if not after:
            return 0
        since = float(self.store.get_meta(THINNED_AT) or -math.inf)
        lo, hi = since - max(after) * DAY_S, now - min(after) * DAY_S
        where = f"created < {_sql_float(hi)}"
        if math.isfinite(lo):
            where += f" AND created >= {_sql_float(lo)}"
        rows = self.store.scan(where, ["session", "sense", "source", "created"])
        groups: dict[tuple[str, str, str], Policy] = {}
        policies: dict[tuple[str, str], Policy] = {}
        for session, sense, source, created in zip(
            *(rows.column(c).to_pylist() for c in ("session", "sense", "source", "created")),
            strict=True,
        ):
            key = (session, sense, source)
            policy = policies.get((session, sense))
            if policy is None:
                policy = policies[(session, sense)] = resolve(self.cfg, self.tenant, session, sense)
            wait = policy.thin_after_days
            # a row that aged past its own bar since the last pass
            if wait is not None and since - wait * DAY_S <= created < now - wait * DAY_S:
                groups[key] = policy
        removed = 0
        for (session, sense, source), policy in sorted(groups.items()):
            assert policy.thin_after_days is not None
            removed += self._thin_group(session, sense, source, policy, now)
            self.report.groups_thinned += 1
        self.store.set_meta(THINNED_AT, json.dumps(now))
        return removed

    def _thin_group(self, session: str, sense: str, source: str, policy: Policy, now: float) -> int:
        bar = now - float(policy.thin_after_days or 0.0) * DAY_S
        where = Where().session(session).sense(sense).source(source).sql()
        rows = self.store.scan(f"{where} AND created < {_sql_float(bar)}", ["id", "t", "vector"])
        if rows.num_rows < 3:
            return 0
        ids = np.asarray(rows.column("id").to_pylist(), dtype=object)
        t = rows.column("t").to_numpy()
        order = np.lexsort((ids.astype(str), t))  # time order (ties: by id, stable across passes)
        vectors = np.stack(rows.column("vector").to_numpy(zero_copy_only=False))[order]
        doomed = ids[order][thin_run_drops(vectors.astype(np.float32), policy.thin_cosine)]
        removed = 0
        for part in _chunks(list(doomed)):
            removed += self._delete(Where().ids(part).sql() or "false")
        return removed

    def _delete(self, where: str) -> int:
        n = self.store.count(where)
        if n:
            self.store.delete(where)
        return n


def drop_orphaned_teachings(store: RetentionStore) -> int:
    """Delete every teaching whose span holds no stored row of its session and sense any
    more (expired, thinned or deleted by id), as a session delete drops the session's
    teachings (issue 48: a label taught on an expired session was still listed); returns how
    many. One count per teaching: teachings are few, and this runs after deletes only."""
    dropped = 0
    for key, raw in store.meta_items(TAUGHT_PREFIX).items():
        try:
            rec = json.loads(raw)
            span = Where().session(rec["session"]).sense(rec["sense"])
            where = span.overlaps(rec["t"], rec["t_end"]).sql()
        except (TypeError, ValueError, KeyError):
            continue  # a record of a later version: not ours to judge
        if store.count(where) == 0:
            store.delete_meta(key)
            dropped += 1
    return dropped


def _chunks(values: Sequence[Any]) -> Iterable[Sequence[Any]]:
    for i in range(0, len(values), _CHUNK):
        yield values[i : i + _CHUNK]


def _pairs_sql(pairs: Sequence[tuple[str, str]]) -> str:
    return " OR ".join(f"({Where().session(s).sense(n).sql()})" for s, n in pairs)


class Erasure:
    """Whether a store's deleted rows may still be in its files. Deleted rows stay in their
    fragment (a deletion file marks them) until compaction rewrites it (``erase_deleted``),
    and in the older versions' files until cleanup removes them (``retain_seconds`` after
    they were superseded): the deletes so far are erased once a compaction left no deleted
    row and a cleanup ran ``retain_seconds`` after it."""

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.deletes = 0  # deletes of items rows so far (this process)
        self._compacted: tuple[int, float] | None = None  # (deletes covered, when)
        self._cleaned = -math.inf  # when the last cleanup started
        self._erased = 0

    def note_delete(self) -> None:
        with self.lock:
            self.deletes += 1

    def note_compacted(self, deletes: int, deleted_rows_left: int) -> None:
        """After compaction, which started once ``deletes`` deletes were committed."""
        if deleted_rows_left == 0:
            with self.lock:  # (a pass with no new delete leaves the earlier time)
                if self._compacted is None or deletes > self._compacted[0]:
                    self._compacted = (deletes, time.time())

    def note_cleanup(self, started: float, retain_seconds: float) -> None:
        with self.lock:
            self._cleaned = max(self._cleaned, started)
            done = self._compacted
            if done is not None and self._cleaned >= done[1] + retain_seconds:
                self._erased = max(self._erased, done[0])

    def pending(self) -> bool:
        """True while some delete's rows may still be in a file of the store."""
        with self.lock:
            return self.deletes > self._erased

    def due(self, retain_seconds: float) -> bool:
        """Whether a maintenance pass now would erase more: deleted rows not compacted
        away yet, or compacted ones whose old versions a cleanup may now remove."""
        with self.lock:
            done = self._compacted
            if self.deletes <= self._erased:
                return False
            return done is None or done[0] < self.deletes or time.time() >= done[1] + retain_seconds
