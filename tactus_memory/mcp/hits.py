"""What the MCP tools answer: small JSON an agent can read in one glance.

Every remembered thing is a :class:`Found`: its id (to ask again or cite), session, sense,
its time span ``t``/``t_end`` (seconds on the session clock; ``when`` is the same start in
ISO 8601 UTC when ``t`` is a unix time), the calibrated ``score`` for ranked results, the
text of notes, and for touch a :class:`TouchSummary` (how much of the glove was in contact,
how hard) instead of the frames themselves (8 x 32 x 32 numbers per window).
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from datetime import datetime, timezone
from typing import Any

import numpy as np
from pydantic import BaseModel, Field

from tactus_memory.results import Moment, Place, SessionSummary
from tactus_memory.senses.base import bytes_to_array
from tactus_memory.storage.store import Store
from tactus_memory.touch.windows import contact_taxels
from tactus_memory.where import Where

#: a ``t`` at or after this (2001-09-09, unix 1e9) is a wall-clock time and gets ``when``
UNIX_EPOCH_FLOOR = 1e9
#: meta larger than this (JSON characters) is left out of a result (``meta_omitted``)
MAX_META_CHARS = 400
#: evidence items listed per moment (the moment still counts every sense)
MAX_MOMENT_ITEMS = 8


class TouchSummary(BaseModel):
    """A touch window in four numbers (the frames stay in the store)."""

    frames: int = Field(description="Frames in the window.")
    contact_taxels: int = Field(
        description="Most taxels in contact in any one frame (calibrated >= 1/6)."
    )
    contact_area: float = Field(
        description="contact_taxels / (H * W): share of the sensor's frame in contact (H x W "
        "the touch sense's frame shape, 32x32 = 1024 taxels on the glove's raster)."
    )
    peak: float = Field(description="Highest calibrated pressure in the window, 0..1.")


class Found(BaseModel):
    """One remembered item."""

    id: str
    session: str
    sense: str
    t: float = Field(description="Start, seconds on the session clock.")
    t_end: float
    when: str | None = Field(None, description="Start as ISO 8601 UTC, when t is a unix time.")
    score: float | None = Field(None, description="Calibrated match score (higher is better).")
    match: bool | None = Field(
        None,
        description="Whether the score clears its sense's match bar for this query (the rule "
        "of last/first/count); ranked results only.",
    )
    bar: float | None = Field(None, description="The score this item's sense needed to match.")
    text: str | None = None
    source: str | None = Field(None, description="The stream it came from, if any.")
    meta: dict[str, Any] | None = None
    meta_omitted: int | None = Field(None, description="Size (chars) of meta left out.")
    touch: TouchSummary | None = None
    grasp_windows: int | None = Field(
        None,
        description="A touch answer is a grasp by default: the windows of that hold it pools "
        "(id is its best window, t/t_end span the hold).",
    )
    facets: dict[str, Any] | None = Field(
        None,
        description="Touch: force, area, peak, centroid, spread, regions (share of the load), "
        "grip; a grasp adds onset, release, duration, peak_time, ramp (squeeze), slip.",
    )


class MomentResult(BaseModel):
    """Things of one session that happened together."""

    session: str
    t: float
    t_end: float
    when: str | None = None
    score: float
    senses: list[str] = Field(description="Senses with evidence in this moment.")
    best: str = Field(description="Id of the best-scoring item.")
    items: list[Found] = Field(description=f"Evidence, time order (at most {MAX_MOMENT_ITEMS}).")


class SearchResult(BaseModel):
    query: str
    hits: list[Found]
    moments: list[MomentResult] | None = Field(
        None, description="With group='moment': the moments (hits are their best items)."
    )


class OccurrenceResult(BaseModel):
    """``last`` / ``first``: the occurrence, or ``found: false``."""

    query: str
    found: bool
    moment: MomentResult | None = None


class CountResult(BaseModel):
    query: str
    count: int = Field(description="Distinct occurrences (matches merged within merge_gap s).")
    capped: bool = Field(description="True when the count is a lower bound (narrow the time).")
    occurrences: list[MomentResult] = Field(
        description="Each occurrence, in time order (or in `sort` order)."
    )


class ContextResult(BaseModel):
    """``before`` / ``after``: the anchor's best match and what happened around it."""

    side: str
    window: float
    anchor: Found | None = Field(None, description="Null when nothing matched the anchor.")
    items: list[Found]


class TimelineResult(BaseModel):
    session: str
    items: list[Found]


class SessionsResult(BaseModel):
    sessions: list[SessionSummary]


