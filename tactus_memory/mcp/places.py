"""The place and grouping arguments of the MCP tools, and the two place tools.

As the HTTP API has them (``service/routers/search.py``, ``temporal.py``, ``places.py``):

* ``near``: ``[x, y, z, r]``, only items placed within ``r`` metres of ``(x, y, z)`` (HTTP's
  ``near=x,y,z,r``; unplaced items never match); ``frame``: only items placed in that frame;
* ``group`` on ``search`` (``auto`` / ``window`` / ``moment`` / ``grasp``) and on ``last`` /
  ``first`` / ``count`` (``auto`` / ``window`` / ``grasp``), the same library calls;
* ``where`` (HTTP ``GET /where``: ``memory.where``) and ``at`` (HTTP ``GET /at``:
  ``memory.at``).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, replace
from typing import Annotated, Any, Literal

from mcp.types import CallToolResult
from pydantic import BaseModel, Field

from tactus_memory.errors import InvalidInputError
from tactus_memory.limits import ID_PATTERN, MAX_COORDINATE, MAX_ID_CHARS
from tactus_memory.mcp.args import (
    MAX_TOOL_ITEMS,
    MAX_TOOL_K,
    AfterArg,
    BeforeArg,
    Number,
    QueryArg,
    SensesArg,
    SessionArg,
    compact,
)
from tactus_memory.mcp.hits import Compactor, Found, MomentResult, moment_fields
from tactus_memory.memory.main import Memory
from tactus_memory.query import Scope
from tactus_memory.results import Place
from tactus_memory.search.grasps import windows_group
from tactus_memory.signatures import grouped
from tactus_memory.where import Near, check_near, check_regions

#: a coordinate (m), bounded as HTTP's (``limits.MAX_COORDINATE``)
Coordinate = Annotated[Number, Field(ge=-MAX_COORDINATE, le=MAX_COORDINATE)]

NearArg = Annotated[
    Annotated[list[Number], Field(min_length=4, max_length=4)] | None,
    Field(
        description="Only items placed within r metres of (x, y, z), given as [x, y, z, r] "
        "(r > 0; HTTP's near=x,y,z,r). Items with no place never match."
    ),
]
FrameArg = Annotated[
    str | None,
    Field(
        pattern=ID_PATTERN,
        max_length=MAX_ID_CHARS,
        description="Only items placed in this frame (e.g. 'map').",
    ),
]
SearchGroup = Literal["auto", "window", "moment", "grasp"]
QuestionGroup = Literal["auto", "window", "grasp"]
SearchGroupArg = Annotated[
    SearchGroup | None,
    Field(
        description="'auto' (default): a touch answer is a grasp (a hold's contiguous windows, "
        "scored together), other senses one hit per item; 'window': one hit per stored item; "
        "'moment': hits close in time merged into moments across senses (listed in "
        "`moments`); 'grasp': one hit per grasp of every sense. As HTTP's group=."
    ),
]
QuestionGroupArg = Annotated[
    QuestionGroup | None,
    Field(
        description="'auto' (default): touch is asked of grasps, other senses of items; "
        "'window': of items everywhere; 'grasp': of grasps for every sense. As HTTP's group=."
    ),
]


def near_of(near: list[float] | None) -> Near | None:
    """``[x, y, z, r]`` -> the library's ``((x, y, z), r)`` (checked: r > 0, finite)."""
    if near is None:
        return None
    x, y, z, r = near
    return check_near(((x, y, z), r))


def scope_of(
    session: str | None,
    senses: list[str] | None,
    after: float | None,
    before: float | None,
    near: list[float] | None = None,
    frame: str | None = None,
) -> Scope:
    """The scope arguments of a tool -> the library's one :class:`Scope` (``near``:
    ``[x, y, z, r]``, :func:`near_of`)."""
    return Scope(
        session=session, senses=senses, after=after, before=before, near=near_of(near), frame=frame
    )


@dataclass(frozen=True)
class Within:
    """``session``, ``senses``, ``after``, ``before``: which items a tool reads, one group of
    arguments (:func:`tactus_memory.signatures.grouped`; ``search``, ``where``, ``at``)."""

    session: SessionArg = None
    senses: SensesArg = None
    after: AfterArg = None
    before: BeforeArg = None

    def scope(self, near: list[float] | None = None, frame: str | None = None) -> Scope:
        return scope_of(self.session, self.senses, self.after, self.before, near, frame)

    def keywords(self) -> dict[str, Any]:
        """As the library's keywords (``memory.at(..., **within.keywords())``)."""
        return asdict(self)


