"""Moving a store made before sense codes to the coded layout, in place
(tactus_memory.storage.migrate, ``tactus maintain --sense-codes``): every row and column kept,
each vector given its sense's code, the same hits and cosines, the ANN index built again.
Real LanceDB files."""

from __future__ import annotations

import json
import threading
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pytest
from lance.commit import CommitConflictError
from typer.testing import CliRunner

from tactus_memory.adapters.vectors import VectorSense
from tactus_memory.cli import app
from tactus_memory.memory.main import Memory
from tactus_memory.storage.codes import CODE_DIMS, FIELD_KEY, code, codes_of
from tactus_memory.storage.migrate import RETIRED, STAGED, add_sense_codes, stage, swap
from tactus_memory.storage.store import ITEMS
from tactus_memory.storage.tables import IndexConfig, items_schema
from tactus_memory.vectors import as_unit_rows
from tests.helpers.fakes import HashingSpace
from tests.helpers.progress import assert_bar_finished

DIM = 64
ROWS = 150  # of each sense
#: indexes only when a test builds them (32 rows a partition: 9 partitions of 300 rows)
CFG = IndexConfig(threshold=10**9, scalar_threshold=10**9, rows_per_partition=32)
#: every column of the items table
COLUMNS = items_schema(DIM).names


def old_memory(path: Path, *, indexed: bool = False) -> Memory:
    """A memory whose items table was made before sense codes: ROWS touch vectors (placed)
    and ROWS notes, in two sessions."""
    mem = Memory.open(str(path), HashingSpace(dim=DIM), index=CFG, background=False)
    mem.store.db.drop_table(ITEMS)  # the items table without codes, as stores were made
    mem.store._items = mem.store.db.create_table(ITEMS, schema=items_schema(DIM))
    mem.store._schema = None
    mem.add_sense(VectorSense("touch", dim=DIM))
    rng = np.random.default_rng(3)
    vecs = as_unit_rows(rng.standard_normal((ROWS, DIM)))
    t = list(np.arange(ROWS, dtype=float))
    mem.add_many("lab-1", "touch", list(vecs), t=t, position=(1.0, 2.0, 0.5), frame="map")
    words = [f"w{i}" for i in range(40)]
    notes = [" ".join(rng.choice(words, 5)) + f" n{i}" for i in range(ROWS)]
    mem.add_many("lab-2", "text", notes, t=t, meta={"by": "test"})
    assert mem.store.codes() == 0
    if indexed:
        mem.store.build_indexes()
        assert mem.store.has_vector_index()
    return mem


def every_row(mem: Memory) -> pa.Table:
    """Every row and column as reads give it (the D embedding), by id."""
    return mem.store.scan(None, COLUMNS).sort_by("id")


def stored(mem: Memory) -> tuple[np.ndarray, np.ndarray]:
    """(senses, (N, width) vectors) as the items table holds them (codes included)."""
    tbl = mem.store.items.to_lance().to_table(columns=["sense", "vector"])
    width = tbl.schema.field("vector").type.list_size
    vecs = np.asarray(tbl.column("vector").combine_chunks().flatten()).reshape(-1, width)
    return np.asarray(tbl.column("sense").to_pylist()), vecs


def assert_coded(mem: Memory) -> None:
    """Every stored row is [v, |v| * c(its sense)]."""
    senses, vecs = stored(mem)
    assert vecs.shape[1] == DIM + CODE_DIMS
    norms = np.linalg.norm(vecs[:, :DIM], axis=1, keepdims=True)
    tails = np.stack([code(s) for s in senses]) * norms
    assert np.allclose(vecs[:, DIM:], tails, atol=1e-6)


def hits(mem: Memory, queries: np.ndarray) -> list[dict[str, float]]:
    """Each query's exact top 10 (id -> cosine) within touch, within text and over both."""
    out = []
    for q in queries:
        for senses in (["touch"], ["text"], None):
            rows = mem.store.vector_search(q, 10, None, senses=senses, columns=["id", "sense"])
            assert set(rows.column("sense").to_pylist()) <= set(senses or ["touch", "text"])
            cos = 1.0 - np.asarray(rows["_distance"])
            out.append(dict(zip(rows.column("id").to_pylist(), cos, strict=True)))
    return out


