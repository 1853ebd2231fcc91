"""Maintenance policy (issue 11): size-tiered compaction, version retention, index refresh,
on real LanceDB files. The disk/live figures over minutes are in benchmarks/disk.py."""

from __future__ import annotations

import os
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import lance
import numpy as np
import pytest

from tactus_memory.memory.main import Memory
from tactus_memory.policies import MaintenanceConfig
from tactus_memory.senses.base import Sense, array_to_bytes
from tactus_memory.settings import Settings
from tactus_memory.storage.compaction import FragmentInfo, fragment_infos, plan_compaction, tier_of
from tactus_memory.storage.disk import footprint
from tactus_memory.storage.tables import IndexConfig
from tests.helpers.fakes import HashingSpace

KiB = 1024
WINDOW = (8, 32, 32)  # a glove window: K frames x 32 x 32 int16 (~16 KB raw)


class RawSense(Sense):
    """A touch-like sense: stores the raw window (npy bytes), vector from a seeded RNG."""

    name = "touch"
    modality = "touch"

    def __init__(self, dim: int) -> None:
        self.dim = dim
        self.rng = np.random.default_rng(0)

    def validate(self, item: Any) -> np.ndarray:
        return np.asarray(item, dtype=np.int16).reshape(WINDOW)

    def embed(self, batch: Sequence[Any]) -> np.ndarray:
        v = self.rng.standard_normal((len(batch), self.dim)).astype(np.float32)
        return v / np.linalg.norm(v, axis=1, keepdims=True)

    def to_row(self, item: Any) -> dict[str, Any]:
        return {"raw": array_to_bytes(item)}


def _cfg(**kw: Any) -> MaintenanceConfig:
    base = {"maintain": True, "retain_seconds": 0.0, "fan_in": 4, "tier_base_bytes": 64 * KiB}
    return MaintenanceConfig(**(base | kw))


def _open(path: Path, cfg: MaintenanceConfig, compact_every: int = 8, **index: Any) -> Memory:
    mem = Memory.open(
        str(path),
        HashingSpace(),
        maintenance=cfg,
        index=IndexConfig(compact_every=compact_every, **index),
        background=False,  # maintenance runs inline: deterministic
    )
    mem.add_sense(RawSense(mem.space.dim))
    return mem


def _stream(mem: Memory, n: int, start: int = 0) -> None:
    for i in range(start, start + n):
        mem.add("s1", "touch", np.full(WINDOW, i % 1000, np.int16), t=float(i))


# ------------------------------------------------------------------ planner (pure)
def test_tiers_grow_geometrically_and_settled_fragments_have_none() -> None:
    cfg = MaintenanceConfig(tier_base_bytes=1000, fan_in=8, settled_bytes=1_000_000)
    assert tier_of(999, cfg) == 0
    assert tier_of(1000, cfg) == 1 and tier_of(7999, cfg) == 1
    assert tier_of(8000, cfg) == 2
    assert tier_of(1_000_000, cfg) is None


def test_plan_merges_only_full_runs_of_one_tier() -> None:
    cfg = MaintenanceConfig(tier_base_bytes=1000, fan_in=3, settled_bytes=100_000)
    frags = [
        FragmentInfo(0, 1000, 0, 200_000),  # settled: never merged
        FragmentInfo(1, 10, 0, 3000),  # tier 1
        FragmentInfo(2, 10, 0, 3000),  # tier 1: a run of 2 < fan_in, left alone
        FragmentInfo(3, 1, 0, 100),  # tier 0 run of 3: merged
        FragmentInfo(4, 1, 0, 100),
        FragmentInfo(5, 1, 0, 100),
    ]
    assert plan_compaction(frags, cfg) == [[3, 4, 5]]
    frags.append(FragmentInfo(6, 10, 0, 3000))  # a tier-1 fragment after the tail
    assert plan_compaction(frags, cfg) == [[3, 4, 5]]


