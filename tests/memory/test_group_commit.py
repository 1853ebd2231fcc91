"""Group commit (tactus_memory.memory.group_commit): many writers, one embed per sense, one LanceDB
commit.

Real LanceDB files in tmp_path; the HashingSpace and a stand-in touch sense keep these fast
(the real MiniLM + TactusEncoder + uvicorn path is tests/memory/test_group_commit_real.py)."""

from __future__ import annotations

import os
import threading
import time
from collections.abc import Sequence
from typing import Any

import numpy as np
import pytest
from fastapi.testclient import TestClient

from tactus_memory.errors import InvalidInputError, OverloadedError
from tactus_memory.memory.group_commit import GroupCommitter
from tactus_memory.service.app import create_app
from tactus_memory.settings import Settings
from tests.helpers.service import GatedTouch, StandInTouch, make_memory, window

POISON = -7.0  # a window whose first value is this makes PoisonTouch.embed fail


#: a tick no test waits out: batches in these tests are due by count (max_batch) or by
#: close(), so they do not depend on how fast a loaded machine runs the writers
LONG_TICK = 60.0


class PoisonTouch(StandInTouch):
    """Embedding fails for the whole batch when one window in it is poisoned (as a real
    encoder would on, say, a value its kernels cannot take); counts its embed calls."""

    def __init__(self, dim: int) -> None:
        super().__init__(dim)
        self.calls: list[int] = []

    def embed(self, batch: Sequence[np.ndarray]) -> np.ndarray:
        self.calls.append(len(batch))
        if any(float(w[0, 0, 0]) == POISON for w in batch):
            raise InvalidInputError("poisoned window")
        return super().embed(batch)


def versions(memory: Any) -> int:
    return len(memory.store.items.list_versions())


@pytest.fixture
def memory(tmp_path):
    return make_memory(tmp_path / "mem", touch=False)