def test_an_old_store_gets_codes_and_keeps_every_row_and_value(tmp_path: Path) -> None:
    mem = old_memory(tmp_path / "m")
    before = every_row(mem)
    senses, plain = stored(mem)
    report = add_sense_codes(mem.store)
    assert report.migrated and report.rows == 2 * ROWS and report.codes == CODE_DIMS
    assert not report.index_rebuilt and report.finished is None
    assert mem.store.codes() == CODE_DIMS and mem.store.dim() == DIM
    field = mem.store.items.to_lance().schema.field("vector")
    assert codes_of(field) == CODE_DIMS and field.metadata[FIELD_KEY] == b"16"
    assert not field.nullable
    names = mem.store.items.to_lance().schema.names
    assert sorted(names) == sorted(COLUMNS)  # no staged or retired column left
    after = every_row(mem)
    assert after.equals(before)  # ids, times, places, meta, text, vectors: exactly
    assert_coded(mem)
    senses_after, coded = stored(mem)
    by_id = dict(zip(before.column("id").to_pylist(), range(before.num_rows), strict=True))
    assert sorted(senses_after) == sorted(senses)
    assert np.array_equal(np.sort(coded[:, :DIM], axis=0), np.sort(plain, axis=0))
    item = mem.get_item(before.column("id")[0].as_py(), vector=True)
    assert np.array_equal(item.vector, before.column("vector")[by_id[item.id]].values)
    mem.close()


def test_searches_find_the_same_rows_at_the_same_cosines(tmp_path: Path) -> None:
    mem = old_memory(tmp_path / "m")
    rng = np.random.default_rng(5)
    rows = every_row(mem)
    vecs = np.asarray(rows.column("vector").combine_chunks().flatten()).reshape(-1, DIM)
    queries = as_unit_rows(vecs[rng.choice(len(vecs), 6)] + 0.5 * rng.standard_normal((6, DIM)))
    before = hits(mem, queries)
    add_sense_codes(mem.store)
    after = hits(mem, queries)
    for was, now in zip(before, after, strict=True):
        assert list(now) == list(was)  # the same rows, in the same order
        assert np.allclose(list(now.values()), list(was.values()), atol=1e-5)
    mem.close()


def test_a_second_run_changes_nothing(tmp_path: Path) -> None:
    mem = old_memory(tmp_path / "m", indexed=True)
    assert add_sense_codes(mem.store).migrated
    version = mem.store.items.version
    again = add_sense_codes(mem.store)
    assert not again.migrated and again.rows == 0 and not again.index_rebuilt
    assert again.codes == CODE_DIMS and again.finished is None
    mem.store.items.checkout_latest()
    assert mem.store.items.version == version  # no commit
    mem.close()


def test_a_write_after_the_migration_gets_its_sense_code(tmp_path: Path) -> None:
    mem = old_memory(tmp_path / "m")
    add_sense_codes(mem.store)
    v = as_unit_rows(np.random.default_rng(9).standard_normal((1, DIM)))[0]
    [new] = mem.add_many("lab-3", "touch", [v])
    [note] = mem.add_many("lab-3", "text", ["a brand new note"])
    assert mem.store.count() == 2 * ROWS + 2
    assert_coded(mem)  # the new rows too
    assert np.allclose(mem.get_item(new, vector=True).vector, v, atol=1e-6)
    found = mem.store.vector_search(v, 1, None, senses=["touch"], columns=["id"])
    assert found.column("id").to_pylist() == [new]
    assert np.isclose(1.0 - found["_distance"][0].as_py(), 1.0, atol=1e-5)
    assert mem.store.scan(f"id = '{note}'", ["text"]).column("text").to_pylist() == [
        "a brand new note"
    ]
    mem.close()


