"""Shared by the tests that start a real uvicorn server in a subprocess."""

from __future__ import annotations

import signal
import subprocess
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import pytest

from benchmarks.serving import free_port, start_serve, stop_process, wait_ok

__all__ = ["stop_process", "wait_healthy"]


def wait_healthy(
    proc: subprocess.Popen,
    base: str,
    startup_s: float,
    tail: Callable[[], str],
    stop: Callable[[], None],
) -> None:
    """Poll ``base/health`` until it answers 200; fail with the server's log tail if the
    process exits or ``startup_s`` passes (then ``stop`` it)."""
    if wait_ok(proc, base + "/health", startup_s) is not None:
        return
    if proc.poll() is not None:
        pytest.fail(f"server exited ({proc.returncode}):\n{tail()}")
    stop()
    pytest.fail(f"server did not start in {startup_s}s:\n{tail()}")


#: how long a test waits for a server it started to answer: a backstop against a hung process,
#: not a budget (the wait ends as soon as the server answers, and a server that exits fails at
#: once). A fresh clone's first start on a loaded 2-core machine (load 8 to 12) exported MiniLM
#: to ONNX for over 180 s, the old limit.
STARTUP_S = 900


class Server:
    """``tactus serve`` on a free port (``env`` added to the environment)."""

    def __init__(
        self, data: Path | str, log: Path, *extra: str, env: Mapping[str, str] | None = None
    ) -> None:
        self.port = free_port()
        self.base = f"http://127.0.0.1:{self.port}"
        self.log = log
        full_env = {"OMP_NUM_THREADS": "1", **(env or {})}
        self.proc = start_serve(self.port, data, log, *extra, env=full_env)
        wait_healthy(self.proc, self.base, STARTUP_S, lambda: log.read_text()[-3000:], self.kill)

    def kill(self) -> None:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGKILL)
            self.proc.wait(10)

    def stop(self) -> None:
        stop_process(self.proc)


def touch_and_note_found(
    proc: subprocess.Popen, base: str, log: Path, ready_s: float
) -> tuple[list[dict[str, Any]], str]:
    """Once the server at ``base`` is ready (its ``log`` shown if not in ``ready_s``): a touch
    window and a note stored, then ``(the hits of "red mug", the process's memory map)`` (the
    map says which runtimes it loaded)."""
    import httpx
    import numpy as np

    assert wait_ok(proc, base + "/ready", ready_s, interval=0.1) is not None, log.read_text()
    raw = np.full((8, 32, 32), 512, np.int16)
    raw[:, 10:22, 8:20] = 700
    with httpx.Client(base_url=base, timeout=30) as c:
        c.post("/sessions/a/touch", json={"frames": raw.tolist(), "t": 1.0}).raise_for_status()
        c.post("/sessions/a/text", json={"text": "holding a red mug", "t": 2.0}).raise_for_status()
        hits = c.get("/search", params={"q": "red mug", "k": 5}).json()["hits"]
    return hits, Path(f"/proc/{proc.pid}/maps").read_text()
