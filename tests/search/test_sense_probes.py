"""Searches over an ANN index ask each sense on its own, at the probes that sense's own
recall needed when the index was built (a sense near the text queries: few; a sense far
from them: many), the senses at once; the merged hits are those of the shared query
(``Ranker.split_senses = False``) and of an exact scan. A time window is sized from the
``t`` index (the items that start in it) and still finds the items that began before it.
Real LanceDB files, clustered vectors."""

from __future__ import annotations

import json
from collections.abc import Iterator

import numpy as np
import pytest

from tactus_memory.adapters.vectors import VectorSense
from tactus_memory.memory.main import Memory
from tactus_memory.search.ranking import Ranker
from tactus_memory.storage.tables import IndexConfig
from tactus_memory.vectors import as_unit_rows
from tactus_memory.where import Where

DIM = 384
K = 10
#: 6,400 rows at 128 per partition: a 50-partition IVF index
CFG = IndexConfig(threshold=6_000, scalar_threshold=3_000, rows_per_partition=128)
#: (rows, centres) of the sense near the probe queries and of the one far from them
NEAR, FAR = (4_800, 16), (1_600, 8)
#: items of the far sense that began before the tested window and last into it
LONG = 3


def around(centres: np.ndarray, n: int, spread: float, rng: np.random.Generator) -> np.ndarray:
    """(n, DIM) unit rows around the (C, DIM) unit ``centres``."""
    rows = centres[rng.integers(0, len(centres), n)] + spread * rng.standard_normal((n, DIM))
    return as_unit_rows(rows)


@pytest.fixture(scope="module")
def store(tmp_path_factory: pytest.TempPathFactory) -> Iterator[dict]:
    rng = np.random.default_rng(11)
    near_c = as_unit_rows(rng.standard_normal((NEAR[1], DIM)))
    far_c = as_unit_rows(rng.standard_normal((FAR[1], DIM)))
    near = around(near_c, NEAR[0], 0.06, rng)
    far = around(far_c, FAR[0], 0.06, rng)
    # the queries the index measures its probes with (a text probe bank, as a search caches
    # it): near the first sense's centres, so its rows lie in the partitions nearest to them
    bank = around(near_c, 24, 0.05, rng)
    path = tmp_path_factory.mktemp("sense-probes") / "m"
    mem = Memory.open(str(path), space="minilm-l6", index=CFG, background=False)
    for name in ("near", "far"):
        mem.add_sense(VectorSense(name, dim=DIM))
    t_near = np.arange(NEAR[0], dtype=float)  # 0 .. 4799, one a second
    t_far = 10_000.0 + np.arange(FAR[0])  # all after the window tested below
    t_far[:LONG] = 1_000.0  # ... but these, which last from 1,000 s to 3,000 s
    t_end_far = t_far.copy()
    t_end_far[:LONG] = 3_000.0
    ids_near = mem.add_many("s", "near", list(near), t=t_near.tolist())
    ids_far = mem.add_many("s", "far", list(far), t=t_far.tolist(), t_end=t_end_far.tolist())
    mem.store.set_meta("probes:bench:24", json.dumps(bank.tolist()))
    mem.store.build_indexes()
    yield {
        "mem": mem,
        "vectors": np.concatenate([near, far]),
        "ids": np.array([*ids_near, *ids_far]),
        "sense": np.array(["near"] * NEAR[0] + ["far"] * FAR[0]),
        "t": np.concatenate([t_near, t_far]),
        "t_end": np.concatenate([t_near, t_end_far]),
        "path": path,
        "near_c": near_c,
        "far_c": far_c,
    }
    mem.close()


def reopen(data: dict, cfg: IndexConfig) -> Memory:
    """Another handle on the fixture's store, with ``cfg``."""
    mem = Memory.open(str(data["path"]), space="minilm-l6", index=cfg, background=False)
    for name in ("near", "far"):
        if name not in mem.senses:
            mem.add_sense(VectorSense(name, dim=DIM))
    return mem


def exact(data: dict, q: np.ndarray, mask: np.ndarray | None = None) -> list[str]:
    """The ids of the exact calibrated top K over the rows ``mask`` allows; q: (DIM,)."""
    mem = data["mem"]
    cal = {s: mem.calibration(s) for s in ("near", "far")}
    mu = np.array([cal[s].mu for s in data["sense"]])
    sigma = np.array([cal[s].sigma for s in data["sense"]])
    z = (data["vectors"] @ q - mu) / sigma  # (N,)
    if mask is not None:
        z = np.where(mask, z, -np.inf)
    top = np.argsort(-z)[:K]
    return [str(data["ids"][i]) for i in top if np.isfinite(z[i])]


