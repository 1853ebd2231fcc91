"""Sense codes (tactus_memory.storage.codes): each stored vector carries its sense's code after
the embedding, so the ANN index gives each sense partitions of its own; nothing reads or
ranks differently. Real LanceDB files."""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from tactus_memory.adapters.vectors import VectorSense
from tactus_memory.memory.main import Memory
from tactus_memory.storage.codes import (
    CODE_DIMS,
    code,
    coded_query,
    embedding_distance,
    with_code,
)
from tactus_memory.storage.store import ITEMS
from tactus_memory.storage.tables import IndexConfig, items_schema
from tactus_memory.vectors import as_unit_rows

DIM = 384
#: 128 rows per partition: a 46-partition IVF index of 6,000 rows, built by the tests
#: themselves (build_indexes), never by the writes
CFG = IndexConfig(threshold=10**9, scalar_threshold=10**9, rows_per_partition=128)


def test_a_code_is_a_fixed_unit_sign_vector_per_name() -> None:
    a, b = code("glove"), code("notes")
    assert a.shape == (CODE_DIMS,) and np.isclose(np.linalg.norm(a), 1.0)
    assert set(np.unique(np.abs(a) * np.sqrt(CODE_DIMS)).round(6)) == {1.0}
    assert np.array_equal(a, code("glove"))  # from the name alone: every process agrees
    assert abs(float(a @ b)) < 1.0  # two senses' codes differ


@pytest.mark.parametrize("sense", ["glove", None])
def test_the_embeddings_cosine_comes_back_exactly_from_a_coded_distance(
    sense: str | None,
) -> None:
    rng = np.random.default_rng(0)
    v = as_unit_rows(rng.standard_normal((50, DIM))) * rng.uniform(0.5, 3.0, (50, 1)).astype(
        np.float32
    )
    q = as_unit_rows(rng.standard_normal(DIM))[0]
    stored = with_code(v, "glove", CODE_DIMS)  # (50, DIM + CODE_DIMS)
    asked = coded_query(q, sense, CODE_DIMS)
    assert stored.shape == (50, DIM + CODE_DIMS) and asked.shape == (DIM + CODE_DIMS,)
    assert np.array_equal(stored[:, :DIM], v)  # the embedding is kept as given
    cos_coded = stored @ asked / (np.linalg.norm(stored, axis=1) * np.linalg.norm(asked))
    cos = (v / np.linalg.norm(v, axis=1, keepdims=True)) @ q
    got = embedding_distance(1.0 - cos_coded, coded=sense is not None)
    assert np.allclose(got, 1.0 - cos, atol=1e-6)


