"""Faults found under attack (issue 29), each on the real path: a real uvicorn on 127.0.0.1
serving a real LanceDB store in tmp_path, spoken to over real HTTP (httpx); exceptions are
injected into the served memory and data files truncated by the test. HashingSpace and a
stand-in touch sense keep it fast (the embedding is not what is under test).

Writes are queued behind a commit held in the encoder (``GatedTouch``) until every request
of the test is waiting, so they share one commit by construction, not by timing.
"""

from __future__ import annotations

import os
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import httpx
import pytest
from typer.testing import CliRunner

from benchmarks.serving import serve_app
from tactus_memory.memory.group_commit import GroupCommitter
from tactus_memory.memory.main import Memory
from tactus_memory.policies import MaintenanceConfig
from tactus_memory.service.app import create_app
from tactus_memory.settings import Settings
from tactus_memory.storage.tables import IndexConfig
from tests.helpers.fakes import HashingSpace
from tests.helpers.service import GatedTouch, make_memory, window

TOKEN = "t0k"
AUTH = {"Authorization": f"Bearer {TOKEN}"}


def versions(memory: Any) -> int:
    return len(memory.store.items.list_versions())


def gated_memory(path: Path) -> tuple[Any, GatedTouch]:
    memory = make_memory(path, touch=False)
    touch = GatedTouch(memory.space.dim)
    memory.add_sense(touch)
    return memory, touch


def queued_together(
    app: Any, base: str, touch: GatedTouch, posts: list[tuple[str, dict[str, Any]]]
) -> tuple[httpx.Response, list[httpx.Response]]:
    """POST a touch window whose commit blocks in the encoder, then ``posts`` (path, JSON)
    at once; release the encoder once all of them wait in the queue: they are one batch.
    Returns (the touch write's answer, the posts' answers in order)."""
    out: list[Any] = [None] * (len(posts) + 1)

    def post(i: int, path: str, body: dict[str, Any]) -> None:
        out[i] = httpx.post(base + path, json=body, timeout=60)

    first = {"frames": window().tolist(), "t": 0.0}
    threads = [threading.Thread(target=post, args=(0, "/sessions/gate/touch", first))]
    threads[0].start()
    assert touch.entered.wait(120), "the gating write never reached the encoder"
    for i, (path, body) in enumerate(posts, 1):
        threads.append(threading.Thread(target=post, args=(i, path, body)))
        threads[-1].start()
    committer = app.state.tactus.committer
    deadline = time.monotonic() + 120  # a liveness bound only
    while committer.pending < 1 + len(posts):  # every post queued (no timing: a condition)
        assert time.monotonic() < deadline, f"only {committer.pending} items queued"
        time.sleep(0.01)
    touch.gate.set()
    for th in threads:
        th.join(60)
    return out[0], out[1:]


# ------------------------------------------------------------------ 1. racing ids
def _ordinary(n: int) -> list[tuple[str, dict[str, Any]]]:
    return [(f"/sessions/w{i}/text", {"text": f"ordinary note {i}", "t": 1.0}) for i in range(n)]


def record_commits(memory: Any, monkeypatch: pytest.MonkeyPatch) -> list[tuple[str, int]]:
    """Every store commit of items from now on, as (``append``/``merge``, rows)."""
    seen: list[tuple[str, int]] = []
    real = memory.store.write

    def write(data: Any, *, upsert: bool) -> None:
        seen.append(("merge" if upsert else "append", data.num_rows))
        real(data, upsert=upsert)

    monkeypatch.setattr(memory.store, "write", write)
    return seen


def test_same_id_twice_in_one_commit_is_written_once_and_the_rest_commits_once(
    tmp_path, monkeypatch
):
    memory, touch = gated_memory(tmp_path / "mem")
    app = create_app(Settings(commit_tick_ms=0), memory=memory)
    repeat = ("/sessions/att0/text", {"text": "x", "t": 1, "id": "a0-1"})
    commits = record_commits(memory, monkeypatch)
    with serve_app(app) as base:
        gate, answers = queued_together(app, base, touch, [repeat, *_ordinary(4), repeat])
        stats = app.state.tactus.committer.stats
    assert gate.status_code == 201
    assert [r.status_code for r in answers] == [201] * 6, [r.text for r in answers]
    assert answers[0].json()["ids"] == answers[-1].json()["ids"] == ["a0-1"]
    # the gate's commit, then the batch: the four ordinary notes appended, the id once merged
    assert commits == [("append", 1), ("append", 4), ("merge", 1)]
    assert stats.commits == 2 and stats.failed_writes == 0 and stats.batch_retries == 0
    assert len(memory) == 1 + 5 and memory.get_item("a0-1").text == "x"
    assert {s.id: s.n for s in memory.sessions()}["att0"] == 1


