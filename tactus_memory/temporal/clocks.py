"""Per-stream clock offsets: ``Clocks.set(session, sense, offset, source)`` records that a
stream's clock runs ``offset`` seconds behind its session's reference clock, so its items are
placed at ``t + offset`` (``t_aligned``) for grouping, ordering and every ``after``/``before``
bound of the temporal operators (:mod:`tactus_memory.temporal.operators`).

Stored in the store's meta table, one row per session (key ``clock:<session>``, value JSON
``{"sense/source": offset}``), so a PUT writes one small row (one JSON of every session's
offsets grew with each new session: 3,060 PUTs left a 141 MB meta table) and deleting a
session deletes its row. Stores written before keep all offsets under :data:`CLOCK_KEY` in one
JSON value: they are read as they are and moved to per-session rows on the next clock write.
"""

from __future__ import annotations

import json
import threading
from collections.abc import Mapping

from tactus_memory.errors import InvalidInputError
from tactus_memory.limits import MAX_CLOCK_OFFSET
from tactus_memory.names import validate_id, validate_sense_name
from tactus_memory.results import ClockOffset
from tactus_memory.storage.store import Store
from tactus_memory.where import finite_float, validate_source

#: the meta key of every session's offsets in one JSON value (stores written before)
CLOCK_KEY = "clock_offsets"
#: the meta key of one session's offsets is this prefix + the session id
CLOCK_PREFIX = "clock:"

Streams = dict[str, float]  # "sense/source" -> offset


def clock_table(store: Store) -> dict[str, Streams]:
    """Every clock offset: session -> {"sense/source": offset}."""
    table: dict[str, Streams] = json.loads(store.get_meta(CLOCK_KEY) or "{}")
    for key, value in store.meta_items(CLOCK_PREFIX).items():
        table[key.removeprefix(CLOCK_PREFIX)] = json.loads(value)
    return {session: streams for session, streams in table.items() if streams}


def session_clock(store: Store, session: str) -> Streams:
    """One session's offsets (one meta row, not the whole table)."""
    raw = store.get_meta(CLOCK_PREFIX + session)
    if raw is not None:
        return json.loads(raw)
    legacy = store.get_meta(CLOCK_KEY)
    return dict(json.loads(legacy).get(session, {})) if legacy else {}


def put_session_clock(store: Store, session: str, streams: Streams) -> None:
    """Replace one session's offsets (none: its row is deleted). Call under the memory lock."""
    legacy = store.get_meta(CLOCK_KEY)
    if legacy is not None:  # move the old one-value table to per-session rows first
        rows = {
            CLOCK_PREFIX + s: json.dumps(v, sort_keys=True) for s, v in json.loads(legacy).items()
        }
        if rows:
            store.set_meta_many(rows)
        store.delete_meta(CLOCK_KEY)
    if streams:
        store.set_meta(CLOCK_PREFIX + session, json.dumps(streams, sort_keys=True))
    elif store.get_meta(CLOCK_PREFIX + session) is not None:
        store.delete_meta(CLOCK_PREFIX + session)


def drop_session_clock(store: Store, session: str) -> int:
    """Delete every clock offset of ``session``; returns how many there were."""
    n = len(session_clock(store, session))
    if n:
        put_session_clock(store, session, {})
    return n


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
        #: the offsets as of a meta-table version: every question asks for them, and reading
        #: them is two meta queries (a tenth of a search's time beside a fleet's writes)
        self._cached: tuple[int, dict[tuple[str, str, str], float]] | None = None

    def offsets(self) -> dict[tuple[str, str, str], float]:
        """(session, sense, source) -> offset, for every recorded stream (a copy)."""
        version = self.store.meta_version()
        if self._cached is not None and self._cached[0] == version:
            return dict(self._cached[1])
        out: dict[tuple[str, str, str], float] = {}
        for session, streams in clock_table(self.store).items():
            for key, value in streams.items():
                sense, source = key.split("/", 1)
                out[(session, sense, source)] = float(value)
        self._cached = (version, out)
        return dict(out)

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
            streams = session_clock(self.store, session)
            key = f"{sense}/{source}"
            if value == 0.0:
                streams.pop(key, None)
            else:
                streams[key] = value
            put_session_clock(self.store, session, streams)  # this session's row only

    def listed(self, session: str | None = None) -> list[ClockOffset]:
        """Every recorded clock offset (of one session: its one meta row), sorted."""
        if session is not None:
            streams = session_clock(self.store, validate_id(session, "session id"))
            offsets: dict[tuple[str, ...], float] = {
                (session, *k.split("/", 1)): float(v) for k, v in streams.items()
            }
        else:
            offsets = {k: v for k, v in self.offsets().items()}
        return [
            ClockOffset(session=s, sense=sense, source=source, offset=v)
            for (s, sense, source), v in sorted(offsets.items())
        ]

    def drop_session(self, session: str) -> int:
        """Forget every offset of ``session`` (its items were deleted); returns how many."""
        with self.lock:
            return drop_session_clock(self.store, session)