def test_plan_rewrites_a_settled_fragment_only_for_its_deletions() -> None:
    sizes = {"tier_base_bytes": 1000, "fan_in": 3, "settled_bytes": 100_000}
    cfg = MaintenanceConfig(**sizes, erase_deleted=False)
    big = FragmentInfo(0, 1000, 50, 200_000)  # 5 % deleted: kept
    assert plan_compaction([big], cfg) == []
    # erase_deleted (the default): any deleted row is rewritten away (issue 25)
    assert plan_compaction([big], MaintenanceConfig(**sizes)) == [[0]]
    big = FragmentInfo(0, 1000, 300, 200_000)  # 30 % deleted: rewritten alone
    assert plan_compaction([big], cfg) == [[0]]
    gone = FragmentInfo(0, 1000, 1000, 200_000)  # all deleted: Lance drops it itself
    assert plan_compaction([gone], cfg) == []


# ------------------------------------------------------------------ real LanceDB
def test_streaming_keeps_few_fragments_and_disk_near_live(tmp_path: Path) -> None:
    mem = _open(tmp_path / "m", _cfg())
    _stream(mem, 160)
    mem.optimize()
    table = str(tmp_path / "m" / "items.lance")
    fp = footprint(table)
    assert fp.rows == 160
    assert fp.fragments <= 12, fp  # 160 one-row commits, merged by tiers
    # retain 0: nothing but the latest version's files stays (manifests aside)
    assert fp.disk_bytes <= 1.3 * fp.live_bytes, fp
    assert fp.versions <= 3, fp
    assert len(mem) == 160
    assert mem.search("anything", k=3, senses=["touch"])


def test_settled_fragments_are_never_rewritten(tmp_path: Path) -> None:
    cfg = _cfg(settled_bytes=200 * KiB)  # 200 KB: about 12 windows
    mem = _open(tmp_path / "m", cfg)
    _stream(mem, 100)
    mem.optimize()
    table = str(tmp_path / "m" / "items.lance")
    settled = {f.id for f in fragment_infos(lance.dataset(table)) if f.bytes >= cfg.settled_bytes}
    assert settled, "the stream should have produced settled fragments"
    files_before = {
        frag.metadata.id: [f.path for f in frag.metadata.files]
        for frag in lance.dataset(table).get_fragments()
        if frag.metadata.id in settled
    }
    _stream(mem, 100, start=100)
    mem.optimize()
    after = {frag.metadata.id: frag for frag in lance.dataset(table).get_fragments()}
    for fid, paths in files_before.items():
        assert fid in after, f"settled fragment {fid} was rewritten"
        assert [f.path for f in after[fid].metadata.files] == paths
    assert len(mem) == 200


def test_legacy_full_compaction_would_rewrite_the_large_fragment(tmp_path: Path) -> None:
    """The problem being fixed: LanceDB's optimize() rewrites every fragment under 1M rows."""
    mem = _open(tmp_path / "m", _cfg(maintain=False))
    _stream(mem, 40)
    mem.store.items.optimize()
    table = str(tmp_path / "m" / "items.lance")
    first = [f.path for f in lance.dataset(table).get_fragments()[0].metadata.files]
    _stream(mem, 5, start=40)
    mem.store.items.optimize()
    again = [f.path for f in lance.dataset(table).get_fragments()[0].metadata.files]
    assert first != again  # the one large fragment was rewritten for 5 new rows


def test_deleted_rows_are_dropped_from_a_settled_fragment(tmp_path: Path) -> None:
    cfg = _cfg(settled_bytes=100 * KiB)
    mem = _open(tmp_path / "m", cfg)
    _stream(mem, 60)
    mem.optimize()
    ids = mem.store.scan(None, ["id"]).column("id").to_pylist()
    mem.delete(ids[:30])
    mem.optimize()
    infos = fragment_infos(lance.dataset(str(tmp_path / "m" / "items.lance")))
    assert all(f.deleted / f.rows < cfg.deletion_threshold for f in infos), infos
    assert len(mem) == 30


