"""Issue 48, defect 13: ``tactus serve --workers 2`` with a wrong ``--space-path`` fails once,
before any worker starts: one line, exit 2, nothing opened. (Read-your-writes across workers,
the startup lines printed once and the maintenance passes of several workers:
tests/service/test_workers.py, on its real two-worker server.)"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path


def test_a_wrong_space_path_fails_once_before_the_workers_start(tmp_path: Path) -> None:
    cmd = [sys.executable, "-c", "from tactus_memory.cli import main; main()", "serve"]
    args = ["--workers", "2", "--port", "0", "--data", str(tmp_path / "mem")]
    r = subprocess.run(
        [*cmd, *args, "--space-path", str(tmp_path / "no-such-folder")],
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert r.returncode == 2, r.stderr
    lines = [line for line in (r.stdout + r.stderr).splitlines() if line.strip()]
    assert len(lines) == 1 and "--space-path" in lines[0] and "not a folder" in lines[0], lines
    assert not (tmp_path / "mem").exists()  # nothing opened, no worker started


def test_a_store_every_worker_refuses_is_one_error_line(tmp_path: Path) -> None:
    """A mistake only opening the store finds (here: a store recorded in another dimension
    of the space) fails every worker alike: the parent prints the first worker's line once
    (they used to race to print it once or twice), with the progress lines once, exit 2."""
    from tactus_memory.storage.store import Store

    Store(str(tmp_path / "mem")).bind_space("minilm", 7)
    cmd = [sys.executable, "-c", "from tactus_memory.cli import main; main()", "serve"]
    args = ["--workers", "2", "--port", "0", "--data", str(tmp_path / "mem"), "--no-touch"]
    r = subprocess.run([*cmd, *args], capture_output=True, text=True, timeout=300)
    assert r.returncode == 2, r.stderr
    out = r.stdout + r.stderr
    errors = [
        line for line in out.splitlines() if line.startswith("tactus serve: ") and "dim" in line
    ]
    assert len(errors) == 1, out
    assert out.count("opening the memory at") <= 1, out  # worker 0's progress only
    assert "Traceback" not in out
