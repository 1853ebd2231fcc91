"""A session's timeline rows: the items of a scope on the aligned clock
(:meth:`~tactus_memory.temporal.operators.Temporal.timeline` and the context of ``before`` /
``after`` read them), and the overlap rule both use."""

from __future__ import annotations

from typing import TYPE_CHECKING

from tactus_memory.errors import InvalidInputError
from tactus_memory.matching import TIMELINE_MAX
from tactus_memory.results import Episode, TimelineItem, row_fields
from tactus_memory.storage.tables import HIT_COLUMNS

if TYPE_CHECKING:
    from tactus_memory.storage.store import Store
    from tactus_memory.temporal.clocks import Offsets
    from tactus_memory.where import Where


def overlaps(item: TimelineItem | Episode, after: float | None, before: float | None) -> bool:
    """Whether ``item``'s aligned span meets ``[after, before]`` (None: open on that side)."""
    return (after is None or item.t_end_aligned >= after) and (
        before is None or item.t_aligned <= before
    )


def timeline_items(store: Store, where: Where, offsets: Offsets) -> list[TimelineItem]:
    """The rows ``where`` selects as timeline items on each stream's aligned clock (its
    ``offsets``), in aligned time order; more than ``TIMELINE_MAX`` is an InvalidInputError."""
    rows = store.scan(where.sql(), HIT_COLUMNS, limit=TIMELINE_MAX + 1).to_pylist()
    if len(rows) > TIMELINE_MAX:
        raise InvalidInputError(
            f"more than {TIMELINE_MAX} items in range; narrow it with after/before or senses"
        )
    items = []
    for r in rows:
        off = offsets.get((r["session"], r["sense"], r.get("source") or ""), 0.0)
        items.append(
            TimelineItem(**row_fields(r), t_aligned=r["t"] + off, t_end_aligned=r["t_end"] + off)
        )
    items.sort(key=lambda it: (it.t_aligned, it.t_end_aligned, it.sense, it.source, it.id))
    return items
