"""Probes chosen per index: building the ANN index measures its recall@10 at a ladder of
probes (against exact answers) and records the fewest that reach the target; searches then
probe that many (an index recorded before, without a measurement, keeps the configured
default). Real LanceDB files, clustered vectors."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from tactus_memory.adapters.vectors import VectorSense
from tactus_memory.memory.main import Memory
from tactus_memory.storage.tables import UNMEASURED_NPROBES, IndexConfig
from tactus_memory.vectors import as_unit_rows

DIM = 384
CFG = IndexConfig(threshold=6_000, scalar_threshold=3_000, rows_per_partition=128)


def clustered(n: int, rng: np.random.Generator) -> np.ndarray:
    """(n, DIM) unit rows around 30 random centres."""
    centres = as_unit_rows(rng.standard_normal((30, DIM)))
    rows = centres[rng.integers(0, 30, n)] + 0.08 * rng.standard_normal((n, DIM))
    return as_unit_rows(rows)


def test_the_index_records_the_probes_that_reach_the_target_recall(tmp_path: Path) -> None:
    rng = np.random.default_rng(3)
    mem = Memory.open(str(tmp_path / "m"), space="minilm-l6", index=CFG, background=False)
    mem.add_sense(VectorSense("touch", dim=DIM))
    data = clustered(6_400, rng)
    for i in range(0, len(data), 1_600):
        mem.add_many("s", "touch", list(data[i : i + 1_600]))
    store = mem.store
    store.build_indexes()
    info = json.loads(store.get_meta("index"))
    parts = info["partitions"]
    ladder = {int(p): r for p, r in info["ladder"].items()}
    assert parts == 6_400 // 128
    assert list(ladder) == sorted(ladder) and max(ladder) == info["nprobes"]
    assert info["recall"] == ladder[info["nprobes"]] >= CFG.target_recall
    assert all(r < CFG.target_recall for p, r in ladder.items() if p < info["nprobes"])
    assert info["nprobes"] < parts  # clustered rows: fewer than all partitions suffice
    assert store.probes() == info["nprobes"]
    reopened = Memory.open(str(tmp_path / "m"), space="minilm-l6", index=CFG, background=False)
    assert reopened.store.probes() == info["nprobes"]  # from the store's record

    # held-out queries, searched as a user does: recall@10 against an exact scan
    rows = data[rng.choice(len(data), 20, replace=False)]
    queries = as_unit_rows(rows + 1.5 * as_unit_rows(rng.standard_normal(rows.shape)))
    found = 0
    for q in queries:
        hits = mem.search_vector(q, k=10)
        kth = 1.0 - float(np.sort(as_unit_rows(data) @ q)[-10]) + 1e-6  # exact, in numpy
        found += sum(1 - h.cosine <= kth for h in hits)
    assert found / (10 * len(queries)) >= 0.9


def test_an_unmeasured_index_probes_the_old_default_and_a_pinned_one_wins(tmp_path: Path) -> None:
    mem = Memory.open(str(tmp_path / "m"), space="minilm-l6", index=CFG, background=False)
    mem.store.set_meta("index", json.dumps({"rows": 10, "type": "IVF_SQ", "partitions": 4}))
    assert mem.store.probes() == UNMEASURED_NPROBES
    pinned = IndexConfig(nprobes=7)
    other = Memory.open(str(tmp_path / "m"), space="minilm-l6", index=pinned, background=False)
    assert other.store.probes() == 7  # a number in the config wins over any record
