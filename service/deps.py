"""Dependencies shared by the routers (``Annotated`` aliases, FastAPI style). They take an
``HTTPConnection``, so the WebSocket route declares the same ones as the HTTP routes (a
failure refuses the socket with the same problem, see ``problems.py``)."""

from __future__ import annotations

import asyncio
import hmac
from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Annotated, Any, Literal

from fastapi import Depends, HTTPException, Path, Query
from starlette.requests import HTTPConnection
from typing_extensions import Unpack

from tactus_memory.encode_process import EncoderProcess
from tactus_memory.errors import InvalidInputError
from tactus_memory.group_commit import GroupCommitter

# the library's rules, checked at the edge (one home: tactus_memory.limits)
from tactus_memory.limits import (
    FRAME_PATTERN,
    ID_DESCRIPTION,
    ID_PATTERN,
    MAX_ID_CHARS,
    MAX_TEXT_CHARS,
    NEAR_PATTERN,
    SENSE_NAME_PATTERN,
    SOURCE_PATTERN,
)
from tactus_memory.memory import Memory
from tactus_memory.search.query import Scope
from tactus_memory.service.problems import ServiceUnavailable
from tactus_memory.service.writes import WriteThreads
from tactus_memory.settings import Settings
from tactus_memory.storage.rows import WriteKwargs
from tactus_memory.storage.where import Near, check_near, validate_frame


@dataclass
class ServiceState:
    """What the app holds: the settings, the memory, and why touch is off (if it is)."""

    settings: Settings
    memory: Memory
    touch_unavailable: str | None = None
    write_threads: WriteThreads | None = None
    committer: GroupCommitter | None = None
    #: the store's directory cannot be written: write routes answer 503 (reads still work)
    read_only: bool = False
    #: the space has been warmed up (the lifespan ran): ``/ready`` answers 200
    warm: bool = False
    #: the step being loaded while ``tactus serve`` starts (socket open, models loading in
    #: the background): probes say it, other routes answer 503 naming it; None when loaded
    starting: str | None = None
    #: what loading the models in the background raised (the server then stops)
    load_error: BaseException | None = None

    def __post_init__(self) -> None:
        if self.write_threads is None:
            self.write_threads = WriteThreads(self.settings.write_threads)

    def open_committer(self) -> GroupCommitter:
        """The running group committer (a new one after a shutdown closed the last)."""
        if self.committer is None or self.committer.closed:
            encoder = None
            if self.settings.encode_process:
                encoder = EncoderProcess(
                    ("touch",), nice=self.settings.commit_nice, threads=self.settings.torch_threads
                )
            self.committer = GroupCommitter(
                self.memory,
                tick=self.settings.commit_tick_ms / 1000.0,
                max_batch=self.settings.commit_max_batch,
                max_pending=self.settings.commit_max_pending,
                # torch threads; an ONNX server never imports torch
                encode_threads=None if self.settings.onnx else self.settings.torch_threads,
                nice=self.settings.commit_nice,
                encoder=encoder,
            )
        return self.committer

    async def write(
        self, session: str, sense: str, items: Sequence[Any], **kw: Unpack[WriteKwargs]
    ) -> list[str]:
        """Every HTTP write: the one library call, ``GroupCommitter.submit`` (the sense
        validates the items, the write is queued), run on the writer threads; returns the ids
        once the group commit stored them (OverloadedError at once when the queue is full:
        503 + Retry-After)."""
        assert self.write_threads is not None
        queued = await self.write_threads.run(
            self.open_committer().submit, session, sense, items, **kw
        )
        return await asyncio.wrap_future(queued)


def get_state(conn: HTTPConnection) -> ServiceState:
    return conn.app.state.tactus


def get_settings(state: Annotated[ServiceState, Depends(get_state)]) -> Settings:
    return state.settings


def get_memory(state: Annotated[ServiceState, Depends(get_state)]) -> Memory:
    return state.memory


def get_write_threads(state: Annotated[ServiceState, Depends(get_state)]) -> WriteThreads:
    return state.write_threads


StateDep = Annotated[ServiceState, Depends(get_state)]
WriteThreadsDep = Annotated[WriteThreads, Depends(get_write_threads)]
SettingsDep = Annotated[Settings, Depends(get_settings)]
#: the ``tactus_memory.memory.Memory`` behind the app
MemoryDep = Annotated[Memory, Depends(get_memory)]
SessionId = Annotated[
    str,
    Path(
        pattern=ID_PATTERN,
        max_length=MAX_ID_CHARS,
        description="Session id. " + ID_DESCRIPTION,
        examples=["kitchen-2026-11-21"],
    ),
]
ItemIdPath = Annotated[
    str,
    Path(pattern=ID_PATTERN, max_length=MAX_ID_CHARS, description="Item id. " + ID_DESCRIPTION),
]


#: the routes no token guards (README "Trust"): probes, the static page, the API docs
OPEN_PATHS = frozenset(
    {"/live", "/health", "/ready", "/", "/openapi.json", "/docs", "/docs/oauth2-redirect", "/redoc"}
)
OPEN_PREFIXES = ("/static/",)


def token_ok(settings: Settings, presented: str | None) -> bool:
    """Constant-time check of a presented token (True when no token is configured)."""
    if settings.token is None:
        return True
    if not presented:
        return False
    expected = settings.token.get_secret_value().encode()
    return hmac.compare_digest(presented.encode(), expected)


