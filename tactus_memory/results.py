"""The result models: what the memory and its temporal operators return (pydantic, so the
service serves them as they are)."""

from __future__ import annotations

import json
from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field

Side = Literal["before", "after"]
#: a position (x, y, z) in metres, in the item's ``frame``
Position = tuple[float, float, float]
#: the place fields every item, hit and moment carries (None: not placed)
PlacePosition = Annotated[
    Position | None, Field(description="Where it happened (x, y, z), if known.")
]
PlaceFrame = Annotated[str | None, Field(description="The frame of `position`.")]


# --------------------------------------------------------------------------- memory
#: a touch item's or grasp's facets (tactus_memory.touch.facets): force, area, peak,
#: centroid, spread, regions, grip (and for a grasp onset, release, duration, peak_time, ramp,
#: slip); None for other senses and for touch rows stored before facets
FacetsField = Annotated[
    dict[str, Any] | None,
    Field(
        description="Touch only: what the window or grasp physically was (force, area, peak, "
        "centroid, spread, regions, grip; a grasp adds onset, release, duration, peak_time, "
        "ramp, slip), computed from its calibrated frames."
    ),
]


class Span(BaseModel):
    """What every stored item has first: its id, session, sense and time span."""

    id: str
    session: str
    sense: str
    t: float
    t_end: float


class Hit(Span):
    """One search result. ``score`` is the calibrated z-score, ``cosine`` the raw cosine."""

    score: float
    cosine: float
    meta: dict[str, Any] = Field(default_factory=dict)
    text: str | None = None
    source: str = ""
    episode: int | None = None
    match: bool = Field(
        False,
        description="The hit clears its sense's match bar for this query (score >= bar): the "
        "rule of last/first/count (tactus_memory.matching).",
    )
    bar: float | None = Field(
        None,
        description="The score this hit's sense needed to match for this query: max(the "
        "sense's threshold, MATCH_Z, 3.0 by default; RELATIVE_KEEP 0.4 x the best score of that "
        "sense for the query).",
    )
    position: PlacePosition = None
    frame: PlaceFrame = None
    n: int | None = Field(
        None,
        description="A grasp (touch answers by default, group='auto'): how many windows it "
        "pools; None for a single item.",
    )
    ids: list[str] | None = Field(None, description="A grasp's member windows, in time order.")
    window_score: float | None = Field(
        None, description="A grasp's best member window's own score (score is the pooled one)."
    )
    facets: FacetsField = None


class Item(Span):
    """One stored row, with ``raw`` decoded by its sense (array or text) when possible."""

    model_config = ConfigDict(arbitrary_types_allowed=True)

    meta: dict[str, Any] = Field(default_factory=dict)
    text: str | None = None
    raw: Any = None
    source: str = ""
    episode: int | None = None
    position: PlacePosition = None
    frame: PlaceFrame = None
    orientation: tuple[float, float, float, float] | None = Field(
        default=None, description="Unit quaternion (x, y, z, w) when known."
    )
    created: float
    vector: list[float] | None = None
    facets: FacetsField = None


class Stored(list[str]):
    """What a write returns: the ids of the items stored, in input order (a list, as
    before), and ``skipped``: ``(index, reason)`` of each input item the sense skipped
    rather than stored (``"idle"``: a touch window with no contact)."""

    def __init__(self, ids: Any = (), skipped: Any = ()) -> None:
        super().__init__(ids)
        self.skipped: list[tuple[int, str]] = list(skipped)


class SessionSummary(BaseModel):
    """Counts per sense and the time span of one session."""

    id: str
    n: int
    counts: dict[str, int]
    t_min: float
    t_max: float


class SenseInfo(BaseModel):
    """A sense registered in the store (live or persisted only)."""

    name: str
    modality: str
    dim: int
    provenance: dict[str, Any] = Field(default_factory=dict)
    live: bool = Field(description="Can embed new items now (false: known from the store only).")
    rows: int = Field(description="Items of this sense in the store.")
    mu: float | None = Field(None, description="Score calibration: null cosine mean.")
    sigma: float | None = Field(None, description="Score calibration: null cosine spread.")
    calib_n: int | None = Field(
        None, description="Rows the score calibration was estimated on (null: not yet)."
    )
    calib_final: bool = Field(
        False,
        description="The calibration is frozen: this sense's scores no longer move as data "
        "arrives (estimated on enough rows; re-estimated only after a re-embed).",
    )
    classes: list[str] = Field(
        default_factory=list, description="What the sense recognises: its trained classes."
    )
    taught: list[str] = Field(
        default_factory=list,
        description="Labels taught to it (`POST /sessions/{id}/labels`), searchable by text.",
    )
    precision_at_bar: dict[str, Any] | None = Field(
        None,
        description="How often a match is right: the precision of the top hits that pass the "
        "sense's match bar, measured on held-out questions (value, 95 % Wilson interval lo/hi, "
        "k of n, the bar, the question set, the target precision, target_reached and "
        "bar_at_target: the lowest bar whose lower bound reaches the target, null when none "
        "does); null when none was measured for this sense's encoder or space.",
    )
    shape: list[int] | None = Field(
        None,
        description="A windowed sense's frame shape: [H, W] for touch (its sensor profile: "
        "[32, 32] for the STAG glove; windows (K, H, W)), [6] for a 6-axis IMU. Null for "
        "senses that are not windowed.",
    )


