"""``tactus serve --workers N``: N server processes on one port and one store.

The parent reserves the port (``--port 0``: the one it got), then forks N workers before it
has loaded anything (no model, no LanceDB, no thread). Each worker binds the same address
with ``SO_REUSEPORT`` (the kernel spreads new connections, WebSocket gloves included, across
them) and is a whole ``tactus serve``: its own event loop, group committer and models, the
"several servers, one store" path (appends from several processes, each seeing the others'
commits within ``TACTUS_READ_CONSISTENCY``). Worker 0 alone maintains the store (when
maintenance is on). Each writes a marker in a folder the parent made once its models are
loaded; ``/ready`` answers 200 only while every worker's marker is there (:class:`Workers`).
A worker that dies (even ``kill -9``) is replaced: its marker goes, so ``/ready`` says
which one is starting; what it acknowledged was committed first, so nothing acknowledged is
lost. SIGTERM or Ctrl+C stops them all (each commits what it queued).
"""

from __future__ import annotations

import contextlib
import mmap
import os
import shutil
import signal
import socket
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

#: a worker that exits with this status failed to start (a bad setting, a model that did
#: not load): the others would too, so the parent stops them all (the command's own status)
STARTUP_FAILED = 2
#: seconds between the parent's looks at its workers
POLL_S = 0.1