# ----------------------------------------------------------------------------- library
def test_concurrent_writes_share_one_embed_and_one_commit(memory):
    touch = PoisonTouch(memory.space.dim)
    memory.add_sense(touch)
    before_versions = versions(memory)
    text_calls = memory.space.calls
    n = 24
    # the batch is due when all n items are queued (max_batch), not when a clock says so:
    # however slowly a loaded machine starts the threads, the 24 writes meet in one batch
    with GroupCommitter(memory, tick=LONG_TICK, max_batch=n) as gc:
        start = threading.Barrier(n)
        futures: list[Any] = [None] * n

        def writer(i: int) -> None:
            start.wait()
            if i % 2:
                futures[i] = gc.submit(f"glove-{i}", "touch", [window(seed=i)], t=[float(i)])
            else:
                futures[i] = gc.submit(f"op-{i}", "text", [f"note number {i}"], t=[float(i)])

        threads = [threading.Thread(target=writer, args=(i,)) for i in range(n)]
        for th in threads:
            th.start()
        for th in threads:
            th.join()
        ids = [f.result(timeout=30) for f in futures]
        stats = gc.stats
    assert stats.commits == 1 and stats.items == n
    assert versions(memory) - before_versions == 1  # ONE LanceDB commit for 24 writes
    assert touch.calls == [n // 2]  # one encoder call for every glove's window
    assert memory.space.calls - text_calls == 1  # one text-embedding call for the notes
    assert len(memory) == n
    for i, (one,) in enumerate(ids):
        item = memory.get_item(one)
        assert item.session == (f"glove-{i}" if i % 2 else f"op-{i}") and item.t == float(i)


def test_bad_write_fails_alone_and_neighbours_commit(memory):
    touch = PoisonTouch(memory.space.dim)
    memory.add_sense(touch)
    bad = window(seed=1)
    bad[0, 0, 0] = POISON
    with GroupCommitter(memory, tick=LONG_TICK, max_batch=6) as gc:  # due once all 6 queued
        # Invalid per item: refused at submit, before it can join a batch.
        with pytest.raises(InvalidInputError, match="t_end"):
            gc.submit("s", "touch", [window()], t=[5.0], t_end=[1.0])
        good = [gc.submit(f"s{i}", "touch", [window(seed=10 + i)], t=[float(i)]) for i in range(4)]
        poisoned = gc.submit("s-bad", "touch", [bad], t=[9.0])
        note = gc.submit("s-note", "text", ["still here"], t=[1.0])
        with pytest.raises(InvalidInputError, match="poisoned"):
            poisoned.result(timeout=30)
        stored = [f.result(timeout=30)[0] for f in [*good, note]]
        stats = gc.stats
    assert stats.batch_retries == 1 and stats.failed_writes == 1
    assert len(memory) == 5 and {memory.get_item(i).id for i in stored} == set(stored)
    assert "s-bad" not in {s.id for s in memory.sessions()}


def test_the_next_batch_is_embedded_while_the_last_one_is_stored(memory, monkeypatch):
    """Two stages: while batch A's commit is held inside the store write, batch B is taken
    and embedded already (one encoder call), then stored after A, in the order taken; both
    are acknowledged after their own commits only."""
    touch = PoisonTouch(memory.space.dim)
    memory.add_sense(touch)
    in_write, release = threading.Event(), threading.Event()
    order: list[int] = []
    real_write = memory.store.write

    def held_write(table, **kw):
        order.append(len(table))
        if len(order) == 1:
            in_write.set()
            assert release.wait(30), "test never released the first commit"
        return real_write(table, **kw)

    monkeypatch.setattr(memory.store, "write", held_write)
    gc = GroupCommitter(memory, tick=0.0)
    try:
        a = gc.submit("a", "touch", [window(seed=1)], t=[0.0])
        assert in_write.wait(30)  # A is being stored
        b = gc.submit("b", "touch", [window(seed=2), window(seed=3)], t=[1.0, 2.0])
        deadline = time.monotonic() + 30
        while len(touch.calls) < 2 and time.monotonic() < deadline:
            time.sleep(0.01)
        assert touch.calls == [1, 2]  # B embedded while A's commit is still held
        assert not a.done() and not b.done() and order == [1]
        release.set()
        assert len(a.result(timeout=30)) == 1 and len(b.result(timeout=30)) == 2
    finally:
        release.set()
        gc.close(timeout=30)
    assert order == [1, 2] and len(memory) == 3 and gc.stats.commits == 2


def test_full_queue_pushes_back(memory):
    touch = GatedTouch(memory.space.dim)
    memory.add_sense(touch)
    gc = GroupCommitter(memory, tick=0.0, max_pending=3, retry_after=2.5)
    try:
        first = gc.submit("a", "touch", [window(), window(seed=1)], t=[0.0, 1.0])
        assert touch.entered.wait(60)  # being committed: still counts against the limit
        second = gc.submit("b", "touch", [window(seed=2)], t=[2.0])
        with pytest.raises(OverloadedError, match="queue is full") as err:
            gc.submit("c", "text", ["one too many"], t=[3.0])
        assert err.value.retry_after == 2.5 and gc.stats.rejected == 1
        touch.gate.set()
        assert len(first.result(timeout=30)) == 2 and len(second.result(timeout=30)) == 1
        assert gc.submit("c", "text", ["room again"], t=[3.0]).result(timeout=30)
    finally:
        touch.gate.set()
        gc.close()
    assert len(memory) == 4


def test_upserts_and_appends_in_one_batch(memory):
    """One batch: the generated id appended, the explicit one merged on ``id`` (its own
    commit, issue 48: the append never pays the merge-insert's join)."""
    first = memory.add("s", "text", "old text", t=1.0, id="note-1")
    assert first == "note-1"
    before = versions(memory)
    with GroupCommitter(memory, tick=LONG_TICK, max_batch=2) as gc:  # due once both queued
        a = gc.submit("s", "text", ["new text"], t=[1.0], ids=["note-1"])
        b = gc.submit("s", "text", ["another"], t=[2.0])
        assert a.result(timeout=30) == ["note-1"] and len(b.result(timeout=30)) == 1
    assert versions(memory) - before == 2 and gc.stats.commits == 1
    assert memory.get_item("note-1").text == "new text" and len(memory) == 2
    assert {s.name: s.rows for s in memory.sense_info()}["text"] == 2


def test_close_commits_what_is_queued(memory):
    gc = GroupCommitter(memory, tick=5.0)
    futures = [gc.submit(f"s{i}", "text", [f"note {i}"], t=[0.0]) for i in range(5)]
    gc.close(timeout=30)
    assert all(len(f.result(timeout=0)) == 1 for f in futures)
    assert len(memory) == 5 and gc.stats.commits == 1
    with pytest.raises(RuntimeError, match="closed"):
        gc.submit("s", "text", ["late"], t=[0.0])


# ----------------------------------------------------------------------------- service
def test_http_writes_share_commits(tmp_path):
    memory = make_memory(tmp_path / "mem")
    before = versions(memory)
    n = 12
    # the longest tick the settings allow, and a batch due at n items: writes share commits
    # however slowly a loaded machine runs the threads
    app = create_app(
        Settings(commit_tick_ms=1000, commit_max_wait_ms=60_000, commit_max_batch=n), memory=memory
    )
    with TestClient(app) as c:
        results: list[Any] = [None] * n
        start = threading.Barrier(n)

        def post(i: int) -> None:
            start.wait()
            if i % 2:
                body = {"frames": window(seed=i).tolist(), "t": float(i)}
                results[i] = c.post(f"/sessions/g{i}/touch", json=body)
            else:
                results[i] = c.post(f"/sessions/n{i}/text", json={"text": f"n {i}", "t": 1.0})

        threads = [threading.Thread(target=post, args=(i,)) for i in range(n)]
        for th in threads:
            th.start()
        for th in threads:
            th.join()
        commits = app.state.tactus.committer.stats.commits
    assert [r.status_code for r in results] == [201] * n
    assert len(memory) == n
    assert versions(memory) - before == commits < n  # fewer commits than writes


def test_http_full_queue_is_503_with_retry_after(tmp_path):
    memory = make_memory(tmp_path / "mem", touch=False)
    touch = GatedTouch(memory.space.dim)
    memory.add_sense(touch)
    app = create_app(Settings(commit_tick_ms=0, commit_max_pending=1), memory=memory)
    with TestClient(app) as c:
        slow: dict[str, Any] = {}

        def post_touch() -> None:
            body = {"frames": window().tolist(), "t": 1.0}
            slow["r"] = c.post("/sessions/g/touch", json=body)

        th = threading.Thread(target=post_touch)
        th.start()
        try:
            assert touch.entered.wait(60)
            r = c.post("/sessions/n/text", json={"text": "refused", "t": 1.0})
            assert r.status_code == 503, r.text
            assert int(r.headers["retry-after"]) >= 1
            body = r.json()
            assert body["type"].endswith("overloaded") and "queue is full" in body["detail"]
        finally:
            touch.gate.set()
            th.join(30)
        assert slow["r"].status_code == 201
        assert c.post("/sessions/n/text", json={"text": "ok", "t": 1.0}).status_code == 201
    assert {s.id: s.n for s in memory.sessions()} == {"g": 1, "n": 1}


def _frames(n: int, seed: int = 0) -> list[np.ndarray]:
    return list(window(k=n, seed=seed))


def test_websocket_streams_go_through_the_group_committer(tmp_path):
    memory = make_memory(tmp_path / "mem")
    before = versions(memory)
    gloves, windows_each = 4, 3
    settings = Settings(
        commit_tick_ms=1000, commit_max_wait_ms=60_000, commit_max_batch=gloves * windows_each
    )
    app = create_app(settings, memory=memory)
    with TestClient(app) as c:
        streams = [
            c.websocket_connect(f"/sessions/glove-{g}/touch/stream?window=2&stride=2")
            for g in range(gloves)
        ]
        sockets = [s.__enter__() for s in streams]
        try:
            ready = [ws.receive_json() for ws in sockets]
            assert all(m["type"] == "ready" for m in ready)
            for i, frame in enumerate(_frames(2 * windows_each)):
                for ws in sockets:
                    ws.send_json({"frame": frame.tolist(), "t": float(i)})
            acks = [[ws.receive_json() for _ in range(windows_each)] for ws in sockets]
        finally:
            for s in streams:
                s.__exit__(None, None, None)
        stats = app.state.tactus.committer.stats
    for per_glove in acks:
        assert [a["type"] for a in per_glove] == ["stored"] * windows_each
        assert [a["seq"] for a in per_glove] == list(range(windows_each))  # in order
    total = gloves * windows_each
    assert len(memory) == total and stats.items == total
    assert versions(memory) - before == stats.commits < total
    sources = {memory.get_item(a["id"]).source for per in acks for a in per}
    assert sources == {m["stream"] for m in ready}  # one source per stream


def test_websocket_full_queue_sends_error_frame(tmp_path):
    memory = make_memory(tmp_path / "mem", touch=False)
    touch = GatedTouch(memory.space.dim)
    memory.add_sense(touch)
    app = create_app(Settings(commit_tick_ms=0, commit_max_pending=1), memory=memory)
    try:
        with (
            TestClient(app) as c,
            c.websocket_connect("/sessions/x/touch/stream?window=1&stride=1") as ws,
        ):
            assert ws.receive_json()["type"] == "ready"
            frames = _frames(2)
            ws.send_json({"frame": frames[0].tolist(), "t": 0.0})
            assert touch.entered.wait(60)
            ws.send_json({"frame": frames[1].tolist(), "t": 1.0})
            refused = ws.receive_json()
            assert refused["type"] == "error" and refused["windows"] == [1]
            assert refused["error"]["status"] == 503 and refused["retry_after"] > 0
            touch.gate.set()
            stored = ws.receive_json()
            assert stored["type"] == "stored" and stored["seq"] == 0
    finally:
        touch.gate.set()
    assert len(memory) == 1


def test_reads_do_not_wait_for_writes(tmp_path):
    """A commit stuck in the encoder holds no thread that reads need: searches, session
    listings and health answer meanwhile, on the bounded read pool."""
    import anyio.to_thread

    memory = make_memory(tmp_path / "mem", touch=False)
    memory.add("s", "text", "a soft sponge", t=0.0)
    touch = GatedTouch(memory.space.dim)
    memory.add_sense(touch)
    app = create_app(Settings(commit_tick_ms=0, read_threads=3), memory=memory)
    with TestClient(app) as c:
        tokens = c.portal.call(
            lambda: anyio.to_thread.current_default_thread_limiter().total_tokens
        )
        assert tokens == 3
        pending: dict[str, Any] = {}
        writers = [
            threading.Thread(
                target=lambda i=i: pending.__setitem__(
                    i, c.post(f"/sessions/g{i}/touch", json={"frames": window().tolist(), "t": 1})
                )
            )
            for i in range(6)
        ]
        for th in writers:
            th.start()
        try:
            assert touch.entered.wait(60)
            for _ in range(5):  # more reads than read threads: none waits on the stuck commit
                r = c.get("/search", params={"q": "soft sponge", "k": 1})
                assert r.status_code == 200 and r.json()["hits"][0]["text"] == "a soft sponge"
                assert c.get("/sessions").status_code == 200
            assert all(th.is_alive() for th in writers)  # the writes are still waiting
        finally:
            touch.gate.set()
            for th in writers:
                th.join(30)
    assert [pending[i].status_code for i in range(6)] == [201] * 6


def test_serve_sets_torch_threads_to_half_the_cores(monkeypatch):
    """``tactus serve --torch`` passes half the cores as torch threads (unless told
    otherwise); the default server, on ONNX Runtime, sets none (torch is never imported)."""
    from typer.testing import CliRunner

    import tactus_memory.cli.serve_cmd as serve_cmd
    from tactus_memory.cli import app as cli_app

    seen: list[Settings] = []
    monkeypatch.setattr(serve_cmd, "load_app", lambda settings, say: seen.append(settings))
    monkeypatch.setattr(serve_cmd, "run_server", lambda application, settings: None)
    monkeypatch.delenv("TACTUS_TORCH_THREADS", raising=False)
    assert CliRunner().invoke(cli_app, ["serve", "--workers", "1", "--torch"]).exit_code == 0
    assert seen[-1].torch_threads == max(1, (os.cpu_count() or 2) // 2)
    assert seen[-1].onnx is None
    assert CliRunner().invoke(cli_app, ["serve", "--workers", "1"]).exit_code == 0
    assert seen[-1].torch_threads is None and seen[-1].onnx  # the default: ONNX Runtime
    monkeypatch.setenv("TACTUS_TORCH_THREADS", "3")
    assert CliRunner().invoke(cli_app, ["serve", "--workers", "1", "--torch"]).exit_code == 0
    assert seen[-1].torch_threads == 3


def test_app_restart_gets_a_fresh_committer(tmp_path):
    """Shutdown drains and closes the committer; a second startup of the same app opens a
    new one (TestClient and schemathesis run the lifespan once per client)."""
    memory = make_memory(tmp_path / "mem", touch=False)
    app = create_app(Settings(), memory=memory)
    for i in range(2):
        with TestClient(app) as c:
            assert c.post("/sessions/s/text", json={"text": f"n{i}", "t": 0}).status_code == 201
        assert app.state.tactus.committer.closed
    assert len(memory) == 2


# ----------------------------------------------------------------------------- wait bound
class Clock:
    """A monotonic clock the test moves (the committer's waits are measured on it)."""

    def __init__(self) -> None:
        self.now = 0.0

    def __call__(self) -> float:
        return self.now


def test_writes_that_waited_past_the_bound_are_refused_not_acknowledged_late(memory):
    """Issue 48, defect 12: under overload acks came a median 24 s late. With a wait bound
    (``max_wait``, the server's ``commit_max_wait_ms``) a write still queued past it is
    refused with a Retry-After when the committer reaches it, a write submitted while the
    oldest queued one has waited past it is refused at once, and every write gets an
    answer. The committer is held in the encoder and the clock is the test's: no timing."""
    touch = GatedTouch(memory.space.dim)
    memory.add_sense(touch)
    clock = Clock()
    gc = GroupCommitter(memory, tick=0.0, max_wait=1.0, retry_after=2.0, clock=clock)
    try:
        held = gc.submit("g0", "touch", [window(seed=0)], t=[0.0])
        assert touch.entered.wait(30), "the first write never reached the encoder"
        queued = [gc.submit(f"g{i}", "touch", [window(seed=i)], t=[0.0]) for i in (1, 2)]
        clock.now = 0.4  # within the bound when it arrives
        within = gc.submit("g3", "text", ["in time"], t=[0.0])
        clock.now = 1.5  # the queued ones have now waited 1.5 s > 1 s
        with pytest.raises(OverloadedError, match="wait bound") as refused:
            gc.submit("g4", "text", ["at once"], t=[0.0])
        assert refused.value.retry_after == 2.0
        touch.gate.set()
        assert len(held.result(timeout=30)) == 1  # taken in time: acknowledged
        for fut in [*queued, within]:
            with pytest.raises(OverloadedError, match="waited") as late:
                fut.result(timeout=30)
            assert late.value.retry_after == 2.0
        after = gc.submit("g5", "text", ["after the backlog"], t=[0.0])
        assert len(after.result(timeout=30)) == 1
    finally:
        touch.gate.set()
        gc.close(timeout=30)
    sessions = {s.id for s in memory.sessions()}
    assert sessions == {"g0", "g5"}  # the refused were never stored
    assert gc.stats.late == 4 and gc.pending == 0


def test_the_wait_bound_must_exceed_the_tick(memory):
    with pytest.raises(ValueError, match="longer than tick"):
        GroupCommitter(memory, tick=0.5, max_wait=0.5)


def test_with_a_wait_bound_a_batch_holds_what_commits_within_it(memory):
    """A batch under a wait bound takes no more items than the committer commits within the
    bound at its measured rate (a 256-item batch embedding for seconds made acks late even
    with the queue bounded). The committer is held while 20 writes queue; the rate is set."""
    touch = GatedTouch(memory.space.dim)
    memory.add_sense(touch)
    gc = GroupCommitter(memory, tick=0.0, max_wait=1.0, clock=Clock())
    try:
        held = gc.submit("g", "touch", [window(seed=0)], t=[0.0])
        assert touch.entered.wait(30)
        gc._rate = 10.0  # items per second, as if measured: 10 items fit in the 1 s bound
        futures = [gc.submit(f"s{i}", "text", [f"note {i}"], t=[0.0]) for i in range(20)]
        touch.gate.set()
        assert len(held.result(timeout=30)) == 1
        assert all(len(f.result(timeout=30)) == 1 for f in futures)  # all in time: stored
    finally:
        touch.gate.set()
        gc.close(timeout=30)
    assert gc.stats.largest_batch <= 10 and gc.stats.commits >= 3 and gc.stats.late == 0
