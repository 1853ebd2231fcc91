"""One Scope value along every search path; sense options flowing through the memory; the
``source`` filter on /search (TestClient and a real uvicorn)."""

from __future__ import annotations

from datetime import timedelta

import httpx
import numpy as np
import pytest
from fastapi.testclient import TestClient

from tactus_memory.adapters.touch import CalibratedWindow, TactusEncoder
from tactus_memory.errors import DynamicRangeError, InvalidInputError
from tactus_memory.memory.main import Memory
from tactus_memory.query import Scope, embed_query
from tactus_memory.service.app import create_app
from tactus_memory.settings import Settings
from tactus_memory.touch.profile import STAG_GLOVE
from tactus_memory.where import Where
from tests.helpers.fakes import HashingSpace
from tests.helpers.service import make_memory


@pytest.fixture
def mem(tmp_path) -> Memory:
    m = Memory.open(str(tmp_path / "m"), space=HashingSpace())
    m.add("a", "text", "red ball on the table", t=1.0, source="cam-1")
    m.add("a", "text", "red ball on the floor", t=2.0, source="cam-2")
    m.add("b", "text", "red ball in the box", t=10.0)
    return m


def test_scope_of_applies_keywords_and_rejects_misspelt_ones() -> None:
    base = Scope(session="a", senses=["text"])
    assert Scope.of(base, after=1.0) == Scope(session="a", senses=["text"], after=1.0)
    assert Scope.of(base, session=None) is base  # None keywords leave the scope as it is
    with pytest.raises(TypeError, match="sesion"):
        Scope.of(sesion="a")


def test_scope_where_is_the_store_filter_and_checks_order() -> None:
    scope = Scope(session="a", source="cam-1", after=1.0, before=5.0)
    expected = Where().session("a").overlaps(1.0, 5.0).source("cam-1").sql()
    assert scope.where().sql() == expected
    assert "t_end >= 0.5" in scope.where(pad=0.5).sql()
    with pytest.raises(InvalidInputError, match="later than"):
        Scope(after=5.0, before=1.0).where(pad=10.0)  # checked before padding


def test_search_takes_a_scope_or_the_same_keywords(mem) -> None:
    by_kw = mem.search("red ball", session="a", source="cam-2")
    by_scope = mem.search("red ball", scope=Scope(session="a", source="cam-2"))
    assert [h.id for h in by_kw] == [h.id for h in by_scope]
    assert [h.source for h in by_kw] == ["cam-2"]
    # keywords refine a given scope
    assert mem.search("red ball", scope=Scope(session="a"), source="cam-1")[0].source == "cam-1"
    with pytest.raises(TypeError, match="sesion"):
        mem.search("red ball", sesion="a")
    assert mem.count("red ball", scope=Scope(session="b"), threshold=0.0) == 1


def test_group_moment_embeds_the_query_once(mem) -> None:
    space = mem.space
    mem.search("warm up", session="a")  # the calibration probes are embedded once, first
    before = space.calls
    moments = mem.search("red ball", group="moment", session="a")
    assert space.calls - before == 1
    assert {m.session for m in moments} == {"a"}
    q = embed_query(space, "red ball")
    assert q.shape == (1, space.dim)


class _CountsVersions:
    """A LanceDB table that counts how often its ``version`` is asked (a round trip to
    LanceDB's event loop thread each)."""

    def __init__(self, table: object) -> None:
        self._table, self.asked = table, 0

    def __getattr__(self, name: str) -> object:
        if name == "version":
            self.asked += 1
        return getattr(self._table, name)


def test_a_search_reads_the_tables_versions_once_and_still_sees_new_rows(mem) -> None:
    """A question (a search, a temporal one) reads each table's version once (``pinned``),
    not at each step (the registry's refresh, each sense's ANN query, teaching's
    prototypes). A row added between two questions is still found by the next."""
    store = mem.store
    store._items, store._senses = _CountsVersions(store._items), _CountsVersions(store._senses)
    try:
        mem.search("red ball", group="window")
        assert (store._items.asked, store._senses.asked) == (1, 1)  # items: 3 without Store.pinned
        store._items.asked = store._senses.asked = 0
        mem.last("red ball")  # a temporal question ranks each sense in scope: one view
        assert (store._items.asked, store._senses.asked) == (1, 1)
        mem.add("c", "text", "a green cube under the chair", t=20.0)
        assert mem.search("green cube", k=1, group="window")[0].session == "c"
    finally:
        store._items, store._senses = store._items._table, store._senses._table


def test_http_search_filters_by_source(tmp_path) -> None:
    memory = make_memory(tmp_path / "svc")
    memory.add("a", "text", "red ball", t=1.0, source="cam-1")
    memory.add("a", "text", "red ball", t=2.0, source="cam-2")
    with TestClient(create_app(Settings(), memory=memory)) as c:
        hits = c.get("/search", params={"q": "red ball", "source": "cam-2"}).json()["hits"]
        assert [h["source"] for h in hits] == ["cam-2"]
        r = c.get("/search", params={"q": "red ball", "source": "bad id!"})
        assert r.status_code == 422 and "source" in r.json()["detail"]


