"""The real thing: ``tactus serve`` in a subprocess (uvicorn on 127.0.0.1, a random free port,
the real MiniLM space, a real LanceDB store in tmp_path), spoken to over real HTTP (httpx) and
a real WebSocket; then SIGKILLed after acknowledged writes and restarted: nothing is lost."""

from __future__ import annotations

import json
import signal
import threading

import httpx
import pytest

from tests.helpers.servers import Server
from tests.helpers.service import window

pytestmark = pytest.mark.slow


@pytest.fixture
def data_dir(tmp_path):
    return tmp_path / "memory"


def test_real_server_search_stream_crash_and_restart(data_dir, tmp_path):
    log = tmp_path / "server.log"
    server = Server(data_dir, log, "--token", "t0k")
    auth = {"Authorization": "Bearer t0k"}
    try:
        with httpx.Client(base_url=server.base, headers=auth, timeout=60) as c:
            health = httpx.get(server.base + "/health").json()
            assert health["space"]["name"] == "minilm-l6" and health["space"]["dim"] == 384
            started = log.read_text()  # `tactus serve` said what it loaded and where to look
            assert "[2/3] loading the text model (minilm-l6): done in" in started
            assert f"memory browser: {server.base}/" in started
            assert httpx.get(server.base + "/sessions").status_code == 401

            notes = ["the mug was hot", "a soft sponge", "a cold metal spoon", "a rough brick"]
            acked = []
            for i, note in enumerate(notes):
                r = c.post("/sessions/kitchen/text", json={"text": note, "t": float(i)})
                assert r.status_code == 201, r.text
                acked += r.json()["ids"]
            hits = c.get("/search", params={"q": "something squishy", "k": 2}).json()["hits"]
            assert hits[0]["text"] == "a soft sponge"

            r = c.get("/search", params={"q": "x", "k": 0})
            assert r.status_code == 422
            assert r.headers["content-type"].startswith("application/problem+json")

            # the shipped touch encoder must load in the real server (a 503 here is a bug)
            assert health["touch"] is True, health.get("touch_unavailable")
            r = c.post("/sessions/glove/touch", json={"frames": window().tolist(), "t": 1.0})
            assert r.status_code == 201, r.text
            touch_rows = 1 + _stream(server.port, "glove", n_frames=16)
            assert touch_rows == 1 + 16 // 4

        # Many writers at once, then SIGKILL while they are still writing.
        crash_acked = _write_until_killed(server, auth, threads=6, acks_before_kill=60)
    finally:
        server.kill()  # SIGKILL: no shutdown hooks, no flush
    assert server.proc.returncode == -signal.SIGKILL
    assert len(crash_acked) >= 60

    server = Server(data_dir, log, "--token", "t0k")
    try:
        with httpx.Client(base_url=server.base, headers=auth, timeout=60) as c:
            sessions = {s["id"]: s for s in c.get("/sessions").json()["sessions"]}
            assert sessions["kitchen"]["counts"] == {"text": len(notes)}
            assert sessions["glove"]["counts"] == {"touch": touch_rows}
            hits = c.get("/search", params={"q": "hot mug", "k": 10}).json()["hits"]
            assert {h["id"] for h in hits} >= set(acked)
            # every acknowledged write survived the SIGKILL (unacknowledged ones may too)
            assert sessions["crash"]["n"] >= len(crash_acked)
            params = {"q": "note", "session": "crash", "k": 1000}
            found = {h["id"] for h in c.get("/search", params=params).json()["hits"]}
            assert set(crash_acked) <= found
    finally:
        server.stop()


#: the longest stretch without a new acknowledgement before a writer test gives up
PROGRESS_S = 60


def _write_until_killed(
    server: Server, auth: dict[str, str], threads: int, acks_before_kill: int
) -> list[str]:
    """``threads`` clients post notes as fast as they can; SIGKILL the server once
    ``acks_before_kill`` writes are acknowledged; returns the acknowledged ids."""
    acked: list[str] = []
    errors: list[BaseException] = []  # a failed assert in a writer thread fails the test
    lock = threading.Lock()
    enough = threading.Event()

    def client(i: int) -> None:
        try:
            with httpx.Client(base_url=server.base, headers=auth, timeout=30) as c:
                for j in range(10_000):
                    try:
                        r = c.post("/sessions/crash/text", json={"text": f"note {i} {j}", "t": j})
                    except httpx.TransportError:
                        return  # the server is gone
                    assert r.status_code == 201, r.text
                    with lock:
                        acked.extend(r.json()["ids"])
                        if len(acked) >= acks_before_kill:
                            enough.set()
        except BaseException as exc:  # noqa: BLE001  (re-raised in the main thread)
            with lock:
                errors.append(exc)
            enough.set()

    pool = [threading.Thread(target=client, args=(i,)) for i in range(threads)]
    for t in pool:
        t.start()
    # wait on progress, not a budget: each stretch must add acknowledgements (a busy machine
    # is slow, a hung server adds none)
    seen = -1
    while not enough.wait(PROGRESS_S):
        with lock:
            now = len(acked)
        assert now > seen, f"no write acknowledged in {PROGRESS_S} s ({now} in all)"
        seen = now
    server.kill()
    for t in pool:
        t.join(60)
    assert not any(t.is_alive() for t in pool), "a writer thread hung"
    with lock:
        if errors:
            raise errors[0]
        return list(acked)


def _stream(port: int, session: str, n_frames: int) -> int:
    from websockets.sync.client import connect

    url = f"ws://127.0.0.1:{port}/sessions/{session}/touch/stream?window=4&stride=4&token=t0k"
    frames = window(k=n_frames)
    with connect(url, open_timeout=30) as ws:
        assert json.loads(ws.recv(timeout=30))["type"] == "ready"
        ws.send(json.dumps({"frame": [[1.0] * 3], "t": 0.0}))
        for i, f in enumerate(frames):
            ws.send(json.dumps({"frame": f.tolist(), "t": i / 30}))
        msgs = [json.loads(ws.recv(timeout=60)) for _ in range(1 + n_frames // 4)]
    assert [m["type"] for m in msgs].count("error") == 1
    stored = [m for m in msgs if m["type"] == "stored"]
    assert len(stored) == n_frames // 4
    return len(stored)
