"""Compaction, index refresh and version cleanup of one table: bounded disk while ingest runs.

Three jobs, run by one process per store (the *maintainer*: ``tactus maintain``, or a
``tactus serve`` without ``--no-maintain``), each on every table of the store:

1. **Size-tiered compaction.** Streaming writes make one small fragment per commit. A fragment
   is in tier 0 below ``tier_base_bytes`` and in tier ``k`` when it is about
   ``tier_base_bytes * fan_in**(k-1)`` to ``fan_in`` times that. A run of at least
   ``fan_in`` adjacent fragments of one tier is merged into one fragment of the next tier
   (Lance ``compact_files`` with every other fragment excluded), so each row is rewritten
   about ``log_fan_in(table bytes / tier_base_bytes)`` times in its life, and fragments of
   ``settled_bytes`` or more are never rewritten again (only a fragment whose deleted share
   passes ``deletion_threshold`` is rewritten alone, to drop the deleted rows). LanceDB's own
   ``optimize()`` instead merges every fragment under 1M rows each time: with ~16 KB touch
   rows that is the whole table, rewritten every 64 appends (issue 11: 30x disk).
2. **Index refresh.** Rows appended since the last run are merged into the existing indices
   incrementally (Lance ``optimize_indices``), never a rebuild. Retraining the ANN index is
   the store's separate, rare decision (:meth:`tactus_memory.storage.store.Store.maintain`).
3. **Version retention.** Every commit is a version; a version's files go only when no
   version still kept needs them. A version is removed once it was *superseded* more than
   ``retain_seconds`` ago (not merely created that long ago), so a reader that opened it just
   before a compaction or delete has ``retain_seconds`` to finish. The maintainer notes which
   version was the latest at each run; the first run reads the version history once.

Before these, retention (expiry, stale-duplicate thinning:
:mod:`tactus_memory.storage.retention`) deletes what the policy says. With ``erase_deleted``
compaction rewrites every fragment that holds a deleted row, and a delete that is a table's
latest version is superseded by an empty commit (its manifest names the delete's filter),
so once cleanup has run ``retain_seconds`` later no file of the store holds deleted data
(docs/operations/retention.md).

Disk then stays near the live data: the extra is what compaction rewrote within the last
``retain_seconds`` plus the small tier-0 tail (measured by ``benchmarks/disk.py``).

Knobs: :class:`MaintenanceConfig` (settings ``TACTUS_*``, :mod:`tactus_memory.settings`;
docs/operations/maintenance.md).
"""

from __future__ import annotations

import contextlib
import logging
import math
import threading
import time
from collections import deque
from dataclasses import dataclass
from typing import Any

from tactus_memory.policies import MaintenanceConfig, MiB
from tactus_memory.storage import orphans

log = logging.getLogger(__name__)


#: Lance rewrites a fragment whose deleted share is above this (erase_deleted: any deletion)
ERASE_BAR = 1e-9


# --------------------------------------------------------------------------- planning
@dataclass(frozen=True)
class FragmentInfo:
    """One fragment as the planner sees it."""

    id: int
    rows: int  # physical rows, deleted included
    deleted: int
    bytes: int  # data files on disk


def tier_of(nbytes: int, cfg: MaintenanceConfig) -> int | None:
    """The size tier of a fragment of ``nbytes`` (None: settled, never merged)."""
    if nbytes >= cfg.settled_bytes:
        return None
    if nbytes < cfg.tier_base_bytes:
        return 0
    return 1 + int(math.log(nbytes / cfg.tier_base_bytes, cfg.fan_in))


def plan_compaction(frags: list[FragmentInfo], cfg: MaintenanceConfig) -> list[list[int]]:
    """Groups of fragment ids to rewrite, each group into one fragment (fragments in table
    order), cheapest tier first.

    For tier T = 0, 1, ...: in a run of adjacent fragments all of tier <= T, the fragments up
    to and including its ``fan_in``-th fragment *of tier T* are a group (tier 0: the whole
    run once it has ``fan_in``, cut into consecutive groups within the budget below when it
    is larger: a burst of writes between two passes, 64 gloves streaming 4 MB/s for a 10 s
    interval, would otherwise leave a tail no merge may take, growing for ever; smaller stragglers
    inside it, e.g. appends that landed between a merge's inputs and its output, are absorbed
    rather than stranded). A group may rewrite at most ``max_merge_share`` of the table's
    bytes (or ``free_merge_bytes``): a larger merge waits until the table has grown, which
    bounds the disk spike of keeping its inputs for ``retain_seconds``. The first tier with
    a group wins. Without any, each fragment whose deleted share passes
    ``deletion_threshold`` (with ``erase_deleted``: any deleted row) is a group alone.
    Settled fragments (tier None) are boundaries.
    """
    tiers = [tier_of(f.bytes, cfg) for f in frags]
    top = max((t for t in tiers if t is not None), default=-1)
    size = {f.id: f.bytes for f in frags}
    budget = max(cfg.free_merge_bytes, cfg.max_merge_share * sum(size.values()))
    for level in range(top + 1):
        groups: list[list[int]] = []
        run: list[int] = []
        at_level = 0
        for f, tier in zip([*frags, None], [*tiers, None], strict=True):
            if f is not None and tier is not None and tier <= level:
                run.append(f.id)
                at_level += tier == level
                if at_level < cfg.fan_in or level == 0:
                    continue  # the tier-0 tail is merged whole (it is small)
            if at_level >= cfg.fan_in and sum(size[i] for i in run) <= budget:
                groups.append(run)
            elif level == 0 and at_level >= cfg.fan_in:  # a tail longer than the budget
                groups += _chunks(run, size, budget, cfg.fan_in)
            run, at_level = [], 0
        if groups:
            return groups
    bar = 0.0 if cfg.erase_deleted else cfg.deletion_threshold
    return [[f.id] for f in frags if f.deleted and f.deleted / f.rows >= bar and f.deleted < f.rows]