def bearer(authorization: str | None) -> str | None:
    if not authorization:
        return None
    scheme, _, value = authorization.partition(" ")
    if scheme.lower() != "bearer" or not value.strip():
        return None
    return value.strip()


#: the 401's detail and challenge, for the API routes and the MCP endpoint (service/mcp_http.py)
TOKEN_REFUSED = "missing or wrong bearer token: send 'Authorization: Bearer <token>'"
BEARER_CHALLENGE = {"WWW-Authenticate": 'Bearer realm="tactus"'}


def require_token(conn: HTTPConnection, settings: SettingsDep) -> None:
    """Every route but the open ones: ``Authorization: Bearer <token>`` when a token is set
    (a WebSocket may pass ``?token=`` instead: browsers cannot set its headers)."""
    if settings.token is None:
        return
    presented = bearer(conn.headers.get("authorization"))
    websocket = conn.scope["type"] == "websocket"
    if websocket and presented is None:
        presented = conn.query_params.get("token")
    if not token_ok(settings, presented):
        how = " or ?token=" if websocket else ""
        raise HTTPException(401, TOKEN_REFUSED + how, headers=BEARER_CHALLENGE)


def require_writable(state: StateDep) -> None:
    """Writes outside the HTTP write methods (a WebSocket stream) on a read-only store: 503
    (HTTP writes are refused by ``middleware.ReadOnlyMiddleware``, before their body)."""
    if state.read_only:
        raise ServiceUnavailable("the store is read-only: writes are refused")


def require_touch(state: StateDep) -> None:
    """Touch routes answer 503 when no touch sense is registered, naming why."""
    memory = state.memory
    if "touch" not in memory.senses:
        why = state.touch_unavailable or "no sense named 'touch' is registered in this memory"
        raise ServiceUnavailable(f"touch is not available on this server: {why}")


Authorized = Depends(require_token)
TouchAvailable = Depends(require_touch)
Writable = Depends(require_writable)


# --------------------------------------------------------------------------- the scope
QueryText = Annotated[
    str,
    Query(
        description="The query in words.",
        examples=["holding a warm mug"],
        min_length=1,
        max_length=MAX_TEXT_CHARS,
    ),
]
SensesQ = Annotated[
    list[str] | None,
    Query(
        description="Restrict to these senses (repeat the parameter).",
        json_schema_extra={"items": {"type": "string", "pattern": SENSE_NAME_PATTERN}},
    ),
]
SessionQ = Annotated[str | None, Query(pattern=ID_PATTERN, max_length=MAX_ID_CHARS)]
SourceQ = Annotated[
    str | None,
    Query(
        max_length=MAX_ID_CHARS,
        pattern=SOURCE_PATTERN,
        description="Only this stream (source id; '' for none).",
    ),
]
AfterQ = Annotated[
    float | None,
    Query(description="Items still going on at or after (aligned); must be <= before (422)."),
]
BeforeQ = Annotated[
    float | None,
    Query(description="Items started at or before (aligned); must be >= after (422)."),
]


NearQ = Annotated[
    str | None,
    Query(
        max_length=100,
        pattern=NEAR_PATTERN,
        description="Only items placed within r metres of (x, y, z): `near=x,y,z,r` (r > 0).",
        examples=["2.0,0.5,0,1.5"],
    ),
]
FrameQ = Annotated[
    str | None,
    Query(
        max_length=MAX_ID_CHARS + 1,
        pattern=FRAME_PATTERN,
        description="Only items placed in this frame (e.g. `map`).",
    ),
]


def parse_near(near: str | None) -> Near | None:
    """``"x,y,z,r"`` -> ``((x, y, z), r)`` (checked by the library: finite, r > 0)."""
    if near is None:
        return None
    parts = near.split(",")
    if len(parts) != 4:
        raise InvalidInputError(f"near must be 'x,y,z,r' (four numbers), got {near!r}")
    try:
        x, y, z, r = (float(p) for p in parts)
    except ValueError:
        raise InvalidInputError(f"near must be 'x,y,z,r' (four numbers), got {near!r}") from None
    return check_near(((x, y, z), r))


def stream_scope(
    sense: SensesQ = None,
    source: SourceQ = None,
    after: AfterQ = None,
    before: BeforeQ = None,
    near: NearQ = None,
    frame: FrameQ = None,
) -> Scope:
    """The scope's query parameters but the session (a route with the session in its path)."""
    return Scope(
        senses=sense,
        source=source,
        after=after,
        before=before,
        near=parse_near(near),
        frame=None if frame is None else validate_frame(frame),
    )


def scope(base: Annotated[Scope, Depends(stream_scope)], session: SessionQ = None) -> Scope:
    """``sense`` (repeated), ``session``, ``source``, ``after``, ``before``, ``near``,
    ``frame`` -> one
    :class:`~tactus_memory.search.query.Scope`, what every search and temporal route passes down."""
    return replace(base, session=session)


ScopeDep = Annotated[Scope, Depends(scope)]
StreamScopeDep = Annotated[Scope, Depends(stream_scope)]


#: how group=grasp scores a grasp (tactus_memory.temporal.grasps.POOLS)
GraspPool = Annotated[
    Literal["mean", "top", "max"],
    Query(
        description="With group=grasp: `mean` scores the pooled vector of every window of the "
        "grasp, `top` of its 3 windows closest to the query, `max` its best window."
    ),
]
