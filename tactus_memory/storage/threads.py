"""Background threads for store maintenance that an exiting interpreter waits for (the
compaction, cleanup and retention threads of :mod:`tactus_memory.storage.scheduler`).

Compaction, erasure and version cleanup run in daemon threads off the write path. A daemon
thread still inside Lance's native code while Python finalises aborts the process (SIGABRT),
so a script that writes or deletes and ends at once would crash: every such thread is started
here and joined at exit (bounded). Imports nothing of the project (storage's bottom floor)."""

from __future__ import annotations

import atexit
import threading
import time
from typing import Any

#: the longest an exiting interpreter waits for background maintenance (s): a daemon thread
#: still inside Lance's native code while Python finalises aborts the process (SIGABRT)
EXIT_WAIT_S = 120.0
_running: set[threading.Thread] = set()
_running_lock = threading.Lock()


def start_background(target: Any, name: str) -> threading.Thread:
    """A daemon thread for maintenance work that an exiting interpreter waits for (at most
    :data:`EXIT_WAIT_S` in all), so a script that writes or deletes and ends at once exits
    cleanly instead of aborting mid-compaction."""

    def run() -> None:
        try:
            target()
        finally:
            with _running_lock:
                _running.discard(threading.current_thread())

    thread = threading.Thread(target=run, name=name, daemon=True)
    with _running_lock:
        _running.add(thread)
    thread.start()
    return thread


@atexit.register
def _wait_for_background() -> None:
    deadline = time.monotonic() + EXIT_WAIT_S
    while True:
        with _running_lock:
            alive = [t for t in _running if t.is_alive()]
        if not alive or time.monotonic() >= deadline:
            return
        alive[0].join(max(0.0, deadline - time.monotonic()))
