"""Memory layer, fast: HashingSpace at the space seam, real LanceDB files in tmp_path."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from tactus_memory.adapters.vectors import VectorSense
from tactus_memory.errors import (
    DimensionMismatchError,
    InvalidIdError,
    InvalidInputError,
    NotFoundError,
    SenseConflictError,
    SpaceMismatchError,
    UnknownSenseError,
)
from tactus_memory.memory.main import Memory
from tactus_memory.senses.base import Sense
from tactus_memory.senses.plugins import register
from tactus_memory.spaces.base import Space
from tests.helpers.fakes import HashingSpace
from tests.helpers.motion import MOTION_DIM, motion_memory
from tests.helpers.threads import run_threads

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture
def mem(tmp_path, hashing_space) -> Memory:
    return Memory.open(str(tmp_path / "mem"), space=hashing_space)


def _fill(mem: Memory) -> None:
    mem.add_many(
        "s1",
        "text",
        ["put the mug on the shelf", "open the door", "red ball rolling"],
        t=[1.0, 2.0, 3.0],
    )
    mem.add_many("s2", "text", ["mug of coffee", "close the window"], t=[10.0, 20.0])


def test_add_returns_ids_and_search_ranks_match_first(mem: Memory) -> None:
    i = mem.add("s1", "text", "put the mug on the shelf", t=3.0, meta={"by": "operator"})
    mem.add_many("s1", "text", ["open the door", "red ball rolling", "cat asleep"], t=[1, 2, 4])
    assert isinstance(i, str) and len(mem) == 4
    hits = mem.search("mug shelf", k=2)
    assert hits[0].id == i
    assert hits[0].meta == {"by": "operator"}
    assert hits[0].text == "put the mug on the shelf"
    assert hits[0].score > hits[1].score
    assert -1.0 <= hits[0].cosine <= 1.0


def test_add_with_id_is_idempotent_upsert(mem: Memory) -> None:
    assert mem.add("s1", "text", "first version", t=1.0, id="abc") == "abc"
    assert mem.add("s1", "text", "second version", t=2.0, id="abc") == "abc"
    assert len(mem) == 1
    item = mem.get_item("abc")
    assert item.text == "second version" and item.t == 2.0
    ids = mem.add_many("s1", "text", ["x one", "y two"], t=[1, 2], ids=["abc", "def"])
    assert ids == ["abc", "def"] and len(mem) == 2


def test_add_many_validates_lengths_and_duplicates(mem: Memory) -> None:
    with pytest.raises(InvalidInputError, match="2 entries for 3"):
        mem.add_many("s1", "text", ["a", "b", "c"], t=[1, 2])
    with pytest.raises(InvalidInputError, match="duplicates"):
        mem.add_many("s1", "text", ["a", "b"], ids=["x", "x"])
    with pytest.raises(InvalidInputError, match="before t"):
        mem.add("s1", "text", "a", t=5.0, t_end=4.0)
    with pytest.raises(InvalidInputError):
        mem.add("s1", "text", "a", t=float("nan"))
    with pytest.raises(InvalidInputError, match="JSON"):
        mem.add("s1", "text", "a", meta={"x": object()})
    with pytest.raises(InvalidInputError, match="empty"):
        mem.add("s1", "text", "   ")
    assert mem.add_many("s1", "text", []) == []
    assert len(mem) == 0


@pytest.mark.parametrize("bad", ["s1' OR 1=1 --", 'x"; drop', "ünï", "a" * 10_000, ""])
def test_hostile_ids_raise_typed_errors_everywhere(mem: Memory, bad: str) -> None:
    _fill(mem)
    with pytest.raises(InvalidIdError):
        mem.add(bad, "text", "hello")
    with pytest.raises(InvalidIdError):
        mem.add("s1", "text", "hello", id=bad)
    with pytest.raises(InvalidIdError):
        mem.search("mug", session=bad)
    with pytest.raises(InvalidIdError):
        mem.search("mug", senses=[bad])
    with pytest.raises(InvalidIdError):
        mem.delete([bad])
    with pytest.raises(InvalidIdError):
        mem.delete_session(bad)
    with pytest.raises(InvalidIdError):
        mem.session(bad)
    with pytest.raises(InvalidIdError):
        mem.get_item(bad)
    assert len(mem) == 5  # nothing was deleted or added


def test_unknown_sense_and_bad_query_args(mem: Memory) -> None:
    _fill(mem)
    with pytest.raises(UnknownSenseError, match="unknown sense 'smell'"):
        mem.search("mug", senses=["smell"])
    with pytest.raises(UnknownSenseError):
        mem.add("s1", "smell", "x")
    with pytest.raises(InvalidInputError):
        mem.search("mug", k=0)
    with pytest.raises(InvalidInputError):
        mem.search("mug", k=10_001)
    with pytest.raises(InvalidInputError):
        mem.search("", k=3)
    with pytest.raises(InvalidInputError):
        mem.search("mug", after=float("inf"))
    with pytest.raises(InvalidInputError):
        mem.search("mug", after="0 OR 1=1")  # type: ignore[arg-type]


def test_misspelt_keywords_raise_type_error(mem: Memory) -> None:
    """add and timeline take their options as typed keywords: a misspelt one raises, as a
    misspelt keyword argument would, and nothing is written."""
    _fill(mem)
    n = len(mem)
    with pytest.raises(TypeError, match="unexpected keyword argument.*tt"):
        mem.add("s1", "text", "a note", tt=1.0)  # type: ignore[call-arg]
    assert len(mem) == n
    with pytest.raises(TypeError, match="unexpected keyword argument.*sense"):
        mem.timeline("s1", sense=["text"])  # type: ignore[call-arg]
    one = mem.add("s1", "text", "a note", t=1.0, t_end=2.0, meta={"by": "me"}, id="n1")
    item = mem.get_item(one)
    assert (one, item.t, item.t_end, item.meta) == ("n1", 1.0, 2.0, {"by": "me"})
    assert [i.id for i in mem.timeline("s1", senses=["text"], after=1.5, limit=1)] == ["n1"]


def test_filters_never_leak(mem: Memory) -> None:
    rng = np.random.default_rng(0)
    words = ["mug", "shelf", "door", "ball", "cup", "table"]
    mem.add_sense(VectorSense("motion", dim=mem.space.dim))
    for s in ("s1", "s2", "s3"):
        texts = [" ".join(rng.choice(words, 3)) for _ in range(20)]
        mem.add_many(s, "text", texts, t=list(range(20)), t_end=[x + 0.5 for x in range(20)])
        mem.add_many(s, "motion", list(rng.standard_normal((10, mem.space.dim))), t=list(range(10)))
    hits = mem.search("mug shelf", k=100, session="s2")
    assert len(hits) == 30 and {h.session for h in hits} == {"s2"}
    hits = mem.search("mug shelf", k=100, senses=["motion"])
    assert len(hits) == 30 and {h.sense for h in hits} == {"motion"}
    hits = mem.search("mug", k=100, session="s3", senses=["text"], after=5.2, before=8.0)
    # overlap: [t, t+0.5] meets [5.2, 8] for t = 5, 6, 7, 8
    assert sorted(h.t for h in hits) == [5.0, 6.0, 7.0, 8.0]
    assert {(h.session, h.sense) for h in hits} == {("s3", "text")}
    vec = rng.standard_normal(mem.space.dim)
    hits = mem.search_vector(vec, k=100, session="s1", senses=["motion"], before=4.0)
    assert sorted(h.t for h in hits) == [0.0, 1.0, 2.0, 3.0, 4.0]
    assert mem.search("mug", session="nobody") == []


def test_sessions_summary_and_deletes(mem: Memory) -> None:
    _fill(mem)
    sums = mem.sessions()
    assert [s.id for s in sums] == ["s1", "s2"]
    assert sums[0].counts == {"text": 3} and sums[0].t_min == 1.0 and sums[0].t_max == 3.0
    assert mem.session("s2").n == 2
    with pytest.raises(NotFoundError):
        mem.session("s9")
    first = mem.search("mug coffee", k=1, session="s2")[0].id
    assert mem.delete([first, "not-there"]) == 1
    assert all(h.id != first for h in mem.search("mug coffee", k=10))
    with pytest.raises(NotFoundError):
        mem.get_item(first)
    assert mem.delete_session("s1") == 3
    assert [s.id for s in mem.sessions()] == ["s2"]
    assert mem.search("mug", session="s1") == []
    assert len(mem) == 1


def test_reopen_keeps_data_and_space_is_checked(tmp_path) -> None:
    path = str(tmp_path / "mem")
    mem = Memory.open(path, space=HashingSpace())
    _fill(mem)
    mem.add_sense(VectorSense("motion", dim=64))
    vec = np.eye(64, dtype=np.float32)[3]
    mid = mem.add("s1", "motion", vec, t=4.0)
    del mem
    again = Memory.open(f"file://{path}", space=HashingSpace())
    assert len(again) == 6
    assert again.search("mug coffee", k=1)[0].text == "mug of coffee"
    # motion has rows but no live object: it is listed, searchable, not addable
    info = {s.name: s for s in again.sense_info()}
    assert info["motion"].live is False and info["motion"].rows == 1
    assert "motion" not in again.senses
    assert again.search_vector(vec, k=1, senses=["motion"])[0].id == mid
    with pytest.raises(UnknownSenseError, match="not loaded"):
        again.add("s1", "motion", vec)
    again.add_sense(VectorSense("motion", dim=64))
    again.add("s1", "motion", vec, t=5.0)
    with pytest.raises(SenseConflictError):
        again.add_sense(VectorSense("motion", dim=64))
    with pytest.raises(SpaceMismatchError, match="fake-hash.*other"):
        Memory.open(path, space=HashingSpace(name="other"))


def test_add_sense_conflicts(mem: Memory) -> None:
    with pytest.raises(SenseConflictError, match="already registered"):
        mem.add_sense(VectorSense("text", dim=64))
    with pytest.raises(SenseConflictError, match="dimension"):
        mem.add_sense(VectorSense("motion", dim=32))
    with pytest.raises(SenseConflictError, match="space"):
        mem.add_sense(VectorSense("imu", dim=64, space="another-space"))
    assert set(mem.senses) == {"text"}


def test_vector_sense_round_trip_and_bad_vectors(mem: Memory) -> None:
    mem.add_sense(VectorSense("motion", dim=64))
    rng = np.random.default_rng(1)
    vecs = rng.standard_normal((5, 64)).astype(np.float32)
    ids = mem.add_many("s1", "motion", list(vecs), t=[0, 1, 2, 3, 4])
    hit = mem.search_like("motion", vector=vecs[2], k=1)[0]
    assert hit.id == ids[2] and hit.cosine == pytest.approx(1.0, abs=1e-5)
    assert mem.search_like("motion", vecs[3], k=1)[0].id == ids[3]
    item = mem.get_item(ids[2], vector=True)
    assert np.allclose(item.vector, vecs[2] / np.linalg.norm(vecs[2]), atol=1e-6)
    with pytest.raises(DimensionMismatchError):
        mem.add("s1", "motion", np.ones(63))
    with pytest.raises(InvalidInputError, match="NaN"):
        mem.add("s1", "motion", np.full(64, np.nan))
    with pytest.raises(DimensionMismatchError):
        mem.search_vector(np.ones(10))
    assert len(mem) == 5


class ExplodingSense(Sense):
    """Validates fine, fails while embedding (like a model crash mid-batch)."""

    modality = "vector"

    def __init__(self, dim: int, result: str = "raise") -> None:
        self.name = "boom"
        self.dim = dim
        self.result = result

    def validate(self, item: object) -> object:
        return item

    def embed(self, batch: Sequence[object]) -> np.ndarray:
        if self.result == "raise":
            raise RuntimeError("encoder crashed")
        return np.full((len(batch), self.dim), np.nan, dtype=np.float32)


def test_failing_embed_writes_nothing(tmp_path) -> None:
    mem = Memory.open(str(tmp_path / "m"), space=HashingSpace())
    mem.add_sense(ExplodingSense(64))
    with pytest.raises(RuntimeError, match="crashed"):
        mem.add_many("s1", "boom", [1, 2, 3], t=[1, 2, 3])
    assert len(mem) == 0
    mem2 = Memory.open(str(tmp_path / "m2"), space=HashingSpace())
    mem2.add_sense(ExplodingSense(64, result="nan"))
    with pytest.raises(InvalidInputError, match="NaN"):
        mem2.add_many("s1", "boom", [1, 2, 3], t=[1, 2, 3])
    assert len(mem2) == 0


def test_concurrent_writers_lose_nothing(mem: Memory) -> None:
    def writer(k: int) -> None:
        for j in range(5):
            mem.add_many(f"s{k}", "text", [f"note {k} {j} a", f"note {k} {j} b"], t=[j, j])

    run_threads(writer, [(k,) for k in range(4)])  # a writer's exception fails the test
    assert len(mem) == 40
    assert {s.id: s.n for s in mem.sessions()} == {f"s{k}": 10 for k in range(4)}


def test_sigkill_after_add_keeps_row(tmp_path) -> None:
    path = tmp_path / "mem"
    script = (
        "import sys, time\n"
        f"sys.path.insert(0, {str(ROOT)!r})\n"
        "from tests.helpers.fakes import HashingSpace\n"
        "from tactus_memory.memory.main import Memory\n"
        f"m = Memory.open({str(path)!r}, space=HashingSpace())\n"
        "m.add('s1', 'text', 'survives the crash', t=1.0, id='keep')\n"
        "print('added', flush=True)\n"
        "sys.stdin.read()\n"  # blocks until killed: no race with a sleep running out
    )
    proc = subprocess.Popen(
        [sys.executable, "-c", script], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True
    )
    try:
        assert proc.stdout is not None
        assert proc.stdout.readline().strip() == "added"
    finally:
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait(60)
    assert proc.returncode == -signal.SIGKILL
    mem = Memory.open(str(path), space=HashingSpace())
    assert mem.get_item("keep").text == "survives the crash"


def test_calibration_overcomes_modality_gap(mem: Memory) -> None:
    """A strong match of a sense whose vectors share a common offset (low raw cosines with
    every text query) must outrank a weak match of another sense with a higher raw cosine."""
    dim = mem.space.dim
    rng = np.random.default_rng(0)
    q = mem.space.embed_texts(["mug shelf"], query=True)[0]
    offset = rng.standard_normal(dim)
    offset -= (offset @ q) * q
    offset /= np.linalg.norm(offset)
    mem.add_sense(VectorSense("motion", dim=dim))
    background = [5 * offset + 0.5 * rng.standard_normal(dim) / np.sqrt(dim) for _ in range(40)]
    strong = 5 * offset + q
    mem.add_many("s1", "motion", [*background, strong], ids=[f"m{i}" for i in range(41)])
    weak = mem.add("s1", "text", "a mug and a plate", t=0.0)
    mem.add_many("s1", "text", ["open the door", "red ball", "cat asleep", "walk to kitchen"])
    hits = mem.search("mug shelf", k=3)
    by_id = {h.id: h for h in hits}
    assert "m40" in by_id and weak in by_id
    # precondition: the raw cosine alone would rank the weak text note first
    assert by_id[weak].cosine > by_id["m40"].cosine
    # calibrated: the strong motion match wins
    assert hits[0].id == "m40"
    assert by_id["m40"].score > by_id[weak].score + 0.5


def test_calibration_persists_and_refreshes_when_rows_double(tmp_path) -> None:
    path = str(tmp_path / "m")
    mem = Memory.open(path, space=HashingSpace())
    mem.add_many("s1", "text", ["alpha beta", "gamma delta", "mug shelf"])
    mem.search("mug", k=1)
    first = mem.registry.own_calibration("text")  # the estimate (no prior blended in)
    assert first.n == 3 and first.sigma > 0
    mem.add_many("s1", "text", ["one two"])  # 4 rows: not yet doubled
    assert mem.registry.own_calibration("text") == first
    again = Memory.open(path, space=HashingSpace())
    assert again.registry.own_calibration("text") == first  # persisted, not re-estimated
    again.add_many("s1", "text", ["three four", "five six"])  # 6 rows = 2 x 3
    assert again.registry.own_calibration("text").n == 6


def test_background_index_and_compaction(tmp_path) -> None:
    """Past the threshold an ANN index and scalar indexes appear; unindexed appends are still
    found; compaction keeps the row count."""
    from tactus_memory.storage.tables import IndexConfig

    cfg = IndexConfig(threshold=300, scalar_threshold=150, rows_per_partition=100, compact_every=4)
    mem = motion_memory(tmp_path / "m", cfg, background=False)
    rng = np.random.default_rng(2)
    vecs = rng.standard_normal((400, MOTION_DIM)).astype(np.float32)
    for k in range(4):
        mem.add_many("s1", "motion", list(vecs[k * 100 : (k + 1) * 100]), t=list(range(100)))
        if k == 1:  # 200 rows: scalar indexes yes, ANN index not yet
            assert mem.store.has_scalar_indexes() and not mem.store.has_vector_index()
    assert mem.store.has_vector_index()
    cols = {tuple(ix.columns) for ix in mem.store.items.list_indices()}
    assert {("vector",), ("session",), ("sense",), ("t",), ("id",)} <= cols
    late = mem.add("s2", "motion", vecs[7] + 0.001, t=1.0)  # lands in the unindexed tail
    hits = mem.search_vector(vecs[7] + 0.001, k=2, senses=["motion"])
    assert late in {h.id for h in hits}
    assert len(mem) == 401


def test_object_storage_uri_is_accepted(tmp_path) -> None:
    from tactus_memory.storage.connect import normalise_uri

    assert normalise_uri("s3://bucket/prefix") == "s3://bucket/prefix"
    with pytest.raises(InvalidInputError):
        Memory.open("http://example.com/mem", space=HashingSpace())
    mem = Memory.open(f"file://{tmp_path}/m", space=HashingSpace())
    mem.add("s1", "text", "hello world")
    assert (tmp_path / "m").is_dir() and len(mem) == 1


def test_cli_search_and_sessions(tmp_path, monkeypatch) -> None:
    import json

    from typer.testing import CliRunner

    import tactus_memory.spaces as spaces
    from tactus_memory.cli import app

    monkeypatch.setattr(spaces, "get_space", lambda name="minilm", path=None: HashingSpace())
    mem = Memory.open(str(tmp_path / "m"), space=HashingSpace())
    _fill(mem)
    runner = CliRunner()
    res = runner.invoke(app, ["search", "mug coffee", "--data", str(tmp_path / "m"), "--json"])
    assert res.exit_code == 0, res.output
    hits = json.loads(res.output)
    assert hits[0]["text"] == "mug of coffee" and len(hits) == 5
    res = runner.invoke(
        app, ["search", "mug", "--data", str(tmp_path / "m"), "--session", "s1", "--k", "2"]
    )
    assert res.exit_code == 0 and "put the mug" in res.output and "coffee" not in res.output
    monkeypatch.setenv("TACTUS_DATA", str(tmp_path / "m"))
    res = runner.invoke(app, ["sessions", "--json"])
    assert res.exit_code == 0
    assert [s["id"] for s in json.loads(res.output)] == ["s1", "s2"]
    res = runner.invoke(app, ["search", "mug", "--session", "s1' OR 1=1 --"])
    assert res.exit_code == 2 and "invalid session id" in res.output
    res = runner.invoke(app, ["sessions", "--data", str(tmp_path / "absent")])
    assert res.exit_code == 2 and "no memory" in res.output


class CentroidSense(VectorSense):
    """A touch-like sense: text queries are compared after removing a target centroid."""

    def __init__(self, centroid: np.ndarray) -> None:
        super().__init__("touchy", dim=len(centroid))
        self.query_centroid = centroid

    def query_transform(self, queries: np.ndarray) -> np.ndarray:
        x = queries - self.query_centroid[None, :]
        return x / np.linalg.norm(x, axis=1, keepdims=True)


def test_query_centroid_survives_reopen(tmp_path) -> None:
    path = str(tmp_path / "m")
    rng = np.random.default_rng(3)
    centroid = rng.standard_normal(64).astype(np.float32) * 0.2
    mem = Memory.open(path, space=HashingSpace())
    mem.add_sense(CentroidSense(centroid))
    mem.add_many("s1", "touchy", list(rng.standard_normal((30, 64))), t=list(range(30)))
    live = mem.search("mug shelf", k=5, senses=["touchy"])
    versions = mem.store._senses.version
    again = Memory.open(path, space=HashingSpace())
    assert again.store._senses.version == versions  # reopening writes no registry rows
    stored = again.search("mug shelf", k=5, senses=["touchy"])
    assert [h.id for h in stored] == [h.id for h in live]
    assert [h.score for h in stored] == pytest.approx([h.score for h in live], abs=1e-5)
    # without the centroid the ranking would differ: the transform really is applied
    plain = again.search_vector(again.space.embed_texts(["mug shelf"])[0], k=5, senses=["touchy"])
    assert [h.id for h in plain] != [h.id for h in live]


def test_upsert_keeps_sense_counts_exact(mem: Memory) -> None:
    mem.add_many("s1", "text", ["a b", "c d"], ids=["x1", "x2"])
    mem.search("a", k=1)  # counts are cached from here on
    mem.add_many("s1", "text", ["e f", "g h"], ids=["x3", "x4"])
    assert mem.registry.counts() == {"text": 4}
    mem.add_many("s1", "text", ["a b c", "i j"], ids=["x1", "x5"])  # one replaces, one is new
    assert mem.registry.counts() == {"text": 5} == {"text": len(mem)}


def _reference(mem: Memory, q: np.ndarray, k: int, where: str | None = None) -> list[str]:
    """Brute force: cosine to every allowed row, per-sense z-score, merged top k."""
    tbl = mem.store.scan(where, ["id", "sense", "vector"])
    vecs = np.asarray(tbl.column("vector").to_pylist(), dtype=np.float32)
    senses = tbl.column("sense").to_pylist()
    cos = vecs @ (q / np.linalg.norm(q))
    z = [mem.calibration(s).score(c) for s, c in zip(senses, cos, strict=True)]
    order = np.argsort(-np.asarray(z), kind="stable")[:k]
    return [tbl.column("id")[int(i)].as_py() for i in order]


@pytest.mark.parametrize("k", [1, 5, 12])
def test_grouped_search_equals_per_sense_reference(tmp_path, k: int) -> None:
    """Senses sharing a query vector share one LanceDB query; the pruned merge must equal
    the brute-force per-sense calibrated merge (flat search, so exactness is expected).
    Sense "b" sits in a gap region with a low null mean, so it sometimes needs its own query."""
    dim = 32
    mem = Memory.open(str(tmp_path / "m"), space=HashingSpace(dim=dim))
    rng = np.random.default_rng(k)
    gap = -mem.registry.probe_vectors().mean(axis=0)
    gap /= np.linalg.norm(gap)
    for name, n, shift in (("a", 200, 0.0), ("b", 150, 4.0), ("c", 4, 0.0)):
        mem.add_sense(VectorSense(name, dim=dim))
        vecs = rng.standard_normal((n, dim)) + shift * gap
        mem.add_many(f"s{n % 3}", name, list(vecs), t=list(range(n)))
    calls: list[int] = []
    search = mem.store.vector_search

    def counting(*args, **kwargs):
        calls[-1] += 1
        return search(*args, **kwargs)

    mem.store.vector_search = counting  # type: ignore[method-assign]
    for _ in range(15):
        qv = rng.standard_normal(dim)
        calls.append(0)
        got = [h.id for h in mem.search_vector(qv, k=k)]
        assert got == _reference(mem, qv, k)
        unfiltered_calls = calls[-1]
        got = [h.id for h in mem.search_vector(qv, k=k, senses=["a", "c"], session="s2")]
        assert got == _reference(mem, qv, k, "sense IN ('a', 'c') AND session = 's2'")
        calls[-1] = unfiltered_calls
    assert 1 in calls  # the shared query sufficed (pruned or complete)...
    assert max(calls) >= 2  # ...and sometimes a sense needed its own query


def test_index_deltas_are_bounded(tmp_path) -> None:
    """Each optimize after appends adds an ANN index segment; past max_deltas the index is
    retrained into one, so streaming ingest cannot degrade search without bound."""
    from tactus_memory.storage.tables import IndexConfig

    cfg = IndexConfig(threshold=200, rows_per_partition=100, compact_every=1, max_deltas=2)
    mem = motion_memory(tmp_path / "m", cfg, background=False)
    rng = np.random.default_rng(4)
    mem.add_many("s1", "motion", list(rng.standard_normal((250, MOTION_DIM))))
    assert mem.store.vector_deltas() == 1
    seen = []
    for _ in range(4):
        mem.add_many("s1", "motion", list(rng.standard_normal((5, MOTION_DIM))))
        seen.append(mem.store.vector_deltas())
    assert max(seen) == 3 and min(seen[1:]) <= 2  # grew to 3, then was retrained
    assert all(d <= cfg.max_deltas + 1 for d in seen)
    assert len(mem) == 270


def test_upsert_cannot_move_an_id_between_senses_and_keeps_counts(mem: Memory) -> None:
    from tactus_memory.errors import IdConflictError

    mem.add_sense(VectorSense("motion", dim=64))
    mem.add("s1", "text", "a note", id="x1")
    mem.search("note", k=1)  # counts cached
    with pytest.raises(IdConflictError, match="x1"):  # same id as a motion row: refused
        mem.add("s1", "motion", np.ones(64), id="x1")
    mem.add("s1", "text", "a new note", id="x1")  # same session and sense: upsert
    assert mem.registry.counts() == {"text": 1}
    assert [s.name for s in mem.sense_info() if s.rows] == ["text"]
    assert mem.get_item("x1").text == "a new note"


@register("audio")
class AudioSense(Sense):
    """A new sense is one class and its registration: a toy "audio" sense whose clips are
    mono float arrays, embedded by the space's text model from a coarse loudness word."""

    modality = "audio"

    def __init__(self, space: Space, name: str = "audio") -> None:
        self.name, self.space, self.dim = name, space, space.dim

    def validate(self, item: Any) -> np.ndarray:
        clip = np.asarray(item, dtype=np.float32)
        if clip.ndim != 1 or clip.size == 0 or not np.isfinite(clip).all():
            raise InvalidInputError("an audio clip is a non-empty finite (N,) array")
        return clip

    def embed(self, batch: Sequence[np.ndarray]) -> np.ndarray:
        words = ["loud" if float(np.abs(c).mean()) > 0.5 else "quiet" for c in batch]
        return self.space.embed_texts(words)


