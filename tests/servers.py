"""Shared by the tests that start a real uvicorn server in a subprocess."""

from __future__ import annotations

import subprocess
from collections.abc import Callable

import pytest

from benchmarks.serving import stop_process, wait_ok

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