@dataclass(frozen=True)
class TouchFilters:
    """``force_min``, ``force_max``, ``area_min``, ``regions``, ``grip``, ``sort``: the touch
    facet filters and order of ``search``, ``last``, ``first`` and ``count``, one group of
    arguments."""

    force_min: Annotated[
        Number | None, Field(description="Touch only: force (sum of the taxels) >= this.")
    ] = None
    force_max: Annotated[Number | None, Field(description="Touch only: force <= this.")] = None
    area_min: Annotated[
        Number | None,
        Field(ge=0, le=1, description="Touch only: contact area (share of the taxels) >= this."),
    ] = None
    regions: Annotated[
        str | None,
        Field(max_length=400, description="Touch only: these regions active, e.g. 'thumb,index'."),
    ] = None
    grip: Annotated[
        Literal["none", "power", "press", "pinch", "tripod", "other"] | None,
        Field(description="Touch only: this grip."),
    ] = None
    sort: Annotated[
        Literal["force", "-force", "area", "-area", "t", "-t"] | None,
        Field(description="Order by a touch facet or time ('-force': the firmest first)."),
    ] = None

    def scope(self, base: Scope) -> Scope:
        return replace(
            base,
            force_min=self.force_min,
            force_max=self.force_max,
            area_min=self.area_min,
            regions=check_regions(self.regions),
            grip=self.grip,
        )


def group_of(group: str | None, windows: bool) -> str:
    """The ``group`` argument, or the older ``windows`` flag's; both given must agree."""
    if group is None:
        return windows_group(windows)
    if windows and group != "window":
        raise InvalidInputError(
            f"windows: true asks for single windows, group {group!r} for something else: "
            "give one of them"
        )
    return group


class PlaceFound(MomentResult):
    """Where a moment matching the query happened: the moment and its best placed member's
    position."""

    position: tuple[float, float, float] = Field(description="(x, y, z), metres, in `frame`.")
    frame: str


class WhereResult(BaseModel):
    """``where``: the places, best first (moments with no placed member are left out)."""

    query: str
    places: list[PlaceFound]


class AtResult(BaseModel):
    """``at``: what happened within ``radius`` metres of ``position``, in time order."""

    position: tuple[float, float, float]
    radius: float
    items: list[Found]


def place_found(place: Place, items: list[Found]) -> PlaceFound:
    """A library :class:`~tactus_memory.results.Place` -> :class:`PlaceFound`."""
    x, y, z = (round(float(c), 4) for c in place.position)
    return PlaceFound(position=(x, y, z), frame=place.frame, **moment_fields(place, items))


class PlaceTools:
    """The ``where`` and ``at`` tools (mixed into ``server.MemoryTools``, which gives
    ``memory``, ``compactor`` and ``_known`` and turns library errors into tool errors)."""

    memory: Memory
    compactor: Compactor

    def _known(self, session: str | None) -> None:  # pragma: no cover - MemoryTools's
        raise NotImplementedError

    @grouped(within=Within)
    def where(
        self,
        query: QueryArg,
        k: Annotated[int, Field(ge=1, le=MAX_TOOL_K, description="How many places.")] = 5,
        within: Within = Within(),
        near: NearArg = None,
        frame: FrameArg = None,
    ) -> CallToolResult:
        """Where did this happen? The places of the moments that match, best first: each
        with its position (x, y, z in metres) and frame, its span, score and evidence (as
        HTTP's GET /where). Moments with no placed item are left out."""
        self._known(within.session)
        places = self.memory.where(query, k, scope=within.scope(near, frame))
        out = [place_found(p, self.compactor.items(p.evidence)) for p in places]
        return compact(WhereResult(query=query, places=out))

    @grouped(within=Within)
    def at(
        self,
        x: Annotated[Coordinate, Field(description="x (m).")],
        y: Annotated[Coordinate, Field(description="y (m).")],
        z: Annotated[Coordinate, Field(description="z (m).")],
        r: Annotated[Number, Field(gt=0.0, le=MAX_COORDINATE, description="Radius (m).")],
        within: Within = Within(),
        frame: FrameArg = None,
        limit: Annotated[
            int, Field(ge=1, le=MAX_TOOL_ITEMS, description="Most items returned.")
        ] = 50,
    ) -> CallToolResult:
        """What happened near a place? The items placed within r metres of (x, y, z), in
        time order (as HTTP's GET /at)."""
        self._known(within.session)
        items = self.memory.at((x, y, z), r, frame=frame, **within.keywords())
        result = AtResult(position=(x, y, z), radius=r, items=self.compactor.items(items[:limit]))
        return compact(result)