def test_racing_ids_never_make_the_other_writers_rows_a_merge_insert(tmp_path, monkeypatch):
    """Issue 48, defect 3: two pairs of clients re-sending the same ids tick after tick slowed
    every other writer to 0.33-0.46x: each such tick was ONE merge-insert of every row of
    the tick (a join over every stored id). Now the other writers' rows are one append; an
    id re-sent with the content it is stored with is acknowledged and not written again (no
    merge-insert at all), and the row counts stay exact without a recount."""
    memory, touch = gated_memory(tmp_path / "mem")
    app = create_app(Settings(commit_tick_ms=0), memory=memory)
    pairs = [
        ("/sessions/att0/text", {"text": "x", "t": 1, "id": "a0-1"}),
        ("/sessions/att1/text", {"text": "y", "t": 2, "id": "a1-1"}),
    ]
    commits = record_commits(memory, monkeypatch)
    with serve_app(app) as base:
        for _round in range(3):
            touch.gate.clear()  # each round queued behind a held commit again
            touch.entered.clear()
            racers = [pairs[0], pairs[1], pairs[0], pairs[1]]
            gate, answers = queued_together(app, base, touch, [*racers, *_ordinary(4)])
            assert [r.status_code for r in [gate, *answers]] == [201] * 9, [r.text for r in answers]
        stats = app.state.tactus.committer.stats
        listed = httpx.get(base + "/sessions", timeout=30).json()["sessions"]
    merged = [rows for kind, rows in commits if kind == "merge"]
    appended = [rows for kind, rows in commits if kind == "append"]
    assert merged == [2]  # the two ids once, the first time; never the other writers' rows
    assert sum(appended) == 3 + 3 * 4  # the gates' windows and the ordinary notes, appended
    assert stats.batch_retries == 0 and stats.failed_writes == 0
    counts = {s["id"]: s["n"] for s in listed}
    assert counts["att0"] == counts["att1"] == 1 and sum(counts.values()) == 3 + 3 * 4 + 2
    assert memory.get_item("a0-1").text == "x" and memory.get_item("a1-1").text == "y"


def test_same_id_with_other_content_fails_alone_with_409(tmp_path, monkeypatch):
    memory, touch = gated_memory(tmp_path / "mem")
    app = create_app(Settings(commit_tick_ms=0), memory=memory)
    one = ("/sessions/att0/text", {"text": "x", "t": 1, "id": "a0-1"})
    other = ("/sessions/att1/text", {"text": "y", "t": 1, "id": "a0-1"})
    commits = record_commits(memory, monkeypatch)
    with serve_app(app) as base:
        _, answers = queued_together(app, base, touch, [one, *_ordinary(4), other])
    pair = [answers[0], answers[-1]]  # which of them queued first is the threads' business
    assert sorted(r.status_code for r in pair) == [201, 409], [r.text for r in pair]
    assert [r.status_code for r in answers[1:-1]] == [201] * 4
    (lost,) = [r for r in pair if r.status_code == 409]
    assert lost.json()["type"].endswith("id-conflict")
    # no write-by-write retries: the gate, the four notes, the winner of the id
    assert commits == [("append", 1), ("append", 4), ("merge", 1)]
    stored = memory.get_item("a0-1")
    winner = "att0" if answers[0].status_code == 201 else "att1"
    assert len(memory) == 1 + 5 and stored.session == winner
    assert stored.text == {"att0": "x", "att1": "y"}[winner]


# ------------------------------------------------------------------ 2. never twice
def _boom(*_a: Any, **_k: Any) -> None:
    raise RuntimeError("injected failure after the store write")


def _lost_reply(memory: Any) -> Callable[..., None]:
    table = memory.store.items
    real_add = table.add

    def add(data: Any, *a: Any, **k: Any) -> None:
        real_add(data, *a, **k)  # the commit lands ...
        raise OSError("injected: the commit's reply was lost")  # ... and its caller hears not

    return add


STEPS: dict[str, Callable[[Any, pytest.MonkeyPatch], None]] = {
    "registry.note_commit": lambda m, mp: mp.setattr(m.registry, "note_commit", _boom),
    "registry.note_write": lambda m, mp: mp.setattr(m.registry, "note_write", _boom),
    "maintenance.schedule": lambda m, mp: mp.setattr(m._maintenance, "schedule", _boom),
    "committer.statistics": lambda m, mp: mp.setattr(GroupCommitter, "_record", _boom),
    "store.commit-reply": lambda m, mp: mp.setattr(m.store.items, "add", _lost_reply(m)),
}