def row_fields(row: dict[str, Any]) -> dict[str, Any]:
    """The columns every hit and item carry, from a stored row (``meta`` decoded)."""
    keys = ("id", "session", "sense", "t", "t_end", "text", "episode")
    out = {k: row.get(k) for k in keys}
    out.update(meta=json.loads(row["meta"] or "{}"), source=row.get("source") or "")
    if row.get("x") is not None:
        out.update(position=(row["x"], row["y"], row["z"]), frame=row.get("frame"))
    if row.get("facets"):
        out["facets"] = json.loads(row["facets"])
    return out


def hit_from_row(row: dict[str, Any], score: float, cos: float) -> Hit:
    return Hit(**row_fields(row), score=score, cosine=cos)


def item_from_row(row: dict[str, Any], raw: Any) -> Item:
    """A stored row (with ``raw`` already decoded) -> :class:`Item`."""
    return Item(
        **row_fields(row),
        raw=raw,
        created=row["created"],
        vector=row.get("vector"),
        orientation=row.get("orientation"),
    )


# --------------------------------------------------------------------------- temporal
class TimelineItem(BaseModel):
    """One stored item placed on the session clock (``t_aligned = t + clock offset``)."""

    id: str
    session: str
    sense: str
    source: str = ""
    t: float
    t_end: float
    t_aligned: float
    t_end_aligned: float
    text: str | None = None
    meta: dict[str, Any] = Field(default_factory=dict)
    episode: int | None = None
    position: PlacePosition = None
    frame: PlaceFrame = None
    facets: FacetsField = None


class Evidence(TimelineItem):
    """A scored item: ``score`` is the calibrated z-score, ``match`` whether it clears the
    per-sense threshold and the relative gate for the query."""

    score: float
    cosine: float
    match: bool = False
    bar: float | None = Field(
        None, description="The score this item's sense needed to match (see Hit.bar)."
    )


class Grasp(Evidence):
    """One grasp (:mod:`tactus_memory.search.grasps`): contiguous items of one stream, ranked by
    their
    pooled vector. ``id`` is its best-scoring member among the search's candidates; ``t`` /
    ``t_end`` (and the aligned pair) span every member; ``score``/``cosine`` are the pooled
    vector's; ``window_score`` the best member's own; ``ids`` every member, in time order."""

    n: int
    ids: list[str]
    window_score: float


class Moment(BaseModel):
    """Hits of one session that happen together. ``t``/``t_end`` span the members on the
    aligned clock; ``score`` = best member score + CORROBORATION_BONUS per other sense with a
    matching member; ``hits`` (time order) is every sense's evidence. ``position``/``frame``:
    where the best placed member happened (None when no member is placed)."""

    session: str
    t: float
    t_end: float
    score: float
    senses: list[str]
    best: str
    hits: list[Evidence]
    position: PlacePosition = None
    frame: PlaceFrame = None


class Occurrences(BaseModel):
    """Distinct occurrences of a query (``count == len(moments)``), in time order or in
    ``sort`` order (tactus_memory.search.ordering)."""

    query: str
    count: int
    capped: bool = Field(
        description="True when a sense returned MATCH_CANDIDATES candidates that all matched: "
        "the count is a lower bound (narrow with after/before)."
    )
    merge_gap: float
    moments: list[Moment]
    passed: int | None = Field(
        None,
        description="Occurrences past the match bar; the `count` answering ones score >= "
        "`answer` x the best of them (tactus_memory.matching).",
    )
    answer: float | None = Field(
        None, description="The answer ratio asked for (null: the per-sense defaults)."
    )
    sort: str | None = Field(
        None, description="The order of `moments` asked for (null: time order)."
    )


class Context(BaseModel):
    """What happened in ``window`` seconds before/after the anchor (same session)."""

    side: Side
    window: float
    anchor: Evidence
    t_from: float
    t_to: float
    items: list[TimelineItem]


class ClockOffset(BaseModel):
    """A stream's clock offset: its items are placed at ``t + offset`` on the session clock."""

    session: str
    sense: str
    source: str = ""
    offset: float


# --------------------------------------------------------------------------- places
class Place(BaseModel):
    """Where a moment matching a query happened (``memory.where``): the position and frame of
    its best placed member, the moment's aligned span, score and senses, and its evidence."""

    session: str
    position: Position
    frame: str
    t: float
    t_end: float
    score: float
    senses: list[str]
    best: str
    evidence: list[Evidence]


class TrajectoryOut(BaseModel):
    """One frame's poses of a session in time order: ``t: (N,)``, ``position: (N, 3)``,
    ``orientation: (N, 4)`` quaternions (x, y, z, w) or None when any pose has none."""

    session: str
    frame: str
    t: list[float]
    position: list[list[float]]
    orientation: list[list[float]] | None = None


class Episode(BaseModel):
    """One coherent stretch of one stream: ``t``/``t_end`` as stored, ``t_aligned`` /
    ``t_end_aligned`` on the session clock (plus the stream's clock offset)."""

    session: str
    sense: str
    source: str = ""
    episode: int
    t: float
    t_end: float
    t_aligned: float
    t_end_aligned: float
    n: int
    representative: str


#: what ``timeline`` answers: items, or with ``episodes=True`` episodes
Timeline = list[TimelineItem] | list[Episode]


def label_key(label: str) -> str:
    """Labels compare case-insensitively, spaces and underscores alike ("Screw driver")."""
    return " ".join(label.lower().replace("_", " ").split())


class Teaching(BaseModel):
    """One taught span: ``session``'s ``sense`` windows overlapping ``[t, t_end]`` held
    ``label``; ``windows`` is how many there were when it was taught."""

    model_config = ConfigDict(frozen=True)

    id: str
    label: str
    session: str
    sense: str
    t: float
    t_end: float
    windows: int = Field(description="Windows of the span when it was taught.")
    created: float

    def to_dict(self) -> dict[str, Any]:
        return self.model_dump()
