"""``tactus serve`` in a subprocess on a free port of 127.0.0.1, shared by the benchmarks
(``from serving import ...``, run as scripts from ``benchmarks/``) and the tests that start a
real server (``from benchmarks.serving import ...``, the repository root on ``sys.path``)."""

from __future__ import annotations

import os
import shutil
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Iterator, Mapping
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import httpx


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def start_serve(
    port: int,
    data: Path | str,
    log: Path,
    *extra: str,
    env: Mapping[str, str] | None = None,
    python: str | None = None,
) -> subprocess.Popen:
    """Start ``tactus serve --host 127.0.0.1 --port PORT --data DATA [--workers 1] *extra``
    (one worker unless ``extra`` names ``--workers``; the installed package, this interpreter
    or ``python``: another checkout's, for an A/B run), its output appended to ``log``; ``env``
    is added to this process's environment, after ``TACTUS_LOG_LEVEL=warning``."""
    cmd = [
        python or sys.executable,
        "-c",
        "from tactus_memory.cli import main; main()",
        "serve",
        "--host",
        "127.0.0.1",
        "--port",
        str(port),
        "--data",
        str(data),
        # one server process unless the caller names --workers (the default is every core)
        *([] if "--workers" in extra else ["--workers", "1"]),
        *extra,
    ]
    full_env = {**os.environ, "TACTUS_LOG_LEVEL": "warning", **(env or {})}
    with log.open("ab") as fh:
        return subprocess.Popen(cmd, stdout=fh, stderr=subprocess.STDOUT, env=full_env)


def wait_ok(
    proc: subprocess.Popen, url: str, seconds: float, interval: float = 0.3
) -> httpx.Response | None:
    """Poll ``GET url`` until it answers 200 and return that response; None if the process
    exits first or ``seconds`` pass (the caller says which, and stops the process)."""
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            return None
        try:
            r = httpx.get(url, timeout=2)
            if r.status_code == 200:
                return r
        except httpx.TransportError:
            pass
        time.sleep(interval)
    return None


def stop_process(proc: subprocess.Popen, wait_s: float = 20) -> None:
    """SIGTERM, wait ``wait_s``, then SIGKILL (and reap) if the server is still there."""
    if proc.poll() is None:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(wait_s)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(10)


def kill_process(proc: subprocess.Popen | None, wait_s: float = 30) -> None:
    """SIGKILL (no shutdown hooks, no flush) and reap, if the process is still there."""
    if proc is not None and proc.poll() is None:
        proc.send_signal(signal.SIGKILL)
        proc.wait(wait_s)


@contextmanager
def serve_app(app: Any, startup_s: float = 180, probe: str = "/live") -> Iterator[str]:
    """A real uvicorn server for ``app`` on a free port of 127.0.0.1, in a thread of this
    process (so a test can inject failures into the memory it serves); yields its base URL
    once ``probe`` answers 200, and stops it (lifespan shutdown included) on exit.
    ``startup_s`` is a liveness bound only: a loaded machine starts slowly."""
    import uvicorn

    port = free_port()
    server = uvicorn.Server(uvicorn.Config(app, host="127.0.0.1", port=port, log_level="warning"))
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    base = f"http://127.0.0.1:{port}"
    deadline = time.monotonic() + startup_s
    while True:
        try:
            if httpx.get(base + probe, timeout=2).status_code == 200:
                break
        except httpx.TransportError:
            pass
        if time.monotonic() > deadline or not thread.is_alive():
            server.should_exit = True
            thread.join(15)
            raise RuntimeError(f"uvicorn at {base} did not answer {probe} within {startup_s} s")
        time.sleep(0.05)
    try:
        yield base
    finally:
        server.should_exit = True
        thread.join(30)


def copy_checkout(root: Path, dest: Path) -> None:
    """``root``'s files as a fresh clone has them (tracked and new, not ignored ones: no
    store, no runs, no venv) copied into ``dest`` (the newcomer test's and ``make_run.py``'s
    fresh copy)."""
    listed = subprocess.run(
        ["git", "ls-files", "-z", "--cached", "--others", "--exclude-standard"],
        cwd=root,
        capture_output=True,
        check=True,
    ).stdout.decode()
    for name in filter(None, listed.split("\0")):
        src = root / name
        if src.is_file():
            (dest / name).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(src, dest / name)


#: a ``sitecustomize`` that makes what ``make run`` does not install (the ``train`` extra's
#: side: torch, sentence-transformers, transformers) unimportable, so a process of a venv that
#: has them runs as a newcomer's does, its models on ONNX Runtime
NO_TORCH = """
import sys

class NoTorch:
    def find_spec(self, name, path=None, target=None):
        if name.split(".")[0] in {"torch", "sentence_transformers", "transformers"}:
            raise ModuleNotFoundError(f"No module named {name!r} (make run installs no torch)")
        return None

sys.meta_path.insert(0, NoTorch())
"""


def without_torch(env: dict[str, str], folder: Path, tactus: Path) -> dict[str, str]:
    """``env`` with :data:`NO_TORCH` as the ``sitecustomize`` of every Python process: on
    ``PYTHONPATH``, and in a ``tactus`` (wrapping the executable ``tactus``) first on ``PATH``
    for the processes that do not pass the environment on (the MCP SDK's stdio client starts
    ``tactus mcp`` with PATH and HOME only)."""
    (folder / "bin").mkdir(parents=True, exist_ok=True)
    (folder / "sitecustomize.py").write_text(NO_TORCH)
    wrapper = folder / "bin" / "tactus"
    wrapper.write_text(f'#!/bin/sh\nPYTHONPATH={folder} exec {tactus} "$@"\n')
    wrapper.chmod(0o755)
    path = f"{folder / 'bin'}{os.pathsep}{env.get('PATH', '')}"
    return {**env, "PYTHONPATH": str(folder), "PATH": path}