def queries(data: dict, n: int, seed: int) -> np.ndarray:
    """(n, DIM) queries half-way between a near centre and a far one: both senses score."""
    rng = np.random.default_rng(seed)
    a = data["near_c"][rng.integers(0, NEAR[1], n)]
    b = data["far_c"][rng.integers(0, FAR[1], n)]
    return as_unit_rows(a + b + 0.3 * rng.standard_normal((n, DIM)))


def test_each_sense_probes_what_its_own_recall_needed(store: dict) -> None:
    mem = store["mem"]
    info = json.loads(mem.store.get_meta("index"))
    by_sense = info["by_sense"]
    assert set(by_sense) == {"near", "far"}
    # the bank lies by the near sense's rows: a few partitions hold them; the far sense's
    # best rows for it are anywhere, so its search probes at least as many (with sense
    # codes its rows have partitions of their own: k-means gave both 8 in 1 CI run of 4)
    assert by_sense["near"] <= by_sense["far"] <= info["partitions"]
    assert info["nprobes"] == max(by_sense.values())
    assert mem.store.probes(["near"]) == by_sense["near"]
    assert mem.store.probes(["far"]) == by_sense["far"]
    assert mem.store.probes(["near", "far"]) == by_sense["far"]
    assert mem.store.probes() == info["nprobes"]  # unfiltered: the worst part
    assert mem.store.probes(["unmeasured"]) == info["nprobes"]
    reopened = reopen(store, CFG)
    assert reopened.store.probes(["near"]) == by_sense["near"]  # from the index record
    # at its few probes the near sense still finds its exact top K for bank-like queries
    rng = np.random.default_rng(4)
    qs = around(store["near_c"], 12, 0.05, rng)
    found = sum(
        len({h.id for h in mem.search_vector(q, k=K, senses=["near"])} & set(exact(store, q)))
        for q in qs
    )
    assert found / (K * len(qs)) >= CFG.target_recall


def test_per_sense_queries_give_the_hits_of_the_shared_query(store: dict) -> None:
    mem = store["mem"]
    every = IndexConfig(**{**CFG.__dict__, "nprobes": mem.store.partitions()})
    pinned = reopen(store, every)
    both = 0
    for q in queries(store, 12, seed=5):
        Ranker.split_senses = False
        try:
            shared = [(h.id, h.score) for h in pinned.search_vector(q, k=K)]
        finally:
            Ranker.split_senses = True
        split = [(h.id, h.score) for h in pinned.search_vector(q, k=K)]
        assert [i for i, _ in split] == [i for i, _ in shared] == exact(store, q)
        # the same scores: a per-sense query asks with the sense's code, the shared one
        # without, and both recover the embeddings' cosine (float32 distances: ~2e-7)
        assert np.allclose([z for _, z in split], [z for _, z in shared], atol=1e-4)
        both += len({pinned.get_item(i).sense for i, _ in split}) == 2
    assert both >= 4  # answers mixing the two senses: the merge is tested


def test_the_default_search_keeps_recall_at_its_per_sense_probes(store: dict) -> None:
    mem = store["mem"]
    qs = queries(store, 16, seed=6)
    found = sum(len({h.id for h in mem.search_vector(q, k=K)} & set(exact(store, q))) for q in qs)
    assert found / (K * len(qs)) >= 0.9


def test_a_time_window_finds_items_that_began_before_it(store: dict) -> None:
    mem = store["mem"]
    after, before = 2_000.0, 2_100.0
    where = Where().overlaps(after, before)
    assert "t_end" in where.sql() and "t_end" not in where.count_sql()
    # the estimate counts no far item (none starts in the window) but three overlap it
    assert mem.store.count(where.copy().sense("far").count_sql()) == 0
    assert mem.store.count(where.copy().sense("far").sql()) == LONG
    mask = (store["t_end"] >= after) & (store["t"] <= before)
    long_ids = set(store["ids"][(store["sense"] == "far") & mask])
    assert len(long_ids) == LONG
    for q in [*queries(store, 6, seed=7), store["vectors"][NEAR[0]]]:
        hits = mem.search_vector(q, k=K, after=after, before=before)
        assert [h.id for h in hits] == exact(store, q, mask)
        assert all(h.t_end >= after and h.t <= before for h in hits)
    # each long item, asked for by its own vector, is the best hit in the window
    for i in range(NEAR[0], NEAR[0] + LONG):
        for senses in (None, ["far"]):
            hits = mem.search_vector(store["vectors"][i], k=K, senses=senses, after=after)
            assert hits[0].id == store["ids"][i]