class Remembered(BaseModel):
    id: str
    session: str
    t: float


class Taught(BaseModel):
    """A teaching: ``windows`` of ``session`` between ``t`` and ``t_end`` held ``label``."""

    id: str
    label: str
    session: str
    t: float
    t_end: float
    windows: int


def when(t: float) -> str | None:
    """ISO 8601 UTC of a unix time; None for a relative clock."""
    if t < UNIX_EPOCH_FLOOR:
        return None
    return datetime.fromtimestamp(t, tz=timezone.utc).isoformat(timespec="milliseconds")


def touch_summary(window: np.ndarray) -> TouchSummary:
    """(K, H, W) stored (calibrated) window of any touch sense -> its summary."""
    taxels = int(contact_taxels(window).max()) if window.size else 0
    frame = int(window.shape[-2] * window.shape[-1]) if window.ndim == 3 else 1
    return TouchSummary(
        frames=int(window.shape[0]),
        contact_taxels=taxels,
        contact_area=round(taxels / max(frame, 1), 4),
        peak=round(float(np.max(window)) if window.size else 0.0, 4),
    )


def touch_summaries(store: Store, ids: Sequence[str]) -> dict[str, TouchSummary]:
    """Summaries of the touch items ``ids``, read from the store in one scan."""
    if not ids:
        return {}
    rows = store.scan(Where().ids(list(ids)).sql(), ["id", "raw"], limit=len(ids)).to_pylist()
    out = {}
    for row in rows:
        if row.get("raw") is not None:
            window = np.asarray(bytes_to_array(row["raw"]), dtype=np.float32)
            out[row["id"]] = touch_summary(window)
    return out


def found(item: Any, touch: dict[str, TouchSummary]) -> Found:
    """A Hit / Evidence / TimelineItem -> :class:`Found` (aligned times where it has them)."""
    t = float(getattr(item, "t_aligned", item.t))
    t_end = float(getattr(item, "t_end_aligned", item.t_end))
    meta = item.meta or None
    omitted = None
    if meta:
        size = len(json.dumps(meta))
        if size > MAX_META_CHARS:
            meta, omitted = None, size
    score = getattr(item, "score", None)
    return Found(
        id=item.id,
        session=item.session,
        sense=item.sense,
        t=round(t, 3),
        t_end=round(t_end, 3),
        when=when(t),
        score=None if score is None else round(float(score), 3),
        match=None if score is None else bool(getattr(item, "match", False)),
        bar=None if getattr(item, "bar", None) is None else round(float(item.bar), 3),
        text=item.text,
        source=item.source or None,
        meta=meta,
        meta_omitted=omitted,
        touch=touch.get(item.id),
        grasp_windows=getattr(item, "n", None),
        facets=getattr(item, "facets", None),
    )


def shown_hits(m: Moment) -> list[Any]:
    """At most MAX_MOMENT_ITEMS of a moment's evidence, the best item always among them."""
    if len(m.hits) <= MAX_MOMENT_ITEMS:
        return list(m.hits)
    best = [h for h in m.hits if h.id == m.best]
    rest = sorted((h for h in m.hits if h.id != m.best), key=lambda h: -h.score)
    keep = {h.id for h in best + rest[: MAX_MOMENT_ITEMS - len(best)]}
    return [h for h in m.hits if h.id in keep]


def moment_fields(m: Moment | Place, items: list[Found]) -> dict[str, Any]:
    """The fields of a :class:`MomentResult` (times and score rounded) from a library moment
    or place, whose shown ``items`` are given."""
    return {
        "session": m.session,
        "t": round(m.t, 3),
        "t_end": round(m.t_end, 3),
        "when": when(m.t),
        "score": round(m.score, 3),
        "senses": m.senses,
        "best": m.best,
        "items": items,
    }


class Compactor:
    """Turns the library's results into tool results, reading touch summaries as needed."""

    def __init__(self, store: Store) -> None:
        self.store = store

    def _touch(self, items: Sequence[Any]) -> dict[str, TouchSummary]:
        return touch_summaries(self.store, [i.id for i in items if i.sense == "touch"])

    def items(self, items: Sequence[Any]) -> list[Found]:
        touch = self._touch(items)
        return [found(i, touch) for i in items]

    def moments(self, moments: Sequence[Moment]) -> list[MomentResult]:
        shown = [shown_hits(m) for m in moments]
        touch = self._touch([h for hits in shown for h in hits])
        return [
            MomentResult(**moment_fields(m, [found(h, touch) for h in hits]))
            for m, hits in zip(moments, shown, strict=True)
        ]
