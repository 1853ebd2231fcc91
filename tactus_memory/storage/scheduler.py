"""When maintenance runs: :class:`Background` schedules a pass of the store's
:class:`~tactus_memory.storage.compaction.Maintainer` off the write path after commits (at
most one at a time, at least ``maintain_interval`` apart), in a thread an exiting interpreter
waits for (:mod:`tactus_memory.storage.threads`)."""

from __future__ import annotations

import logging
import threading
from typing import Any

from tactus_memory.storage.threads import start_background

log = logging.getLogger(__name__)


# --------------------------------------------------------------------------- background
class Background:
    """Runs a memory's store maintenance off the write path: :meth:`schedule` after each
    commit starts one background pass when the store says one is due (compaction, cleanup, an
    index build once ``rows()`` passes the threshold); never in a process that does not own
    maintenance (``MaintenanceConfig.maintain`` false: ``tactus maintain`` does it)."""

    def __init__(self, store: Any, rows: Any, *, background: bool = True) -> None:
        self.store = store
        self.rows = rows  # () -> int: the live row count (for the index threshold)
        self.background = background
        self._thread: threading.Thread | None = None

    def schedule(self) -> None:
        if not self.store.maintenance.maintain:
            return  # another process maintains this store (`tactus maintain`)
        if not (self.store.needs_maintenance() or self.store.index_due(self.rows())):
            return
        if not self.background:
            self.store.maintain(force=True)
            return
        if self._thread is not None and self._thread.is_alive():
            return
        self._thread = start_background(self._quietly, "tactus-maintenance")

    def _quietly(self) -> None:
        try:
            self.store.maintain()
        except Exception:  # noqa: BLE001  (a background thread must not die loudly; retried)
            log.exception("background maintenance failed; it will be retried")

    def wait(self, timeout: float | None = None) -> None:
        if self._thread is not None:
            self._thread.join(timeout)
