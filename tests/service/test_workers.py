"""``tactus serve --workers 2`` on real uvicorn processes (one port, one store): gloves land on
both workers and each is acknowledged by its own committer; /ready waits for every worker;
worker 0 alone maintains; ``kill -9`` of a worker while its glove streams loses nothing it
acknowledged, and the worker is replaced. Frames go as binary ``.npy`` messages of several
frames (parsed and windowed as one array); an HTTP ``.npy`` body of several windows is stored
by the group too. "Worker 0 alone maintains" is read from the workers' banners and from what
each worker's ``/retention`` says it ran.

Issue 48 on the same server: read-your-writes across the workers (defect 2: 20 write-then-read
and 20 delete-then-read pairs, each request on a fresh connection, every answer naming its
worker in ``X-Tactus-Worker``), the startup lines printed once, and each maintenance pass
recorded and logged with its worker, none overlapping another (defect 13)."""

from __future__ import annotations

import contextlib
import io
import json
import os
import re
import signal
import time
from contextlib import ExitStack
from pathlib import Path

import httpx
import numpy as np
import pytest
from websockets.exceptions import ConnectionClosed

from benchmarks.serving import free_port, start_serve, stop_process, wait_ok
from tactus_memory.memory.main import Memory
from tests.helpers.servers import STARTUP_S

pytestmark = pytest.mark.slow

WINDOW = 8


def npy(frames: np.ndarray) -> bytes:
    buf = io.BytesIO()
    np.save(buf, frames)
    return buf.getvalue()


def frames(n: int, seed: int) -> np.ndarray:
    """(n, 32, 32) int16 raw frames with a contact patch (never idle)."""
    rng = np.random.default_rng(seed)
    out = np.full((n, 32, 32), 512, np.int16)
    out[:, 8:24, 6:20] += rng.integers(100, 300, (n, 16, 14)).astype(np.int16)
    return out


def worker_pids(log: Path) -> dict[int, int]:
    """worker index -> pid, from the banners (the latest one per index)."""
    found = re.findall(r"worker:\s+(\d+) of \d+, pid (\d+)", log.read_text())
    return {int(i): int(pid) for i, pid in found}


def connect(stack: ExitStack, port: int, session: str):  # noqa: ANN201  (a connection)
    from websockets.sync.client import connect as ws_connect

    url = f"ws://127.0.0.1:{port}/sessions/{session}/touch/stream?hz=30&window={WINDOW}"
    ws = stack.enter_context(ws_connect(url, open_timeout=30))
    ready = json.loads(ws.recv(timeout=30))
    assert ready["type"] == "ready", ready
    return ws, ready["worker"]


def stream(ws, n_messages: int, seed: int, acked: list[str], kill=None) -> None:  # noqa: ANN001
    """Send ``n_messages`` .npy messages of two windows each, collect the acks; ``kill``
    runs once the first acks came back (the connection may then close)."""
    for i in range(n_messages):
        ws.send(npy(frames(2 * WINDOW, seed * 1000 + i)))
    want = 2 * n_messages
    try:
        while len(acked) < want:
            msg = json.loads(ws.recv(timeout=60))
            assert msg["type"] == "stored", msg
            acked.append(msg["id"])
            if kill is not None and len(acked) == 3:
                kill()
    except (ConnectionClosed, TimeoutError):  # the killed worker's connection ends
        if kill is None:
            raise


def ready_status(base: str) -> int | str | None:
    """200, the 503's reason after 'starting: ', or None when the connection was reset."""
    try:
        r = httpx.get(base + "/ready", timeout=10)
    except httpx.TransportError:
        return None
    return 200 if r.status_code == 200 else r.json()["detail"].removeprefix("starting: ")