def _chunks(run: list[int], size: dict[int, int], budget: float, least: int) -> list[list[int]]:
    """``run`` (tier-0 fragment ids, in order) cut into consecutive groups of at most
    ``budget`` bytes; a group of fewer than ``least`` fragments (the end of the run) waits."""
    out: list[list[int]] = []
    group: list[int] = []
    total = 0
    for i in run:
        if group and total + size[i] > budget:
            out.append(group)
            group, total = [], 0
        group.append(i)
        total += size[i]
    return [g for g in [*out, group] if len(g) >= least]


# --------------------------------------------------------------------------- running
@dataclass
class TableReport:
    """What one maintenance run did to one table."""

    table: str
    version: int
    fragments: int
    compacted_groups: int = 0
    fragments_removed: int = 0
    indices_refreshed: bool = False
    versions_removed: int = 0
    bytes_removed: int = 0
    orphans_removed: int = 0  # unreferenced files of a crashed writer (storage/orphans.py)
    seconds: float = 0.0


def fragment_infos(ds: Any) -> list[FragmentInfo]:
    """FragmentInfo per fragment of a Lance dataset, in table order."""
    out = []
    for frag in ds.get_fragments():
        m = frag.metadata
        nbytes = sum(int(f.file_size_bytes or 0) for f in m.files)
        out.append(FragmentInfo(int(m.id), int(m.physical_rows), int(m.num_deletions), nbytes))
    return out


