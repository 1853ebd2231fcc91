"""Per-stream clock offsets: ``set(session, sense, offset, source)`` records that a stream's
clock runs ``offset`` seconds behind its session's reference clock, so its items are placed at
``t + offset`` (``t_aligned``) for grouping, ordering and every ``after``/``before`` bound of
the temporal operators (:mod:`tactus_memory.temporal`). Offsets live in the store's ``meta``
table (``Store.clock_table``): persisted, shared by the processes that open the store.
"""

from __future__ import annotations

import threading
from collections.abc import Mapping

from tactus_memory.errors import InvalidInputError
from tactus_memory.limits import MAX_CLOCK_OFFSET
from tactus_memory.models import ClockOffset
from tactus_memory.senses import validate_sense_name
from tactus_memory.store import Store
from tactus_memory.where import finite_float, validate_id, validate_source

#: (session, sense, source) -> offset in seconds
Offsets = Mapping[tuple[str, str, str], float]


def pad(offsets: Offsets, session: str | None) -> float:
    """How far store-side time bounds must be widened so no aligned item is missed."""
    vals = [abs(v) for (s, _, _), v in offsets.items() if session is None or s == session]
    return max(vals, default=0.0)


class Clocks:
    """The clock offsets of one store; writes hold the memory's write lock."""

    def __init__(self, store: Store, lock: threading.RLock) -> None:
        self.store = store
        self.lock = lock

    def offsets(self) -> dict[tuple[str, str, str], float]:
        """(session, sense, source) -> offset, for every recorded stream."""
        out: dict[tuple[str, str, str], float] = {}
        for session, streams in self.store.clock_table().items():
            for key, value in streams.items():
                sense, source = key.split("/", 1)
                out[(session, sense, source)] = float(value)
        return out

    def set(self, session: str, sense: str, offset: float, source: str = "") -> None:
        """Place the stream (session, sense, source) at ``t + offset`` on the session clock.

        Persisted in the store; ``offset=0`` removes the entry. The sense need not exist yet.
        """
        session = validate_id(session, "session id")
        sense = validate_sense_name(sense)
        source = validate_source(source)
        value = finite_float(offset, "offset")
        if abs(value) > MAX_CLOCK_OFFSET:
            raise InvalidInputError(
                f"offset {value!r} is beyond +-{MAX_CLOCK_OFFSET:g} s; a clock offset is a "
                "time shift, and t + offset must stay a finite number"
            )
        with self.lock:
            table = self.store.clock_table()
            streams = table.setdefault(session, {})
            key = f"{sense}/{source}"
            if value == 0.0:
                streams.pop(key, None)
                if not streams:
                    table.pop(session)
            else:
                streams[key] = value
            self.store.put_clock_table(table)

    def listed(self, session: str | None = None) -> list[ClockOffset]:
        """Every recorded clock offset (of one session), sorted."""
        if session is not None:
            validate_id(session, "session id")
        return [
            ClockOffset(session=s, sense=sense, source=source, offset=v)
            for (s, sense, source), v in sorted(self.offsets().items())
            if session is None or s == session
        ]

    def drop_session(self, session: str) -> None:
        """Forget every offset of ``session`` (one meta write; its items were deleted)."""
        with self.lock:
            table = self.store.clock_table()
            if table.pop(session, None):
                self.store.put_clock_table(table)
