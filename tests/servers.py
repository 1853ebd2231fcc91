"""Shared by the tests that start a real uvicorn server in a subprocess."""

from __future__ import annotations

import signal
import subprocess
import time
from collections.abc import Callable

import httpx
import pytest


def wait_healthy(
    proc: subprocess.Popen,
    base: str,
    startup_s: float,
    tail: Callable[[], str],
    stop: Callable[[], None],
) -> None:
    """Poll ``base/health`` until it answers 200; fail with the server's log tail if the
    process exits or ``startup_s`` passes (then ``stop`` it)."""
    deadline = time.monotonic() + startup_s
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            pytest.fail(f"server exited ({proc.returncode}):\n{tail()}")
        try:
            if httpx.get(base + "/health", timeout=2).status_code == 200:
                return
        except httpx.TransportError:
            pass
        time.sleep(0.3)
    stop()
    pytest.fail(f"server did not start in {startup_s}s:\n{tail()}")


def stop_process(proc: subprocess.Popen, wait_s: float = 20) -> None:
    """SIGTERM, wait ``wait_s``, then SIGKILL (and reap) if the server is still there."""
    if proc.poll() is None:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(wait_s)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(10)
