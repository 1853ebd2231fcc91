"""Request and response models of the place routes (``routers/places.py``): poses in,
trajectories, ``where`` and ``at`` out. Numbers must be finite, as in ``schemas.py``."""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict, Field

from tactus_memory.limits import ID_PATTERN, MAX_ID_CHARS, SOURCE_PATTERN
from tactus_memory.results import Place, Position, TimelineItem, TrajectoryOut
from tactus_memory.service.schemas import Point, Quaternion, Strict
from tactus_memory.storage.places import MAX_POSES
from tactus_memory.times import Seconds
from tactus_memory.where import DEFAULT_FRAME


class PosesIn(Strict):
    """A batch of a session's poses: N strictly increasing times on the session clock."""

    model_config = ConfigDict(
        json_schema_extra={
            "examples": [
                {
                    "t": [0.0, 0.1, 0.2],
                    "position": [[0.0, 0.0, 0.0], [0.1, 0.0, 0.0], [0.2, 0.0, 0.0]],
                    "orientation": [[0.0, 0.0, 0.0, 1.0]] * 3,
                    "frame": "map",
                    "source": "odom",
                }
            ]
        }
    )

    t: list[Seconds] = Field(min_length=1, max_length=MAX_POSES, description="(N,) seconds.")
    position: list[Point] = Field(
        min_length=1, max_length=MAX_POSES, description="(N, 3) metres in `frame`."
    )
    orientation: list[Quaternion] | None = Field(
        None, max_length=MAX_POSES, description="(N, 4) unit quaternions (x, y, z, w)."
    )
    frame: str = Field(DEFAULT_FRAME, pattern=ID_PATTERN, description="e.g. map, odom.")
    source: str = Field("", max_length=MAX_ID_CHARS, pattern=SOURCE_PATTERN)


class PosesStoredOut(BaseModel):
    session: str
    count: int = Field(description="Poses stored.")


class TrajectoriesOut(BaseModel):
    session: str
    trajectories: list[TrajectoryOut]


class PlacesOut(BaseModel):
    """Where moments matching the query happened, best first."""

    query: str
    places: list[Place]


class AtOut(BaseModel):
    """What happened within `r` of (x, y, z), in time order."""

    position: Position
    radius: float
    items: list[TimelineItem]
