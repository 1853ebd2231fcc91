"""The audit log: who wrote, deleted or changed keys, where, and how much.

One row per write, delete or key change in the ``audit`` table of the store's root database:
time, key id (``operator`` for the ``--token``, ``anonymous`` on a store with neither), tenant,
route (``POST /sessions/{session}/text``: the route's template, not its ids), HTTP status
and item count. Never a key, never a payload. Rows are buffered and committed together at most
every :data:`FLUSH_EVERY` seconds (and when the log closes), so a burst of writes costs one
extra commit, not one each. ``tactus audit`` prints them.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass
from typing import TYPE_CHECKING, Any

from tactus_memory.identity import validate_tenant
from tactus_memory.storage.connect import normalise_uri, storage_options_for
from tactus_memory.storage.tables import audit_schema
from tactus_memory.where import _sql_float, _sql_str, finite_float

if TYPE_CHECKING:
    pass

log = logging.getLogger(__name__)

#: the audit table, in the root database
AUDIT = "audit"
#: seconds between the commits of buffered audit rows
FLUSH_EVERY = 1.0
#: a maintaining server compacts the audit table (and drops versions older than the
#: store's retention) after this many flushes, as the items table after ``compact_every``
COMPACT_EVERY = 64


@dataclass(frozen=True)
class AuditEntry:
    t: float
    key_id: str
    tenant: str
    route: str
    status: int
    count: int


class AuditLog:
    """Buffered appends to, and reads of, the ``audit`` table of the store at ``root``."""

    def __init__(
        self,
        root: str,
        *,
        storage_options: dict[str, str] | None = None,
        clock: Callable[[], float] = time.time,
        retain_seconds: float | None = None,
    ) -> None:
        """``retain_seconds``: this process maintains the store; the audit table is compacted
        every :data:`COMPACT_EVERY` flushes, keeping versions this recent (None: never)."""
        import lancedb

        self.uri = normalise_uri(str(root))
        options = storage_options_for(self.uri, storage_options)
        self.db = lancedb.connect(self.uri, storage_options=options or None)
        self.clock = clock
        self._pending: list[AuditEntry] = []
        self._lock = threading.Lock()
        self._flusher: threading.Timer | None = None
        self._table: Any = None
        self.retain_seconds = retain_seconds
        self._flushes = 0

    def record(self, key_id: str, tenant: str, route: str, status: int, count: int) -> None:
        """Buffer one entry (committed within :data:`FLUSH_EVERY` seconds)."""
        entry = AuditEntry(self.clock(), key_id, validate_tenant(tenant), route, status, count)
        with self._lock:
            self._pending.append(entry)
            if self._flusher is None:
                self._flusher = threading.Timer(FLUSH_EVERY, self._flush_quietly)
                self._flusher.daemon = True
                self._flusher.start()

    def _flush_quietly(self) -> None:
        try:
            self.flush()
        except Exception:  # noqa: BLE001  (kept in the buffer, retried on the next record)
            log.exception("could not write the audit log; kept for the next try")

    def flush(self) -> int:
        """Commit the buffered entries now; returns how many."""
        import pyarrow as pa

        with self._lock:
            entries, self._pending = self._pending, []
            self._flusher = None
        if not entries:
            return 0
        try:
            data = pa.Table.from_pylist([asdict(e) for e in entries], schema=audit_schema())
            if self._table is None:
                self._table = self.db.create_table(AUDIT, schema=audit_schema(), exist_ok=True)
            self._table.add(data)
        except Exception:
            with self._lock:
                self._pending[:0] = entries
            raise
        self._flushes += 1
        if self.retain_seconds is not None and self._flushes % COMPACT_EVERY == 0:
            tidy(self.db, self.retain_seconds)
        return len(entries)

    def close(self) -> None:
        """Flush what is buffered (a server's shutdown)."""
        with self._lock:
            if self._flusher is not None:
                self._flusher.cancel()
        self.flush()

    def entries(
        self, tenant: str | None = None, since: float | None = None, limit: int | None = 1000
    ) -> list[AuditEntry]:
        """Committed entries, oldest first (``tenant``/``since`` filter them)."""
        res = self.db.list_tables()
        if AUDIT not in set(getattr(res, "tables", res)):
            return []
        parts = []
        if tenant is not None:
            parts.append(f"tenant = {_sql_str(validate_tenant(tenant))}")
        if since is not None:
            parts.append(f"t >= {_sql_float(finite_float(since, 'since'))}")
        q = self.db.open_table(AUDIT).search()
        if parts:
            q = q.where(" AND ".join(parts))
        rows = sorted(q.limit(None).to_arrow().to_pylist(), key=lambda r: r["t"])
        rows = rows if limit is None else rows[-limit:]
        return [AuditEntry(**r) for r in rows]


def tidy(db: Any, retain_seconds: float) -> list[str]:
    """Compact the root database's own tables (keys, audit) and remove their versions older
    than ``retain_seconds`` (``tactus maintain`` and a maintaining server run it); returns the
    tables it tidied."""
    from datetime import timedelta

    from tactus_memory.storage.keys import KEYS

    res = db.list_tables()
    present = set(getattr(res, "tables", res))
    done = []
    for name in (KEYS, AUDIT):
        if name in present:
            db.open_table(name).optimize(cleanup_older_than=timedelta(seconds=retain_seconds))
            done.append(name)
    return done