def _store_rows(n: int, rng: np.random.Generator) -> dict[str, np.ndarray]:
    """Two senses: 'notes' around the queries' centres, 'touch' around centres far from them
    (as a text question is near the notes and far from every touch window)."""
    near_c = as_unit_rows(rng.standard_normal((12, DIM)))
    far_c = as_unit_rows(rng.standard_normal((24, DIM)))
    notes = as_unit_rows(
        near_c[rng.integers(0, 12, n // 4)] + 0.06 * rng.standard_normal((n // 4, DIM))
    )
    touch = as_unit_rows(
        far_c[rng.integers(0, 24, n - n // 4)] + 0.06 * rng.standard_normal((n - n // 4, DIM))
    )
    # a question: near a note centre, a little towards a touch centre
    bank = as_unit_rows(near_c[rng.integers(0, 12, 24)] + 0.3 * far_c[rng.integers(0, 24, 24)])
    return {"notes": notes, "touch": touch, "bank": bank}


def _memory(path: Path, data: dict[str, np.ndarray], *, codes: bool) -> tuple[Memory, list]:
    """A memory of ``data`` and its ids (notes, then touch); ``codes=False``: its items
    table made as before sense codes."""
    mem = Memory.open(str(path), space="minilm-l6", index=CFG, background=False)
    if not codes:  # a store made before: the items table without codes, made first
        mem.store.db.drop_table(ITEMS)
        mem.store._items = mem.store.db.create_table(ITEMS, schema=items_schema(DIM))
        mem.store._schema = None
    ids = []
    for name in ("notes", "touch"):
        mem.add_sense(VectorSense(name, dim=DIM))
        ids += mem.add_many("s", name, list(data[name]))
    mem.store.set_meta("probes:test:24", json.dumps(data["bank"].tolist()))
    return mem, ids


@pytest.fixture(scope="module")
def stores(tmp_path_factory: pytest.TempPathFactory) -> Iterator[dict]:
    data = _store_rows(6_000, np.random.default_rng(7))
    root = tmp_path_factory.mktemp("codes")
    coded, ids = _memory(root / "coded", data, codes=True)
    plain, _ = _memory(root / "plain", data, codes=False)
    yield {"data": data, "coded": coded, "plain": plain, "ids": np.array(ids)}
    coded.close()
    plain.close()


def test_a_new_store_keeps_codes_and_reads_back_the_embeddings(stores: dict) -> None:
    mem, data = stores["coded"], stores["data"]
    assert mem.store.codes() == CODE_DIMS and mem.store.dim() == DIM
    assert mem.store.schema.field("vector").type.list_size == DIM + CODE_DIMS
    assert stores["plain"].store.codes() == 0 and stores["plain"].store.dim() == DIM
    first = mem.store.scan("sense = 'notes'", ["id", "vector"], limit=3)
    assert first.schema.field("vector").type.list_size == DIM
    item = mem.get_item(str(stores["ids"][0]), vector=True)
    assert np.allclose(item.vector, data["notes"][0], atol=1e-6)


@pytest.mark.parametrize("indexed", [False, True])
def test_coded_and_plain_stores_give_the_same_hits_and_cosines(stores: dict, indexed: bool) -> None:
    """Each hit's distance is 1 - its exact cosine; exact scans give the exact top 10 in
    both layouts, the ANN index nearly all of it."""
    coded, plain, data = stores["coded"], stores["plain"], stores["data"]
    if indexed and not coded.store.has_vector_index():
        coded.store.build_indexes()
        plain.store.build_indexes()
    every = np.concatenate([data["notes"], data["touch"]])  # (N, DIM), in ids' order
    sense = np.array(["notes"] * len(data["notes"]) + ["touch"] * len(data["touch"]))
    cos_of = dict(zip(stores["ids"], every, strict=True))
    found = asked = 0
    for q in data["bank"][:8]:
        for senses in (["touch"], ["notes"], None):
            mask = np.ones(len(every), bool) if senses is None else sense == senses[0]
            top = set(stores["ids"][mask][np.argsort(-(every[mask] @ q))[:10]])
            a = coded.store.vector_search(q, 10, None, senses=senses, columns=["id", "sense"])
            ids, cos = a.column("id").to_pylist(), 1.0 - np.asarray(a["_distance"])
            assert set(a.column("sense").to_pylist()) <= set(senses or ["touch", "notes"])
            assert np.allclose(cos, [cos_of[i] @ q for i in ids], atol=1e-5)
            found, asked = found + len(top & set(ids)), asked + 10
            if not indexed:  # exact: the top 10 in both layouts (the plain one's own ids)
                b = plain.store.vector_search(q, 10, None, senses=senses, columns=["id"])
                assert set(ids) == top
                assert np.allclose(1.0 - np.asarray(b["_distance"]), sorted(cos)[::-1], atol=1e-5)
    assert found / asked >= (0.9 if indexed else 1.0)


def test_codes_give_each_sense_its_own_partitions(stores: dict) -> None:
    """A question lies by the notes; asked with the touch code, the index's partition
    nearest to it holds touch rows only, so a touch search probes touch partitions first.
    Without codes the partition nearest to it holds notes."""
    for name in ("coded", "plain"):
        if not stores[name].store.has_vector_index():
            stores[name].store.build_indexes()
    assert json.loads(stores["coded"].store.get_meta("index"))["recall"] >= CFG.target_recall

    def nearest_partition(mem: Memory, q: np.ndarray) -> list[str]:
        """The senses of every row in the one partition probed (k: more than it holds)."""
        knn = {"column": "vector", "q": q, "k": 6_000, "nprobes": 1, "metric": "cosine"}
        rows = mem.store._dataset().to_table(columns=["sense", "_distance"], nearest=knn)
        return rows.column("sense").to_pylist()

    for q in stores["data"]["bank"][:8]:
        touch = nearest_partition(stores["coded"], coded_query(q, "touch", CODE_DIMS))
        notes = nearest_partition(stores["coded"], coded_query(q, "notes", CODE_DIMS))
        plain = nearest_partition(stores["plain"], q)
        assert 0 < len(touch) < 1_000 and set(touch) == {"touch"}
        assert set(notes) == {"notes"}
        # without codes the partition nearest to it holds notes (k-means may give it some
        # touch rows too: 1 build in 12 did)
        assert "notes" in plain


def test_a_sense_of_a_few_rows_is_found_with_its_code_and_nothing_else(
    stores: dict, tmp_path: Path
) -> None:
    """A sense of 3 rows shares partitions with another; asked with its code and its
    condition, only its own rows come back, the nearest first."""
    data = stores["data"]
    mem = Memory.open(str(tmp_path / "m"), space="minilm-l6", index=CFG, background=False)
    for name in ("touch", "rare"):
        mem.add_sense(VectorSense(name, dim=DIM))
    mem.add_many("s", "touch", list(data["touch"][:3_000]))
    rare = mem.add_many("s", "rare", list(data["touch"][3_000:3_003]))
    mem.store.build_indexes()
    q = data["touch"][3_000]
    rows = mem.store.vector_search(q, 10, None, senses=["rare"], columns=["id", "sense"])
    got = rows.column("id").to_pylist()
    assert got[0] == rare[0] and set(got) <= set(rare)  # its own row first, nothing else
    assert np.isclose(1.0 - rows["_distance"][0].as_py(), 1.0, atol=1e-5)
    mem.close()