def retention_by_worker(base: str) -> dict[int, float | None]:
    """worker -> the unix time of its last retention pass (None: never ran one), from
    ``GET /retention`` on fresh connections (the kernel spreads them) until both workers
    answered and worker 0 has run a pass; every answer of worker 1 says it does not
    maintain."""
    seen: dict[int, float | None] = {}
    deadline = time.monotonic() + STARTUP_S
    while set(seen) != {0, 1} or seen[0] is None:
        assert time.monotonic() < deadline, seen
        body = httpx.get(base + "/retention", timeout=10).json()
        assert body["maintained_here"] == (body["worker"] == 0), body
        if body["worker"] == 1:
            assert body["last_run"] is None and body["expired_total"] == 0, body
        seen[body["worker"]] = body["last_run"]
        time.sleep(0.05)
    return seen


PAIRS = 20  # write-then-read and delete-then-read pairs (issue 48, defect 2)


def worker_of(r: httpx.Response) -> int:
    return int(r.headers["x-tactus-worker"])


def read_your_writes(base: str) -> None:
    """Each pair on fresh connections (the kernel spreads them over the workers): a note
    acknowledged 201 is in the next ``GET /sessions``, a deleted session's clock is 404 at
    once, whichever worker answers; some pairs must have crossed workers."""
    crossed = {"write": 0, "delete": 0}
    for i in range(PAIRS):
        w = httpx.post(f"{base}/sessions/n{i}/text", json={"text": f"n {i}", "t": 1.0}, timeout=60)
        assert w.status_code == 201, w.text
        r = httpx.get(f"{base}/sessions", timeout=60)
        listed = {s["id"] for s in r.json()["sessions"]}
        assert f"n{i}" in listed, (i, worker_of(w), worker_of(r))  # its own write, seen
        crossed["write"] += worker_of(w) != worker_of(r)

        put = httpx.put(
            f"{base}/sessions/c{i}/clock", json={"sense": "text", "offset": 2.0}, timeout=60
        )
        assert put.status_code == 200, put.text
        d = httpx.delete(f"{base}/sessions/c{i}", timeout=60)
        assert d.status_code == 200, d.text
        g = httpx.get(f"{base}/sessions/c{i}/clock", timeout=60)
        assert g.status_code == 404, (i, worker_of(d), worker_of(g), g.text)  # gone at once
        crossed["delete"] += worker_of(d) != worker_of(g)
    assert min(crossed.values()) >= 1, crossed  # the pairs did cross workers


def maintenance_passes(base: str) -> list[dict]:
    """Worker 0's recorded maintenance passes, by start (``GET /retention`` on fresh
    connections until both workers answered; worker 1's list must be empty)."""
    seen: dict[int, list[dict]] = {}
    deadline = time.monotonic() + STARTUP_S
    while set(seen) != {0, 1} or not seen[0]:
        assert time.monotonic() < deadline, seen  # a liveness bound only
        r = httpx.get(base + "/retention", timeout=10)
        seen[worker_of(r)] = r.json()["passes"]
        time.sleep(0.05)
    assert seen[1] == [], seen[1]
    return sorted(seen[0], key=lambda p: p["start"])