@pytest.mark.slow
def test_real_server_search_filters_by_source(tmp_path) -> None:
    from tests.helpers.servers import Server

    data = tmp_path / "memory"
    with Memory.open(str(data)) as m:  # the real MiniLM space, a real LanceDB store
        m.add("k", "text", "the mug was hot", t=1.0, source="cam-1")
        m.add("k", "text", "the mug was hot", t=2.0, source="cam-2")
    server = Server(data, tmp_path / "server.log")
    try:
        with httpx.Client(base_url=server.base, timeout=60) as c:
            hits = c.get("/search", params={"q": "hot mug", "source": "cam-1"}).json()["hits"]
            assert [(h["source"], h["t"]) for h in hits] == [("cam-1", 1.0)]
            every = c.get("/search", params={"q": "hot mug"}).json()["hits"]
            assert {h["source"] for h in every} == {"cam-1", "cam-2"}
    finally:
        server.stop()


def test_touch_options_flow_through_the_memory_and_validate_once(tmp_path, enc, monkeypatch):
    mem = Memory.open(str(tmp_path / "t"), space=HashingSpace())
    mem.add_sense(enc)
    rng = np.random.default_rng(0)
    raw = rng.integers(505, 700, size=(8, 32, 32)).astype(np.float32)
    cal = STAG_GLOVE.calibrate(raw)
    with pytest.raises(DynamicRangeError, match="calibrated=True"):
        mem.add("s", "touch", cal, options={"calibrated": False})
    calls: list[object] = []
    real = TactusEncoder.validate

    def counting(self, item, **kw):
        calls.append(kw)
        return real(self, item, **kw)

    monkeypatch.setattr(TactusEncoder, "validate", counting)
    a = mem.add("s", "touch", cal, t=1.0, options={"calibrated": True})
    assert calls == [{"calibrated": True}]  # once: embed trusts the validated window
    b = mem.add("s", "touch", raw, t=2.0, options={"calibrated": False})
    assert len(calls) == 2
    assert np.allclose(mem.get_item(a).raw, mem.get_item(b).raw, atol=1e-2)
    item = mem.validate_item("touch", raw, {"calibrated": False, "unknown": 1})
    assert isinstance(item, CalibratedWindow)
    assert enc.validate(item) is item  # a validated window comes back as it is
    mem.add("s", "text", "a note", options={"calibrated": True})  # not a text option


def test_searches_after_another_writers_commit_go_by_recent_counts(tmp_path, monkeypatch) -> None:
    """Another process's commit (or a compaction) drops the exact row counts. A search then
    goes by the counts read within the store's read consistency interval, plus this process's
    own writes, instead of recounting every fragment at each question; the exact counts
    (``sense_info``, ``counts()``) still see the other writer's rows at once, and with a
    read consistency of 0 a search recounts as before."""
    path = str(tmp_path / "m")
    mine = Memory.open(path, space=HashingSpace(), read_consistency_interval=0)
    other = Memory.open(path, space=HashingSpace(), read_consistency_interval=0)
    mine.add("a", "text", "red ball on the table", t=1.0)
    registry = mine.registry
    recounts = []
    real = registry._count_rows
    monkeypatch.setattr(registry, "_count_rows", lambda: recounts.append(1) or real())
    assert registry.counts() == {"text": 1} and recounts == [1]
    monkeypatch.setattr(mine.store, "read_consistency", timedelta(hours=1))
    other.add("b", "text", "blue cube under the chair", t=2.0)  # the items table moved on
    mine.add("a", "text", "red ball on the floor", t=3.0)  # this process's write: counted
    assert registry.counts(exact=False) == {"text": 2} and recounts == [1]
    assert [h.session for h in mine.search("blue cube", k=1, group="window")] == ["b"]
    assert recounts == [1]  # the search itself went by the recent counts
    assert registry.counts() == {"text": 3} and recounts == [1, 1]  # exact: recounted
    other.add("b", "text", "a green cone", t=4.0)
    monkeypatch.setattr(mine.store, "read_consistency", timedelta(0))
    assert registry.counts(exact=False) == {"text": 4} and recounts == [1, 1, 1]


def test_two_stores_in_one_pinned_question_keep_their_own_versions(tmp_path) -> None:
    """Pinned versions are kept per table handle: a second store (another tenant's) asked
    inside the first one's pinned question reads its own version, not the first's."""
    a = Memory.open(str(tmp_path / "a"), space=HashingSpace())
    b = Memory.open(str(tmp_path / "b"), space=HashingSpace())
    for i in range(3):
        a.add("s", "text", f"note {i}", t=float(i))
    b.add("s", "text", "one note", t=0.0)
    va, vb = a.store.version(), b.store.version()
    assert va != vb
    with a.store.pinned():
        assert (a.store.version(), b.store.version()) == (va, vb)
