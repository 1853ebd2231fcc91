"""Request and response models of the temporal routes (pydantic; numbers finite)."""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict, Field

from tactus_memory.limits import MAX_CLOCK_OFFSET, MAX_ID_CHARS, SOURCE_PATTERN
from tactus_memory.limits import SENSE_NAME_PATTERN as SENSE_PATTERN
from tactus_memory.results import ClockOffset, Episode, Evidence, Moment, TimelineItem
from tactus_memory.service.schemas import Strict
from tactus_memory.temporal.episodes import EPISODE_MAX_GAP, EPISODE_MEAN_COS, EPISODE_MIN_COS


class MomentOut(BaseModel):
    """The occurrence found, or null when nothing matches."""

    moment: Moment | None


class MomentsOut(BaseModel):
    moments: list[Moment]


class ContextOut(BaseModel):
    """What happened before/after the anchor; ``anchor`` null when nothing matches it."""

    side: str
    window: float
    anchor: Evidence | None = None
    t_from: float | None = None
    t_to: float | None = None
    items: list[TimelineItem] = Field(default_factory=list)


class TimelineOut(BaseModel):
    session: str
    items: list[TimelineItem] | None = None
    episodes: list[Episode] | None = None


class ClockIn(Strict):
    model_config = ConfigDict(
        json_schema_extra={"examples": [{"sense": "touch", "source": "glove-l", "offset": 2.5}]},
    )

    sense: str = Field(pattern=SENSE_PATTERN)
    source: str = Field(
        "", max_length=MAX_ID_CHARS, pattern=SOURCE_PATTERN, description="Stream id ('' for none)."
    )
    offset: float = Field(
        ge=-MAX_CLOCK_OFFSET,
        le=MAX_CLOCK_OFFSET,
        description="Seconds added to the stream's t to put it on the session clock (0 clears).",
    )


class ClockOut(BaseModel):
    offsets: list[ClockOffset]


class SegmentIn(Strict):
    min_cos: float = Field(EPISODE_MIN_COS, ge=-1.0, le=1.0)
    mean_cos: float = Field(EPISODE_MEAN_COS, ge=-1.0, le=1.0)
    max_gap: float = Field(EPISODE_MAX_GAP, ge=0.0)


class SegmentOut(BaseModel):
    session: str
    episodes: int = Field(description="Episodes written.")
