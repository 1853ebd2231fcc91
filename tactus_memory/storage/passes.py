"""Who commits and who maintains, process-wide: the listeners told of every commit this
process makes (``tactus serve --workers N`` counts them for the other workers:
read-your-writes) and the label and record of each maintenance pass (``Store.passes``,
logged and answered by ``GET /retention``)."""

from __future__ import annotations

import logging
import os
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass

#: the store's logger: ``tactus serve`` prints its lines at the server's level
log = logging.getLogger("tactus_memory.storage.store")

#: maintenance passes each store remembers (``Store.passes``: the latest, start and end)
PASSES_KEPT = 64
#: who runs this process's maintenance passes, in their log lines and records (``tactus serve
#: --workers N`` names its worker: :func:`set_maintainer`)
_MAINTAINER: list[str] = [""]


#: called after every commit this process makes to any table of any store (``tactus serve
#: --workers N`` tells the other workers, so each request reads its client's writes)
_ON_ANY_COMMIT: list[Callable[[], None]] = []


def on_any_commit(listener: Callable[[], None]) -> None:
    """Call ``listener`` after each commit of this process (before it is acknowledged)."""
    _ON_ANY_COMMIT.append(listener)


def announce_commit() -> None:
    """Tell the listeners (:func:`on_any_commit`) that a commit landed; never raises."""
    for listener in _ON_ANY_COMMIT:
        try:
            listener()
        except Exception:  # noqa: BLE001  (a notice: the commit stands either way)
            log.exception("a commit listener failed")


def set_maintainer(label: str) -> None:
    """Name this process in its maintenance passes' records and log lines ("worker 0")."""
    _MAINTAINER[0] = label


def maintainer() -> str:
    """This process's label for its maintenance passes ("" unless one was set)."""
    return _MAINTAINER[0]


@dataclass(frozen=True)
class MaintenancePass:
    """One maintenance pass of a store: unix times it started and ended, by whom (process id
    and its label)."""

    start: float
    end: float
    pid: int
    by: str


def record_pass(passes: deque[MaintenancePass], start: float) -> None:
    """Record (in ``passes``) and log a pass of this process that began at ``start``."""
    done = MaintenancePass(start, time.time(), os.getpid(), _MAINTAINER[0])
    passes.append(done)
    log.info(
        "maintenance pass by %s pid %d: %.3f to %.3f (%.2f s)",
        done.by or "this process", done.pid, done.start, done.end, done.end - done.start,
    )  # fmt: skip