class TableMaintainer:
    """Maintains one Lance table (by URI). Keeps the version history this process has seen,
    for the superseded-since rule of version retention. Compaction and cleanup may run in
    different threads (each one at a time): cleanup reads every kept version's manifest, so
    it must not hold compaction up."""

    #: compactions per run at most (a cascade: a merged tail completes the next tier's run)
    MAX_GROUPS_PER_RUN = 8

    def __init__(
        self,
        uri: str,
        storage_options: dict[str, str],
        cfg: MaintenanceConfig,
        commit_lock: threading.Lock | None = None,
    ):
        self.uri = uri
        # held while a compaction commits, so this process's own appends (which take it too)
        # do not race it; other processes' commits are resolved by Lance's retries
        self.commit_lock = commit_lock
        self.name = uri.rstrip("/").rsplit("/", 1)[-1]
        self.storage_options = dict(storage_options)
        self.cfg = cfg
        # (wall time, latest version then): every version below it was superseded by then
        self._seen: deque[tuple[float, int]] = deque()
        self._history_read = False
        self._removed_below = 0
        self._swept_at = -math.inf
        self._compact_lock = threading.Lock()
        self._cleanup_lock = threading.Lock()
        self._seen_lock = threading.Lock()
        #: what cleanups in this process removed so far (cleanup may run in its own thread)
        self.versions_removed_total = 0
        self.bytes_removed_total = 0

    def _dataset(self) -> Any:
        import lance

        return lance.dataset(self.uri, storage_options=self.storage_options or None)

    def run(self, *, cleanup: bool = True) -> TableReport:
        report = self.compact()
        if cleanup:
            self.cleanup(report)
        return report

    def compact(self) -> TableReport:
        """Size-tiered compaction, then the incremental index refresh."""
        with self._compact_lock:
            t0 = time.perf_counter()
            ds = self._dataset()
            report = TableReport(self.name, ds.version, 0)
            for _ in range(self.MAX_GROUPS_PER_RUN):
                frags = fragment_infos(ds)
                groups = plan_compaction(frags, self.cfg)
                if not groups:
                    break
                self._compact_group(ds, frags, groups[0], report)
                ds = self._dataset()  # re-plan on the new layout (new fragment ids)
            self._refresh_indices(ds, report)
            if self.cfg.erase_deleted:
                self._seal(self._dataset())
            ds = self._dataset()
            report.version = ds.version
            report.fragments = len(ds.get_fragments())
            self._observe(time.time(), ds.version)
            report.seconds = time.perf_counter() - t0
            return report

    def _compact_group(
        self, ds: Any, frags: list[FragmentInfo], group: list[int], report: TableReport
    ) -> None:
        from lance.optimize import Compaction

        keep = set(group)
        rows = sum(f.rows for f in frags if f.id in keep)
        nbytes = sum(f.bytes for f in frags if f.id in keep)
        options = {
            # every fragment of the group is a candidate (rows < target) and the group
            # becomes one fragment; the rest are excluded (and act as boundaries)
            "target_rows_per_fragment": rows + 1,
            "max_bytes_per_file": max(4 * nbytes, 64 * MiB),
            "excluded_fragment_ids": [f.id for f in frags if f.id not in keep],
            "materialize_deletions": True,
            "materialize_deletions_threshold": ERASE_BAR
            if self.cfg.erase_deleted
            else self.cfg.deletion_threshold,
            "num_threads": self.cfg.num_threads,
        }
        plan = Compaction.plan(ds, options)
        rewrites = [task.execute(ds) for task in plan.tasks]  # the slow part: no lock
        if not rewrites:
            return
        with self.commit_lock or contextlib.nullcontext():
            metrics = Compaction.commit(ds, rewrites, options)
        report.compacted_groups += 1
        report.fragments_removed += int(metrics.fragments_removed)

    def _seal(self, ds: Any) -> None:
        """A delete's filter (ids, session names) is written into its version's manifest and
        transaction file; while that version is the latest, cleanup keeps it. An empty
        delete supersedes it, so cleanup removes it after ``retain_seconds`` like any other."""
        try:
            op = getattr(ds.read_transaction(ds.version), "operation", None)
        except Exception:  # noqa: BLE001  (pylance cannot read some index ops back: not a delete)
            return
        if type(op).__name__ == "Delete" and getattr(op, "predicate", "false") != "false":
            with self.commit_lock or contextlib.nullcontext():
                ds.delete("false")

    def _refresh_indices(self, ds: Any, report: TableReport) -> None:
        stale = any(
            int(ds.stats.index_stats(ix.name).get("num_unindexed_rows", 0)) > 0
            for ix in ds.describe_indices()
        )
        if stale:
            ds.optimize.optimize_indices()
            report.indices_refreshed = True

    def _observe(self, when: float, version: int) -> None:
        with self._seen_lock:
            self._seen.append((when, int(version)))

    def cleanup(self, report: TableReport | None = None) -> tuple[int, int]:
        """Remove the versions superseded more than ``retain_seconds`` ago; returns
        (versions removed, bytes removed) and adds them to ``report``."""
        with self._cleanup_lock:
            ds = self._dataset()
            now = time.time()
            if not self._history_read:  # first run: read the history once (a version's
                # successor's timestamp is when it was superseded)
                history = ds.versions()
                with self._seen_lock:
                    for v in history:
                        self._seen.appendleft((v["timestamp"].timestamp(), int(v["version"])))
                    self._seen = deque(sorted(self._seen))
                self._removed_below = min((int(v["version"]) for v in history), default=0)
                self._history_read = True
            self._observe(now, ds.version)
            cut = 0
            with self._seen_lock:
                while self._seen and self._seen[0][0] <= now - self.cfg.retain_seconds:
                    cut = max(cut, self._seen.popleft()[1])
            out = 0, 0
            if cut > self._removed_below + 1:
                doomed = list(range(max(self._removed_below, 1), cut))
                stats = ds.cleanup_old_versions(versions=doomed, error_if_tagged_old_versions=False)
                self._removed_below = cut
                out = int(stats.old_versions), int(stats.bytes_removed)
            if time.monotonic() - self._swept_at >= orphans.SWEEP_INTERVAL_S:
                sweep = orphans.remove_orphans(
                    self.uri, self.storage_options, self.cfg.orphan_grace_seconds
                )
                self._swept_at = time.monotonic()
                out = out[0], out[1] + sweep.bytes_removed
                if report is not None:
                    report.orphans_removed += sweep.removed
            self.versions_removed_total += out[0]
            self.bytes_removed_total += out[1]
            if report is not None:
                report.versions_removed += out[0]
                report.bytes_removed += out[1]
            return out


class Maintainer:
    """Maintains every table of a store (items, senses, meta)."""

    def __init__(
        self,
        tables: dict[str, str],
        storage_options: dict[str, str],
        cfg: MaintenanceConfig,
        commit_lock: threading.Lock | None = None,
    ):
        self.cfg = cfg
        self.tables = {
            name: TableMaintainer(uri, storage_options, cfg, commit_lock)
            for name, uri in tables.items()
        }

    def run(self, *, cleanup: bool = True) -> list[TableReport]:
        return [t.run(cleanup=cleanup) for t in self.tables.values()]

    def cleanup(self, reports: list[TableReport] | None = None) -> None:
        by_name = {r.table: r for r in reports or []}
        for t in self.tables.values():
            t.cleanup(by_name.get(t.name))
