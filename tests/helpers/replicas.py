"""Shared by the tests where several connections share one store (test_replicas, test_s3)."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from tactus_memory.memory.main import Memory
from tactus_memory.policies import MaintenanceConfig
from tests.helpers.fakes import HashingSpace

ROOT = Path(__file__).resolve().parents[2]
STALENESS = 0.5  # seconds: the read consistency the replicas here connect with


def open_replica(uri: str, *, maintain: bool, **kw: Any) -> Memory:
    """A connection to the store at ``uri`` (a folder or s3://) with the fake hashing space,
    read consistency :data:`STALENESS`, maintenance on or off, old versions kept 5 s."""
    return Memory.open(
        uri,
        HashingSpace(),
        read_consistency_interval=STALENESS,
        maintenance=MaintenanceConfig(maintain=maintain, retain_seconds=5.0),
        **kw,
    )


def wait_for(check: Callable[[], bool], timeout: float = 60.0) -> float:
    """Poll ``check()`` until true; return the seconds it took (fail after ``timeout``)."""
    t0 = time.monotonic()
    while not check():
        if time.monotonic() - t0 > timeout:
            pytest.fail(f"not visible after {timeout}s")
        time.sleep(0.05)
    return time.monotonic() - t0


def start_writer(
    data: str, prefix: str, n: int, *extra: str, env: dict[str, str] | None = None
) -> subprocess.Popen:
    """``python -m tests.helpers.replica_worker DATA PREFIX N *extra`` (one thread), pipes for its
    output; ``env`` is added to this process's environment."""
    return subprocess.Popen(
        [sys.executable, "-m", "tests.helpers.replica_worker", data, prefix, str(n), *extra],
        cwd=ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env={**os.environ, "OMP_NUM_THREADS": "1", **(env or {})},
    )