def test_versions_superseded_within_retention_are_kept(tmp_path: Path) -> None:
    mem = _open(tmp_path / "m", _cfg(retain_seconds=3600), compact_every=1000)
    _stream(mem, 20)
    table = str(tmp_path / "m" / "items.lance")
    old_version = lance.dataset(table).version
    reader = lance.dataset(table, version=old_version)  # a reader in flight on that version
    _stream(mem, 20, start=20)
    mem.optimize()  # compacts: the old version's fragments are superseded now
    assert lance.dataset(table).version > old_version
    assert reader.count_rows() == 20  # its files are still there
    assert reader.to_table(columns=["raw"]).num_rows == 20
    assert footprint(table).versions > 20


def test_versions_go_once_superseded_longer_than_retention(tmp_path: Path) -> None:
    cfg = _cfg(retain_seconds=1.0)
    mem = _open(tmp_path / "m", cfg, compact_every=1000)
    _stream(mem, 30)
    table = str(tmp_path / "m" / "items.lance")
    before = footprint(table).versions  # nothing cleaned yet (no maintenance has run)
    mem.optimize()  # first run: reads the history (what it removes depends on the clock)
    time.sleep(1.5)  # a lower bound: every version before the next one is superseded >= 1.5 s
    mem.add("s1", "text", "one more note")
    mem.optimize()
    after = footprint(table)
    assert after.versions < before / 2, (before, after)
    assert len(mem) == 31
    # every row is readable from the latest version
    assert mem.store.scan(None, ["raw"]).num_rows == 31


def test_replica_without_maintenance_never_compacts(tmp_path: Path) -> None:
    mem = _open(tmp_path / "m", _cfg(maintain=False), compact_every=4)
    _stream(mem, 24)
    assert mem.store.maintain() is False
    ds = lance.dataset(str(tmp_path / "m" / "items.lance"))
    assert len(ds.get_fragments()) == 24  # one per commit, untouched


def test_index_refresh_is_incremental(tmp_path: Path) -> None:
    mem = _open(tmp_path / "m", _cfg(), compact_every=1000, threshold=200, rows_per_partition=50)
    rng = np.random.default_rng(3)
    mem.add_many("s1", "touch", [np.full(WINDOW, i, np.int16) for i in range(220)])
    mem.optimize()  # builds the ANN + scalar indexes
    assert mem.store.has_vector_index()
    table = str(tmp_path / "m" / "items.lance")
    ds = lance.dataset(table)
    built = {ix.name: ix.num_rows_indexed for ix in ds.describe_indices()}
    assert built and all(n == 220 for n in built.values())
    _stream(mem, 10, start=220)
    ds = lance.dataset(table)
    vec_ix = next(ix.name for ix in ds.describe_indices() if "vector" in ix.field_names)
    assert ds.stats.index_stats(vec_ix)["num_unindexed_rows"] == 10
    mem.optimize()
    ds = lance.dataset(table)
    for ix in ds.describe_indices():
        stats = ds.stats.index_stats(ix.name)
        assert stats["num_unindexed_rows"] == 0, (ix.name, stats)
    # merged into the existing index, not retrained (retraining waits for 4x growth)
    assert os.path.exists(table)
    assert mem.store.vector_deltas() >= 1
    assert mem.search_vector(rng.standard_normal(mem.space.dim), k=5, senses=["touch"])


def test_maintenance_config_reads_the_environment(monkeypatch: pytest.MonkeyPatch) -> None:
    """The policy's fields are settings: the environment reaches them through Settings, and
    a store opened without a policy takes the one the settings describe."""
    monkeypatch.setenv("TACTUS_MAINTAIN", "0")
    monkeypatch.setenv("TACTUS_RETAIN_SECONDS", "300")
    cfg = Settings().maintenance()
    assert isinstance(cfg, MaintenanceConfig)
    assert cfg.maintain is False and cfg.retain_seconds == 300.0
    monkeypatch.setenv("TACTUS_FAN_IN", "1")
    with pytest.raises(ValueError, match="fan_in"):
        Settings()