@pytest.mark.parametrize("step", list(STEPS))
def test_a_failure_after_the_store_write_never_writes_the_batch_twice(tmp_path, monkeypatch, step):
    memory, touch = gated_memory(tmp_path / "mem")
    app = create_app(Settings(commit_tick_ms=0), memory=memory)
    STEPS[step](memory, monkeypatch)
    notes = [(f"/sessions/n{i}/text", {"text": f"note {i}", "t": float(i)}) for i in range(5)]
    with serve_app(app) as base:
        gate, answers = queued_together(app, base, touch, notes)
        assert [r.status_code for r in [gate, *answers]] == [201] * 6, [r.text for r in answers]
        ids = [r.json()["ids"][0] for r in [gate, *answers]]
        listed = httpx.get(base + "/sessions", timeout=30).json()["sessions"]
    rows = memory.store.scan(None, ["id", "text"]).to_pylist()
    assert len(rows) == 6 and sorted(r["id"] for r in rows) == sorted(ids)  # each once
    assert sorted(r["text"] for r in rows if r["text"]) == [f"note {i}" for i in range(5)]
    assert sum(s["n"] for s in listed) == 6  # counts repaired, not off by a batch


# ------------------------------------------------------------------ 3. session delete
def test_deleting_a_session_deletes_its_clock_offsets_even_without_items(tmp_path):
    memory = make_memory(tmp_path / "mem")
    with (
        serve_app(create_app(Settings(), memory=memory)) as base,
        httpx.Client(base_url=base, timeout=30) as c,
    ):
        r = c.put("/sessions/s2/clock", json={"sense": "touch", "offset": 2})
        assert r.status_code == 200 and len(r.json()["offsets"]) == 1
        gone = c.delete("/sessions/s2")
        assert gone.status_code == 200, gone.text
        assert gone.json() == {"id": "s2", "deleted": 0, "clock_offsets": 1}
        assert c.get("/sessions/s2/clock").status_code == 404  # no offsets, no items: gone
        assert c.delete("/sessions/s2").status_code == 404  # nothing left to delete
        # with items too: both go
        assert c.post("/sessions/s3/text", json={"text": "a note", "t": 1.0}).status_code == 201
        assert c.put("/sessions/s3/clock", json={"sense": "text", "offset": -1}).status_code == 200
        assert c.delete("/sessions/s3").json() == {"id": "s3", "deleted": 1, "clock_offsets": 1}
        assert c.get("/sessions/s3/clock").status_code == 404
    assert memory.clock_offsets() == [] and len(memory) == 0


# ------------------------------------------------------------------ 4. meta maintenance
def test_clock_writes_alone_get_the_meta_table_maintained(tmp_path):
    """No item is written: the meta table's own commits schedule its maintenance."""
    memory = Memory.open(
        str(tmp_path / "mem"),
        space=HashingSpace(dim=64),
        background=False,  # maintenance runs inline: the count below is exact
        index=IndexConfig(compact_every=16),
        maintenance=MaintenanceConfig(retain_seconds=0, cleanup_interval=0),
    )
    n = 100
    with (
        serve_app(create_app(Settings(), memory=memory)) as base,
        httpx.Client(base_url=base, timeout=30) as c,
    ):
        for i in range(n):
            r = c.put(f"/sessions/c{i}/clock", json={"sense": "touch", "offset": i + 1})
            assert r.status_code == 200, r.text
        assert c.get("/sessions/c42/clock").json()["offsets"][0]["offset"] == 43
    meta = tmp_path / "mem" / "meta.lance" / "_versions"
    kept = len([f for f in os.listdir(meta) if f.endswith(".manifest")])
    assert kept < 32, f"{kept} meta versions kept after {n} clock writes"  # before: > n
    assert len(memory.clock_offsets()) == n and len(memory) == 0


# ------------------------------------------------------------------ 5. damaged store
def _largest_items_file(root: Path) -> Path:
    files = list((root / "items.lance" / "data").iterdir())
    return max(files, key=lambda p: p.stat().st_size)


