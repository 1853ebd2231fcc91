"""Clock offsets in the store's meta table: one row per session (key ``clock:<session>``,
value JSON ``{"sense/source": offset}``).

One row per session, so a PUT writes one small row (one JSON of every session's offsets grew
with each new session: 3,060 PUTs left a 141 MB meta table) and deleting a session deletes
its row. Stores written before keep all offsets under :data:`CLOCK_KEY` in one JSON value:
they are read as they are and moved to per-session rows on the next clock write.
"""

from __future__ import annotations

import json

from tactus_memory.store import Store

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
