"""Request and response models (pydantic). Numbers must be finite: NaN/inf are rejected."""

from __future__ import annotations

from typing import Annotated, Any

from pydantic import BaseModel, ConfigDict, Field, model_validator
from pydantic.json_schema import JsonDict

from tactus_memory.limits import (
    ID_DESCRIPTION,
    ID_PATTERN,
    MAX_COORDINATE,
    MAX_ID_CHARS,
    MAX_K,
    MAX_SECONDS,
    MAX_TEXT_CHARS,
    MAX_WINDOW_FRAMES,
    NAME_PATTERN,
    SOURCE_PATTERN,
)
from tactus_memory.limits import SENSE_NAME_PATTERN as SENSE_PATTERN
from tactus_memory.results import (
    Grasp,
    Hit,
    Moment,
    SenseInfo,
)
from tactus_memory.service.arrays import MAX_FRAME_VALUE
from tactus_memory.service.touch_senses import default_sense_class
from tactus_memory.times import Seconds
from tactus_memory.vectors import MAX_COMPONENT
from tactus_memory.where import DEFAULT_FRAME

#: vectors (and ids) in one JSON write request, far below the library's limits.MAX_BATCH:
#: 4,096 vectors of 384 floats are ~15 MB of JSON, about the default body limit
MAX_JSON_ITEMS = 4096
#: windows in one JSON touch batch (64 x K=8 frames is ~2.6 MB of JSON; send larger
#: batches as .npy, which has no such limit besides the body size)
MAX_JSON_WINDOWS = 64

#: (H, W) the frame the JSON schema states for a touch window: the default touch sense's,
#: the shipped checkpoint's STAG glove (32, 32), as its registered class states it
STATED_FRAME: tuple[int, ...] = default_sense_class().default_frame_shape
#: a valid raw STAG-like frame (values 500-690: a real dynamic range, never all-zero)
_ROWS, _COLS = STATED_FRAME
_FRAME_EXAMPLE: list[Any] = [
    [500.0 + (7 * r + 13 * c) % 191 for c in range(_COLS)] for r in range(_ROWS)
]
_FRAME_EXAMPLE_2: list[Any] = [
    [500.0 + (11 * r + 5 * c) % 187 for c in range(_COLS)] for r in range(_ROWS)
]