def test_a_damaged_store_is_unhealthy_refuses_writes_and_names_no_path(tmp_path):
    root = tmp_path / "mem"
    memory = make_memory(root)
    for i in range(3):  # three commits, three data files
        memory.add_many(f"g{i}", "touch", [window(seed=i), window(seed=i + 9)], t=[0.0, 1.0])
    app = create_app(Settings(), memory=memory)
    bodies: list[str] = []
    with serve_app(app) as base, httpx.Client(base_url=base, timeout=30) as c:
        assert c.get("/health").status_code == 200
        victim = _largest_items_file(root)
        intact = victim.read_bytes()
        os.truncate(victim, len(intact) // 2)
        rows, version = len(memory), versions(memory)
        for probe in ("/health", "/ready"):
            r = c.get(probe)
            bodies.append(r.text)
            assert r.status_code == 503 and "damaged" in r.json()["detail"], r.text
            assert victim.name in r.json()["detail"]  # names the file, not where it lives
        writes = [
            c.post("/sessions/s/text", json={"text": "into a damaged store", "t": 1.0}),
            c.post("/sessions/s/touch", json={"frames": window().tolist(), "t": 2.0}),
            c.put("/sessions/s/clock", json={"sense": "touch", "offset": 1}),
            c.delete("/sessions/g0"),
        ]
        for r in writes:
            bodies.append(r.text)
            assert r.status_code == 503 and r.json()["type"].endswith("store-damaged"), r.text
        assert len(memory) == rows and versions(memory) == version  # nothing written
        for path in ("/sessions", "/search?q=anything", "/sessions/g1"):  # reads: 200 or 503
            r = c.get(path)
            bodies.append(r.text)
            assert r.status_code in (200, 503), (path, r.status_code, r.text)
        assert c.get("/live").status_code == 200
        check = CliRunner().invoke(_cli(), ["maintain", "--check", "--data", str(root)])
        assert check.exit_code == 1, check.output
        assert '"table": "items", "ok": false' in check.output and victim.name in check.output
        victim.write_bytes(intact)  # repaired: healthy again, writes accepted
        assert c.get("/health").status_code == 200 and c.get("/ready").status_code == 200
        assert c.post("/sessions/s/text", json={"text": "after", "t": 3.0}).status_code == 201
    for body in bodies:
        assert str(tmp_path) not in body and "/tmp" not in body, body


def test_maintain_check_on_an_intact_store(tmp_path):
    memory = make_memory(tmp_path / "mem")
    memory.add("s", "text", "fine", t=0.0)
    check = CliRunner().invoke(_cli(), ["maintain", "--check", "--data", str(tmp_path / "mem")])
    assert check.exit_code == 0, check.output
    assert check.output.count('"ok": true') == 3  # items, senses, meta


def _cli() -> Any:
    from tactus_memory.cli import app

    return app


# ------------------------------------------------------------------ 6. HEAD and OPTIONS
def test_head_wherever_get_and_options_behind_the_routes_token(tmp_path):
    memory = make_memory(tmp_path / "mem")
    memory.add("s1", "text", "a red ball", t=1.0)
    app = create_app(Settings(token=TOKEN), memory=memory)
    with serve_app(app) as base, httpx.Client(base_url=base, timeout=30) as c:
        for path in ("/sessions", "/sessions/s1", "/senses", "/search?q=ball"):
            get, head = c.get(path, headers=AUTH), c.head(path, headers=AUTH)
            assert get.status_code == head.status_code == 200, (path, head.status_code)
            assert head.content == b"" and head.headers["content-type"] == "application/json"
            assert head.headers["content-length"] == get.headers["content-length"]
            assert c.head(path).status_code == 401  # HEAD runs the GET's token check
        assert c.head("/health").status_code == 200 and c.head("/live").status_code == 200
        assert c.head("/search/like", headers=AUTH).status_code == 405  # no GET there
        refused = c.options("/sessions")
        assert refused.status_code == 401 and "allow" not in refused.headers
        assert refused.headers["www-authenticate"].startswith("Bearer")
        ok = c.options("/sessions/s1", headers=AUTH)
        assert ok.status_code == 204
        assert ok.headers["allow"] == "DELETE, GET, HEAD, OPTIONS"
        assert c.options("/health").status_code == 204  # an open route stays open


def test_clock_offsets_of_a_store_written_before_are_read_and_moved_to_session_rows(tmp_path):
    """Stores written before issue 29 keep every offset in one meta value (CLOCK_KEY)."""
    import json

    from tactus_memory.temporal.clocks import CLOCK_KEY, CLOCK_PREFIX

    memory = make_memory(tmp_path / "mem")
    old = {"a": {"touch/": 2.0}, "b": {"text/l": -1.0, "touch/": 3.0}}
    memory.store.set_meta(CLOCK_KEY, json.dumps(old))
    assert [(o.session, o.sense, o.offset) for o in memory.clock_offsets("b")] == [
        ("b", "text", -1.0),
        ("b", "touch", 3.0),
    ]
    memory.set_clock_offset("c", "touch", 5.0)  # the first clock write moves the old table
    assert memory.store.get_meta(CLOCK_KEY) is None
    assert set(memory.store.meta_items(CLOCK_PREFIX)) == {"clock:a", "clock:b", "clock:c"}
    assert len(memory.clock_offsets()) == 4
    memory.delete_session("b")
    assert {o.session for o in memory.clock_offsets()} == {"a", "c"}