def test_the_ann_index_is_built_again_on_the_coded_rows(tmp_path: Path) -> None:
    mem = old_memory(tmp_path / "m", indexed=True)
    report = add_sense_codes(mem.store)
    assert report.migrated and report.index_rebuilt and report.index_seconds > 0
    vector_indexes = [ix for ix in mem.store.items.list_indices() if "vector" in ix.columns]
    assert len(vector_indexes) == 1
    stats = mem.store.items.index_stats(vector_indexes[0].name)
    assert stats.num_indexed_rows == 2 * ROWS and stats.num_unindexed_rows == 0
    info = json.loads(mem.store.get_meta("index"))
    assert info["rows"] == 2 * ROWS and set(info["by_sense"]) == {"touch", "text"}
    # asked through the index (no filter: no flat scan), a stored row finds itself first
    row = every_row(mem).filter(pc.equal(pc.field("sense"), "touch"))
    q = np.asarray(row.column("vector")[7].values)
    found = mem.store.vector_search(q, 5, None, senses=["touch"], columns=["id", "sense"])
    assert found.column("id")[0].as_py() == row.column("id")[7].as_py()
    assert set(found.column("sense").to_pylist()) == {"touch"}
    mem.close()


@pytest.mark.parametrize("left", ["staged", "swapped"])
def test_an_interrupted_migration_is_finished_by_the_next_run(tmp_path: Path, left: str) -> None:
    """Killed after the coding commit, or after the swap: the store reads as before (old
    layout, or coded), and the next run finishes the migration, the index included."""
    mem = old_memory(tmp_path / "m", indexed=True)
    before = every_row(mem)
    ds = mem.store.items.to_lance()
    stage(ds, DIM)
    if left == "swapped":
        swap(ds)
    mem.store.reread_layout()
    names = mem.store.items.to_lance().schema.names
    assert (STAGED in names) == (left == "staged") and (RETIRED in names) == (left == "swapped")
    assert mem.store.codes() == (CODE_DIMS if left == "swapped" else 0)
    assert every_row(mem).equals(before)  # readable, the same rows, in either state
    report = add_sense_codes(mem.store)
    assert report.codes == CODE_DIMS and report.index_rebuilt and report.finished
    assert report.migrated == (left == "staged")
    assert sorted(mem.store.items.to_lance().schema.names) == sorted(COLUMNS)
    assert every_row(mem).equals(before)
    assert_coded(mem)
    assert mem.store.has_vector_index()
    mem.close()


def test_a_commit_of_another_writer_meanwhile_is_refused_and_nothing_is_lost(
    tmp_path: Path,
) -> None:
    """Another connection appends while the vectors are coded: Lance refuses the coding
    commit, the store is as it was plus that row, and a second run codes every row."""
    mem = old_memory(tmp_path / "m")
    other = Memory.open(str(tmp_path / "m"), HashingSpace(dim=DIM), index=CFG, background=False)
    written: list[str] = []

    def append_once(rows: int) -> None:  # in another thread, as another process would
        if not written:
            note = "a late note"
            writer = threading.Thread(
                target=lambda: written.append(other.add("lab-9", "text", note))
            )
            writer.start()
            writer.join()

    with pytest.raises(CommitConflictError):
        add_sense_codes(mem.store, on_batch=append_once)
    mem.store.reread_layout()
    assert len(written) == 1 and mem.store.codes() == 0
    assert STAGED not in mem.store.items.to_lance().schema.names
    assert mem.store.count() == 2 * ROWS + 1
    report = add_sense_codes(mem.store)
    assert report.migrated and report.rows == 2 * ROWS + 1
    assert_coded(mem)
    other.close()
    mem.close()


def test_the_maintain_command_migrates_a_store(tmp_path: Path) -> None:
    root = tmp_path / "m"
    mem = old_memory(root, indexed=True)
    before = every_row(mem)
    mem.close()

    def run() -> dict:
        res = CliRunner().invoke(app, ["maintain", "--sense-codes", "--data", str(root)])
        assert res.exit_code == 0, res.output
        [line] = [json.loads(x) for x in res.stdout.splitlines() if x.startswith("{")]
        runs.append(res.stderr)
        return line

    runs: list[str] = []
    first = run()
    # the rows coded, with the time left, on stderr
    assert_bar_finished(runs[0], "sense codes")
    assert first["migrated"] and first["rows"] == 2 * ROWS and first["index_rebuilt"]
    assert first["codes"] == CODE_DIMS and first["seconds"] > 0
    second = run()
    assert not second["migrated"] and second["rows"] == 0 and not second["index_rebuilt"]
    mem = Memory.open(str(root), HashingSpace(dim=DIM), index=CFG, background=False)
    assert mem.store.codes() == CODE_DIMS and mem.store.has_vector_index()
    assert every_row(mem).equals(before)
    mem.close()