def test_plan_absorbs_stragglers_between_larger_fragments() -> None:
    """Appends that land between a merge's inputs and its output must not be stranded."""
    cfg = MaintenanceConfig(tier_base_bytes=1000, fan_in=3, settled_bytes=100_000)
    frags = [
        FragmentInfo(0, 10, 0, 3000),  # tier 1
        FragmentInfo(1, 1, 0, 100),  # tier-0 straggler (a run of 1 < fan_in)
        FragmentInfo(2, 10, 0, 3000),  # tier 1
        FragmentInfo(3, 1, 0, 100),
        FragmentInfo(4, 10, 0, 3000),  # the third tier-1 fragment completes the tier-1 run
    ]
    assert plan_compaction(frags, cfg) == [[0, 1, 2, 3, 4]]
    assert plan_compaction(frags[:3], cfg) == []  # two tier-1 fragments: not yet


def test_plan_caps_a_merge_at_a_share_of_the_table() -> None:
    """A merge's inputs stay on disk for retain_seconds: a merge of most of the table would
    double the disk, so it waits until it is at most max_merge_share of the table."""
    cfg = MaintenanceConfig(
        tier_base_bytes=1000, fan_in=3, settled_bytes=10**9, max_merge_share=0.5, free_merge_bytes=0
    )
    tier2 = [FragmentInfo(i, 100, 0, 10_000) for i in range(4)]  # 40 KB in tier 2
    assert plan_compaction(tier2, cfg) == []  # 3 x 10 KB = 75 % of the table: too big
    big = [FragmentInfo(10, 10_000, 0, 10**6 - 1)]  # a large fragment (tier 4) in front
    assert plan_compaction(big + tier2, cfg) == [[0, 1, 2]]  # now 3 % of the table
    tail = [FragmentInfo(20 + i, 1, 0, 100) for i in range(5)]
    assert plan_compaction(big + tail, cfg) == [[20, 21, 22, 23, 24]]  # tier 0: whole run


def test_plan_cuts_a_tail_longer_than_the_budget_into_merges_within_it() -> None:
    """A burst of writes between two passes (a fleet streaming faster than one pass merges)
    leaves a tier-0 tail larger than a merge may rewrite; it is merged in consecutive groups
    within the budget, not left to grow for ever; the end of it under fan_in waits."""
    sizes = {"tier_base_bytes": 1000, "fan_in": 3, "settled_bytes": 10**9}
    cfg = MaintenanceConfig(**sizes, max_merge_share=0.1, free_merge_bytes=500)
    tail = [FragmentInfo(i, 1, 0, 100) for i in range(22)]  # 2,200 bytes; budget 500
    groups = plan_compaction(tail, cfg)
    assert groups == [list(range(i, i + 5)) for i in range(0, 20, 5)]  # 20, 21: wait
    assert all(sum(tail[i].bytes for i in g) <= 500 for g in groups)


def test_a_burst_longer_than_a_merge_budget_is_still_compacted(tmp_path: Path) -> None:
    """160 one-row commits with no pass in between (2.6 MB of tier-0 fragments against a
    256 KiB merge budget): passes merge the tail group by group until few fragments are left
    (before, the tail was one group too large to merge and stayed 160 fragments)."""
    cfg = _cfg(free_merge_bytes=256 * KiB, max_merge_share=0.05)
    mem = _open(tmp_path / "m", cfg, compact_every=10**6)  # no pass during the burst
    _stream(mem, 160)
    table = str(tmp_path / "m" / "items.lance")
    assert footprint(table).fragments == 160
    for _ in range(4):
        mem.optimize()
    fp = footprint(table)
    assert fp.rows == 160 and len(mem) == 160
    assert fp.fragments <= 16, fp