def test_two_workers_one_port_one_store(tmp_path: Path) -> None:
    port = free_port()
    base = f"http://127.0.0.1:{port}"
    log = tmp_path / "serve.log"
    data = tmp_path / "mem"
    # a retention policy that expires nothing but makes every maintenance pass visible
    maintained = {"TACTUS_RETAIN_DAYS": "3650", "TACTUS_RETENTION_INTERVAL": "0.5"}
    env = {"TACTUS_LOG_LEVEL": "info", "TACTUS_MAINTAIN_INTERVAL": "0.5", **maintained}
    proc = start_serve(port, data, log, "--workers", "2", env=env)
    gloves = ExitStack()
    try:
        assert wait_ok(proc, base + "/ready", STARTUP_S, interval=0.2) is not None, log.read_text()
        started = log.read_text()
        assert "2 workers on port" in started
        assert started.count("maintenance:    on") == 1, started  # worker 0's only
        # the startup lines once, not once per worker (issue 48, defect 13)
        assert started.count("tactus-memory is serving") == 1, started  # one banner
        assert started.count("opening the memory at") == 2, started  # "..." and "done", once
        assert started.count("ready: GET /ready") == 1, started
        assert started.count("of 2, pid") == 2, started  # each worker says who it is, once
        pids = worker_pids(log)
        assert set(pids) == {0, 1} and len(set(pids.values())) == 2
        for pid in pids.values():
            maps = Path(f"/proc/{pid}/maps").read_text()
            assert "onnxruntime" in maps and "libtorch" not in maps  # the light server, each

        read_your_writes(base)

        # gloves until each worker holds one (the kernel spreads connections: SO_REUSEPORT)
        held: dict[int, object] = {}
        for i in range(40):
            ws, worker = connect(gloves, port, f"glove{i}")
            held.setdefault(worker, ws)
            if len(held) == 2:
                break
        assert set(held) == {0, 1}, "every connection went to one worker"
        acked: dict[int, list[str]] = {0: [], 1: []}
        stream(held[0], 2, 0, acked[0])
        assert len(acked[0]) == 4

        # kill -9 worker 1 while its glove streams: what it acknowledged is stored
        def kill() -> None:
            os.kill(pids[1], signal.SIGKILL)

        stream(held[1], 12, 1, acked[1], kill=kill)
        assert len(acked[1]) >= 3
        deadline = time.monotonic() + STARTUP_S
        while "replaced" not in log.read_text():  # the parent saw it die (it looks every 0.1 s)
            assert time.monotonic() < deadline and proc.poll() is None, log.read_text()
            time.sleep(0.1)
        # the group is short of worker 1 until its replacement is ready: worker 0 says so,
        # the replacement names its loading step (a connection the dead worker had queued
        # is reset: asked again)
        while (r := ready_status(base)) != 200:
            assert r is None or r == "worker 1 of 2 is not ready" or r.startswith("["), r
            assert time.monotonic() < deadline and proc.poll() is None, log.read_text()
            time.sleep(0.1)
        assert "worker 1 (pid" in log.read_text() and "replaced" in log.read_text()
        new = worker_pids(log)
        assert new[0] == pids[0] and new[1] != pids[1]
        assert log.read_text().count("maintenance:    on") == 1  # still worker 0's only
        ws, _ = connect(gloves, port, "after")  # the group serves on after the kill
        after: list[str] = []
        stream(ws, 1, 2, after)
        assert len(after) == 2
        # an HTTP .npy body of several windows: one write, parsed off the event loop
        body = npy(frames(3 * WINDOW, 3).reshape(3, WINDOW, 32, 32))
        r = httpx.post(
            base + "/sessions/http/touch",
            params={"t": [1.0, 2.0, 3.0]},
            content=body,
            headers={"content-type": "application/x-npy"},
            timeout=60,
        )
        assert r.status_code == 201 and r.json()["count"] == 3, r.text
        after += r.json()["ids"]
        passes = retention_by_worker(base)
        assert passes[0] is not None  # worker 0 maintains: its retention passes ran
        assert passes[1] is None  # worker 1 (and its replacement) never ran one
        ran = maintenance_passes(base)  # worker 0's, each with start and end
        assert {p["by"] for p in ran} == {"worker 0"} and {p["pid"] for p in ran} == {pids[0]}
        for a, b in zip(ran, ran[1:], strict=False):
            assert a["start"] <= a["end"] <= b["start"], (a, b)  # never overlapping
    finally:
        with contextlib.suppress(Exception):  # the killed worker's glove is closed already
            gloves.close()
        stop_process(proc)
    assert proc.returncode == 0, log.read_text()[-3000:]
    text = log.read_text()
    assert f"maintenance pass by worker 0 pid {pids[0]}" in text  # each pass logged
    assert "maintenance pass by worker 1" not in text
    mem = Memory.open(str(data))
    stored = set(mem.store.scan(None, ["id"])["id"].to_pylist())
    assert set(acked[0]) | set(acked[1]) | set(after) <= stored  # nothing acknowledged lost