def test_a_reopened_store_restores_its_senses_from_its_records(tmp_path) -> None:
    """Every registered sense leaves a record; restore_senses rebuilds it after a reopen
    (a built-in VectorSense with its config, a new AudioSense registered in this test), and
    names the one it cannot rebuild (its record names a class nobody registered)."""
    path = str(tmp_path / "mem")
    mem = Memory.open(path, space=HashingSpace(), background=False)
    mem.add_sense(VectorSense("motion", dim=64, encoder="imu-net", version="2"))
    mem.add_sense(AudioSense(mem.space))
    mem.add("s1", "audio", np.ones(8), t=1.0)
    mem.store.set_meta("sense_config:ghost", '{"kind": "nobody-registered", "config": {}}')
    mem.store.put_sense_row({**mem.store.sense_rows()[0], "name": "ghost"})
    del mem
    again = Memory.open(path, space=HashingSpace(), background=False)
    assert sorted(again.senses) == ["text"]
    failed = again.restore_senses()
    assert sorted(again.senses) == ["audio", "motion", "text"], failed
    assert list(failed) == ["ghost"] and "nobody-registered" in failed["ghost"]
    motion = again.senses["motion"]
    assert isinstance(motion, VectorSense) and motion.provenance()["encoder"] == "imu-net"
    assert isinstance(again.senses["audio"], AudioSense)
    again.add("s1", "audio", np.zeros(8), t=2.0)
    assert {s.name: s.rows for s in again.sense_info()}["audio"] == 2
    assert again.restore_senses(skip=("ghost",)) == {}