class Strict(BaseModel):
    """Base: unknown fields are errors, NaN/inf are errors, and types are strict: a JSON
    boolean is not a number (``t: false`` is a 422, not 0), a string is not a number."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False, strict=True)


Meta = dict[str, Any]
# The shape and float32 range are stated in the JSON schema here and enforced after parsing
# (service/arrays.py: as_window_array / as_float_array), whose 422 names the whole shape, e.g.
# "(8, 32, 31)", instead of listing up to 1,024 per-element errors.
#: one pressure value (service/arrays.py: MAX_FRAME_VALUE)
Value = Annotated[
    float, Field(json_schema_extra={"minimum": -MAX_FRAME_VALUE, "maximum": MAX_FRAME_VALUE})
]
#: one vector component (tactus_memory/vectors.py: MAX_COMPONENT)
Component = Annotated[
    float, Field(json_schema_extra={"minimum": -MAX_COMPONENT, "maximum": MAX_COMPONENT})
]
#: a vector: at least one component of magnitude >= 1e-11 (an all-zero vector has no
#: direction; tactus_memory/vectors.py refuses norms below 1e-12)
NONZERO: JsonDict = {"contains": {"anyOf": [{"minimum": 1e-11}, {"maximum": -1e-11}]}}
# The JSON schema states the default touch sense's frame, the 32x32 glove (STATED_FRAME); a
# touch sense of another sensor (`?sense=NAME`, `"sense"`) reads its own H x W (GET /senses:
# shape), which one schema cannot state per sense: the edge checks each window against its
# sense's shape (service/arrays.py), not against this schema.
#: (32,) one row of a glove frame
Row = Annotated[list[Value], Field(json_schema_extra={"minItems": _COLS, "maxItems": _COLS})]
#: (32, 32) one glove frame
Frame = Annotated[list[Row], Field(json_schema_extra={"minItems": _ROWS, "maxItems": _ROWS})]
#: (K, H, W) a window, 1 <= K <= MAX_WINDOW_FRAMES
Window = Annotated[list[Frame], Field(min_length=1, max_length=MAX_WINDOW_FRAMES)]
#: an item id (the store's rule)
ItemId = Annotated[str, Field(pattern=ID_PATTERN, max_length=MAX_ID_CHARS)]

#: (3,) a position (x, y, z) in metres and (4,) a unit quaternion (x, y, z, w), JSON arrays
Coordinate = Annotated[float, Field(ge=-MAX_COORDINATE, le=MAX_COORDINATE)]
Point = Annotated[list[Coordinate], Field(min_length=3, max_length=3)]
Quaternion = Annotated[list[Annotated[float, Field(ge=-1.001, le=1.001)]],
                       Field(min_length=4, max_length=4)]  # fmt: skip

T_DESC = (
    "Start time in seconds (any clock, e.g. Unix or seconds since session start), "
    f"|t| <= {MAX_SECONDS:g} (tactus_memory/times.py)."
)
T_END_DESC = "End time in seconds (>= t); defaults to t."


# ----------------------------------------------------------------------------- writes
class TouchWindowIn(Strict):
    """One touch window: K frames of H x W pressure (the touch sense's frame shape: 32x32 on
    the STAG glove), raw sensor units by default."""

    model_config = ConfigDict(
        json_schema_extra={
            "examples": [
                {
                    "frames": [_FRAME_EXAMPLE, _FRAME_EXAMPLE_2],
                    "t": 12.5,
                    "t_end": 13.6,
                    "meta": {"object": "mug"},
                    "calibrated": False,
                }
            ]
        }
    )

    frames: Window = Field(
        description="(K, H, W) pressure frames, H x W the touch sense's frame shape: the "
        "schema states the glove's 32x32; a touch sense named with ?sense=NAME reads its own "
        "(GET /senses: shape). RAW sensor units (e.g. 500-700 for the STAG glove) unless "
        "calibrated=true.",
    )
    t: Seconds = Field(description=T_DESC)
    t_end: Seconds | None = Field(None, description=T_END_DESC)
    meta: Meta | None = Field(None, description="Free JSON metadata stored with the window.")
    calibrated: bool = Field(
        False, description="true when frames are already calibrated (0-1); default raw units."
    )
    id: str | None = Field(None, pattern=ID_PATTERN, description="Item id. " + ID_DESCRIPTION)


class TouchBatchIn(Strict):
    """Several touch windows of one session, stored in one commit."""

    windows: list[Window] = Field(
        description="(B, K, H, W) windows (H x W as for `frames`), raw sensor units unless "
        "calibrated=true; every window of a batch has the same K (422 else).",
        min_length=1,
        max_length=MAX_JSON_WINDOWS,
    )
    t: list[Seconds] = Field(
        description="B start times (one per window).", min_length=1, max_length=MAX_JSON_WINDOWS
    )
    t_end: list[Seconds] | None = Field(None, description="B end times (default: t).")
    meta: Meta | list[Meta] | None = Field(
        None, description="One metadata object for all, or one per window."
    )
    calibrated: bool = False
    ids: list[ItemId] | None = Field(
        None,
        description="B item ids (default: generated), all different.",
        min_length=1,
        max_length=MAX_JSON_ITEMS,
        json_schema_extra={"uniqueItems": True},
    )


class TextIn(Strict):
    model_config = ConfigDict(
        json_schema_extra={
            "examples": [
                {"text": "the mug was hot and slippery", "t": 12.5, "meta": {"speaker": "operator"}}
            ]
        }
    )

    text: str = Field(min_length=1, max_length=MAX_TEXT_CHARS, description="A note or caption.")
    t: Seconds = Field(description=T_DESC)
    t_end: Seconds | None = Field(None, description=T_END_DESC)
    meta: Meta | None = None
    id: str | None = Field(None, pattern=ID_PATTERN, description="Item id. " + ID_DESCRIPTION)
    position: Point | None = Field(
        None, description="Where it happened (x, y, z) in `frame` (default: from the poses)."
    )
    frame: str = Field(DEFAULT_FRAME, pattern=ID_PATTERN, description="The frame of `position`.")


class VectorsIn(Strict):
    """Precomputed embeddings of a registered sense (e.g. an IMU motion encoder's output)."""

    model_config = ConfigDict(
        json_schema_extra={
            # the example vector has the space's dimension: set per app (service/openapi.py)
        }
    )

    sense: str = Field(
        pattern=SENSE_PATTERN,
        description="A registered vector sense (POST /senses); text, touch and image take "
        "their raw input on their own routes (422 here).",
        json_schema_extra={"not": {"enum": ["text", "touch", "image"]}},
    )
    vectors: list[Annotated[list[Component], Field(min_length=1, json_schema_extra=NONZERO)]] = (
        Field(
            min_length=1,
            max_length=MAX_JSON_ITEMS,
            description="(N, D) vectors, D = the space's dim.",
        )
    )
    t: list[Seconds] = Field(
        min_length=1, max_length=MAX_JSON_ITEMS, description="One start time per vector (422 else)."
    )
    t_end: list[Seconds] | None = Field(None, description="One end time (>= t) per vector.")
    meta: Meta | list[Meta] | None = None
    ids: list[ItemId] | None = Field(
        None, min_length=1, max_length=MAX_JSON_ITEMS, json_schema_extra={"uniqueItems": True}
    )


class SenseIn(Strict):
    """Register a VectorSense: precomputed vectors from an external encoder."""

    model_config = ConfigDict(
        json_schema_extra={
            "examples": [{"name": "motion", "dim": 384, "encoder": "imu-tcn", "version": "1.2"}]
        }
    )

    name: str = Field(pattern=SENSE_PATTERN, description="1-32 chars of [a-z0-9_].")
    dim: int = Field(ge=1, le=65536, description="Vector dimension; must equal the space's.")
    # names a person reads (GET /senses): no control or format characters (issue 48)
    space: str | None = Field(
        None, max_length=128, pattern=NAME_PATTERN, description="Space the encoder targets."
    )
    encoder: str = Field("external", max_length=256, pattern=NAME_PATTERN)
    version: str = Field("", max_length=128, pattern=NAME_PATTERN)
    checkpoint_sha256: str = Field("", max_length=128)


class SkippedOut(BaseModel):
    index: int = Field(description="The item's index in the request.")
    reason: str = Field(description="`idle`: a touch window with no contact, not stored.")


class StoredOut(BaseModel):
    model_config = ConfigDict(
        json_schema_extra={
            "examples": [
                {"ids": ["a1b2c3"], "count": 1, "skipped": [{"index": 1, "reason": "idle"}]}
            ]
        }
    )

    ids: list[str] = Field(description="Ids of the stored items, in input order.")
    count: int
    skipped: list[SkippedOut] = Field(
        default_factory=list,
        description="Items of a batch skipped, not stored (an idle touch window), by index.",
    )


# ----------------------------------------------------------------------------- reads
class HitOut(Hit):
    """A search hit as the service sends it (:class:`tactus_memory.results.Hit`)."""

    score: float = Field(description="Calibrated score (comparable across senses).")
    # null where a hit has no cosine of its own (the library's Hit always has one)
    cosine: float | None = Field(None, description="Raw cosine similarity.")  # type: ignore[assignment]
    meta: Meta = Field(default_factory=dict)
    text: str | None = Field(None, description="The stored text, for text items.")
    source: str = Field("", description="The stream the item came from, if any.")


class SearchOut(BaseModel):
    model_config = ConfigDict(
        json_schema_extra={
            "examples": [
                {
                    "hits": [
                        {
                            "id": "a1b2c3",
                            "session": "kitchen",
                            "sense": "touch",
                            "t": 12.5,
                            "t_end": 13.6,
                            "score": 2.1,
                            "cosine": 0.41,
                            "meta": {},
                        }
                    ]
                }
            ]
        }
    )

    hits: list[HitOut]
    moments: list[Moment] | None = Field(
        None,
        description="With group=moment: hits grouped into moments, each carrying every sense's "
        "evidence (hits then holds each moment's best member, in moment order).",
    )
    grasps: list[Grasp] | None = Field(
        None,
        description="With group=grasp: one entry per grasp, best first (its member ids, span and "
        "pooled score; hits then holds the same grasps as hits).",
    )


class SearchLikeIn(Strict):
    """Find moments similar to an example: a touch window, a vector, or a text."""

    model_config = ConfigDict(
        json_schema_extra={
            "examples": [
                {"sense": "touch", "frames": [_FRAME_EXAMPLE, _FRAME_EXAMPLE_2], "k": 5},
                {"sense": "text", "text": "holding a mug", "k": 5},
            ],
            # exactly one of frames (a touch window: the glove's 'touch' as the schema states
            # it; another touch sense's window is its own H x W), vector (any sense) or text
            # (sense 'text'): what _one_example and the senses enforce
            "oneOf": [
                {"required": ["frames"], "properties": {"sense": {"const": "touch"}}},
                {"required": ["vector"]},
                {"required": ["text"], "properties": {"sense": {"const": "text"}}},
            ],
        }
    )

    sense: str = Field(pattern=SENSE_PATTERN, description="The sense of the example.")
    frames: Window | None = Field(
        None,
        description="A (K, H, W) touch window of the touch sense `sense`: the schema states "
        "the glove's 32x32, another touch sense's window is its own H x W (GET /senses).",
    )
    vector: list[Component] | None = Field(
        None, description="A vector of that sense (dim D).", min_length=1, json_schema_extra=NONZERO
    )
    text: str | None = Field(None, min_length=1, max_length=MAX_TEXT_CHARS)
    calibrated: bool = False
    k: int = Field(10, ge=1, le=MAX_K)
    senses: list[str] | None = Field(None, description="Search these senses (default: sense).")
    session: str | None = Field(None, pattern=ID_PATTERN)
    source: str | None = Field(
        None, max_length=MAX_ID_CHARS, pattern=SOURCE_PATTERN, description="Only this stream."
    )
    after: Seconds | None = Field(None, description="Only items at or after; <= before (422).")
    before: Seconds | None = Field(None, description="Only items at or before; >= after (422).")

    @model_validator(mode="after")
    def _one_example(self) -> SearchLikeIn:
        given = [n for n in ("frames", "vector", "text") if getattr(self, n) is not None]
        if len(given) != 1:
            raise ValueError(
                "give exactly one example: 'frames', 'vector' or 'text' "
                f"(got {', '.join(given) or 'none'})"
            )
        return self


class SenseOut(SenseInfo):
    """A registered sense as the service sends it (:class:`tactus_memory.results.SenseInfo`)."""


class SensesOut(BaseModel):
    senses: list[SenseOut]


class SessionOut(BaseModel):
    model_config = ConfigDict(
        json_schema_extra={
            "examples": [
                {
                    "id": "kitchen",
                    "n": 42,
                    "counts": {"touch": 40, "text": 2},
                    "t_min": 0.0,
                    "t_max": 61.2,
                }
            ]
        }
    )

    id: str
    n: int = Field(description="Items stored in the session.")
    counts: dict[str, int] = Field(default_factory=dict, description="Items per sense.")
    t_min: float = Field(description="Earliest t.")
    t_max: float = Field(description="Latest t_end.")


class SessionsOut(BaseModel):
    sessions: list[SessionOut]


class DeletedOut(BaseModel):
    id: str
    deleted: int = Field(description="Items removed.")
    clock_offsets: int = Field(0, description="Clock offsets removed.")


class HealthOut(BaseModel):
    status: str = "ok"
    version: str
    space: dict[str, Any]
    senses: list[str]
    touch: bool
    touch_unavailable: str | None = None
    read_only: bool = Field(False, description="The store cannot be written: writes get 503.")


class MaintenancePassOut(BaseModel):
    """One maintenance pass this process ran (compaction, retention, cleanup scheduling)."""

    start: float = Field(description="Unix time the pass started.")
    end: float = Field(description="Unix time the pass ended.")
    pid: int = Field(description="The process that ran it.")
    by: str = Field(description="Who that process is (e.g. 'worker 0'; empty: a lone server).")


class RetentionOut(BaseModel):
    """The store's retention policy and what maintenance did with it (README "Retention and
    deletion"): counts of the last pass and since this process started; none where another
    process maintains."""

    retain_days: float | None = Field(description="Store-wide expiry (null: keep forever).")
    thin_after_days: float | None = Field(description="Store-wide thinning age (null: off).")
    thin_cosine: float = Field(description="Thinning's cosine bar.")
    erase_deleted: bool = Field(description="Compaction rewrites every fragment with deletes.")
    retain_seconds: float = Field(description="Old versions (deleted data) kept this long.")
    rules: int = Field(description="Rules per tenant, session or sense.")
    maintained_here: bool = Field(description="This process runs maintenance.")
    worker: int | None = Field(
        None,
        description="The worker of `tactus serve --workers N` that answered (only worker 0 "
        "maintains); null: a single server process.",
    )
    expired: int = Field(description="Items the last pass expired.")
    thinned: int = Field(description="Items the last pass thinned.")
    expired_total: int = Field(description="Items expired by this process.")
    thinned_total: int = Field(description="Items thinned by this process.")
    groups_thinned: int = Field(
        description="(session, sense, source) groups the last pass thinned."
    )
    last_run: float | None = Field(description="Unix time of the last retention pass.")
    seconds: float = Field(description="How long the last pass took.")
    erasure_pending: bool | None = Field(
        description="Rows this process deleted may still be in the files (null: another "
        "process maintains the store, ask it: `tactus maintain`)."
    )
    passes: list[MaintenancePassOut] = Field(
        default_factory=list,
        description="This process's latest maintenance passes, oldest first (none where "
        "another process maintains): with `--workers N` only worker 0's, never overlapping.",
    )


class LiveOut(BaseModel):
    status: str = "ok"


class ReadyOut(BaseModel):
    status: str = "ready"
    read_only: bool = False