def worker_torch_threads(settings: Any) -> Any:
    """A torch server's workers share the cores: half of each one's share per call (as
    ``serving_torch_threads`` gives one server half of them)."""
    if settings.torch_threads is not None or settings.onnx:
        return settings
    share = max(1, (os.cpu_count() or 2) // (2 * settings.workers))
    return settings.model_copy(update={"torch_threads": share})


#: bytes per worker in the group's commit counters (one unsigned 64-bit count each)
COUNTER_BYTES = 8
COMMITS_FILE = "commits"


@dataclass
class Workers:
    """What a worker knows of its group: its index, how many, and the markers' folder.

    Read-your-writes across workers (issue 48): each worker counts its commits in its own
    slot of a file the group shares (``commits``, mapped into memory: a write and a read are
    a few bytes, no system call); before each request a worker compares the others' slots
    with what it saw when it last read the latest versions of that store, and reads them
    again when they moved (:meth:`refresh`). A write is counted before it is acknowledged,
    so a request sent after an acknowledgement sees that write, whichever worker it reaches.
    """

    index: int
    count: int
    folder: Path
    _counters: Any = None
    _mine: int = 0
    _seen: dict[int, bytes] = field(default_factory=dict)

    def open_counters(self) -> None:
        """Map the group's commit counters (in the worker, after the fork) and count this
        worker's commits there from now on."""
        from tactus_memory.storage.passes import on_any_commit

        with (self.folder / COMMITS_FILE).open("r+b") as fh:
            self._counters = mmap.mmap(fh.fileno(), COUNTER_BYTES * self.count)
        on_any_commit(self.count_commit)

    def count_commit(self) -> None:
        self._mine += 1
        at = self.index * COUNTER_BYTES
        self._counters[at : at + COUNTER_BYTES] = self._mine.to_bytes(COUNTER_BYTES, "little")

    def others(self) -> bytes:
        """The other workers' commit counts, as bytes (equal: nobody else committed)."""
        at = self.index * COUNTER_BYTES
        mm = self._counters
        return mm[:at] + mm[at + COUNTER_BYTES :] if mm is not None else b""

    def refresh(self, memory: Any) -> bool:
        """Read ``memory``'s tables at their latest version when another worker committed
        since this one last did for it; True when it did."""
        now = self.others()
        key = id(memory)
        if self._seen.get(key) == now:
            return False
        memory.read_latest()  # after the counts were read: a later commit is seen next time
        self._seen[key] = now
        return True

    def mark_ready(self) -> None:
        tmp = self.folder / f".{self.index}.tmp"
        tmp.write_text(str(os.getpid()))
        os.replace(tmp, self.folder / str(self.index))

    def failed(self, line: str) -> None:
        """Leave this worker's startup error (one line) for the parent, which prints the
        first one once: every worker fails alike, and each printing it raced."""
        tmp = self.folder / f".error-{self.index}.tmp"
        tmp.write_text(line)
        os.replace(tmp, self.folder / f"error-{self.index}")

    def not_ready(self) -> list[int]:
        """The workers whose models are not loaded (or that are being replaced)."""
        return [i for i in range(self.count) if not (self.folder / str(i)).is_file()]


def listening_socket(host: str, port: int, *, reuse_port: bool = True) -> socket.socket:
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    sock = socket.socket(family, socket.SOCK_STREAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    if reuse_port:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEPORT, 1)
    sock.bind((host, port))
    return sock


#: what a worker runs (``tactus serve``'s own steps: ``serve_cmd.load_app``, ``run_server``)
Server = tuple[Callable[..., Any], Callable[..., None]]


def _worker(
    settings: Any, group: Workers, say: Callable[[str], None], debug: bool, server: Server
) -> None:  # pragma: no cover  (runs in the forked child; tests/service/test_workers.py drives it)
    """A forked worker: a whole server on the group's port; never returns."""
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    signal.signal(signal.SIGINT, signal.SIG_DFL)
    status = 0
    load_app, run_server = server
    try:
        from tactus_memory.service.startup import explain
        from tactus_memory.storage.passes import set_maintainer

        set_maintainer(f"worker {group.index}")
        group.open_counters()

        def line(text: str) -> None:
            if group.index == 0:  # the group's progress, once (every worker loads alike)
                say(text)

        try:
            application = load_app(settings, say=line, on_ready=group.mark_ready)
            application.state.tactus.workers = group
            sock = listening_socket(settings.host, settings.port)
            sock.listen(2048)
            run_server(application, settings, sockets=[sock], worker=group)
        except Exception as exc:  # noqa: BLE001  (startup: one line, the group stops)
            if debug:
                raise
            group.failed(f"tactus serve: {explain(exc, settings.data)}")
            status = STARTUP_FAILED
        else:
            failed = getattr(application.state.tactus, "load_error", None)
            if failed is not None:
                group.failed(f"tactus serve: {explain(failed, settings.data)}")
                status = STARTUP_FAILED
    except BaseException:  # noqa: BLE001
        import traceback

        traceback.print_exc()
        status = status or 1
    finally:
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(status)


def serve_workers(
    settings: Any, count: int, say: Callable[[str], None], server: Server, debug: bool = False
) -> int:
    """Run ``count`` workers (each runs ``server``: load the app, serve it) until SIGTERM or
    SIGINT; the exit status for the command."""
    reserve = listening_socket(settings.host, settings.port)  # holds the port; never listens
    port = reserve.getsockname()[1]
    settings = settings.model_copy(update={"port": port})
    folder = Path(tempfile.mkdtemp(prefix="tactus-workers-"))
    (folder / COMMITS_FILE).write_bytes(bytes(COUNTER_BYTES * count))
    pids: dict[int, int] = {}
    stopping = False

    def start(index: int) -> None:
        (folder / str(index)).unlink(missing_ok=True)
        own = settings.model_copy(update={"maintain": settings.maintain and index == 0})
        group = Workers(index, count, folder)
        sys.stdout.flush()
        sys.stderr.flush()
        pid = os.fork()
        if pid == 0:
            reserve.close()
            _worker(own, group, say, debug, server)
        pids[index] = pid

    def stop(signum: int, frame: Any) -> None:
        nonlocal stopping
        stopping = True
        for pid in pids.values():
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGTERM)

    signal.signal(signal.SIGTERM, stop)
    signal.signal(signal.SIGINT, stop)
    say(f"tactus serve: {count} workers on port {port} (worker 0 maintains the store)")
    status = 0
    try:
        for i in range(count):
            start(i)
        while pids:
            time.sleep(POLL_S)
            for index, pid in list(pids.items()):
                done, code = os.waitpid(pid, os.WNOHANG)
                if done == 0:
                    continue
                del pids[index]
                (folder / str(index)).unlink(missing_ok=True)
                exit_status = os.waitstatus_to_exitcode(code)
                if stopping:
                    continue
                if exit_status == STARTUP_FAILED:
                    status = STARTUP_FAILED
                    stop(signal.SIGTERM, None)  # the others would fail alike
                    error = folder / f"error-{index}"
                    say(
                        error.read_text()
                        if error.is_file()
                        else f"tactus serve: worker {index} failed to start"
                    )
                    continue
                say(f"tactus serve: worker {index} (pid {pid}) exited ({exit_status}); replaced")
                start(index)
    finally:
        reserve.close()
        shutil.rmtree(folder, ignore_errors=True)
    return status
