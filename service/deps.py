"""Dependencies shared by the routers (``Annotated`` aliases, FastAPI style). They take an
``HTTPConnection``, so the WebSocket route declares the same ones as the HTTP routes (a
failure refuses the socket with the same problem, see ``problems.py``)."""

from __future__ import annotations

import asyncio
from collections.abc import Callable, Sequence
from concurrent.futures import Future
from dataclasses import dataclass, replace
from typing import Annotated, Any, Literal

from fastapi import Depends, HTTPException, Path, Query
from starlette.concurrency import run_in_threadpool
from starlette.requests import HTTPConnection
from typing_extensions import Unpack

from tactus_memory.batches import WriteKwargs
from tactus_memory.errors import InvalidInputError, NotFoundError, UnknownTenantError
from tactus_memory.identity import DEFAULT_TENANT

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
from tactus_memory.memory.group_commit import GroupCommitter
from tactus_memory.memory.main import Memory
from tactus_memory.query import Scope
from tactus_memory.service.auth import OPEN, Gate, Principal, declared_scope, needs
from tactus_memory.service.problems import ServiceUnavailable
from tactus_memory.service.tenancy import Tenant, Tenants
from tactus_memory.service.write_threads import WriteThreads
from tactus_memory.settings import Settings
from tactus_memory.storage.audit import AuditLog
from tactus_memory.storage.keys import allows
from tactus_memory.times import Seconds
from tactus_memory.where import (
    REGIONS_PATTERN,
    SESSION_PREFIX,
    Near,
    check_near,
    check_regions,
    session_visible,
    validate_frame,
)


@dataclass
class ServiceState:
    """What the app holds: the settings, the default tenant's memory, the other tenants'
    (``tenancy.Tenants``), the gate (``auth.Gate``), the audit log, and why touch is off."""

    settings: Settings
    memory: Memory
    touch_unavailable: str | None = None
    write_threads: WriteThreads | None = None
    #: the tenants' memories and committers (built from ``memory``, the default tenant's)
    tenants: Tenants | None = None
    #: who may ask: the operator's token and the store's keys
    gate: Gate | None = None
    #: where writes, deletes and key changes are logged (None: not logged)
    audit: AuditLog | None = None
    #: the store's directory cannot be written: write routes answer 503 (reads still work)
    read_only: bool = False
    #: the space has been warmed up (the lifespan ran): ``/ready`` answers 200
    warm: bool = False
    #: the step being loaded while ``tactus serve`` starts (socket open, models loading in
    #: the background): probes say it, other routes answer 503 naming it; None when loaded
    starting: str | None = None
    #: what loading the models in the background raised (the server then stops)
    load_error: BaseException | None = None
    #: ``tactus serve --workers N``: this worker's group (``cli.workers.Workers``); /ready
    #: answers 200 only while every worker is ready. None: one process.
    workers: Any = None

    def __post_init__(self) -> None:
        if self.write_threads is None:
            self.write_threads = WriteThreads(self.settings.write_threads)
        if self.gate is None:
            self.gate = Gate(self.settings, None)
        if self.tenants is None:
            self.tenants = Tenants(self.memory, self.settings, self.key_tenants)

    def key_tenants(self) -> set[str]:
        """The tenants the store's keys name (they exist, data or not)."""
        keys = self.gate.keys if self.gate is not None else None
        return set() if keys is None else keys.tenants()

    @property
    def committer(self) -> GroupCommitter | None:
        """The default tenant's group committer (each tenant has its own, ``Tenant``)."""
        assert self.tenants is not None
        return self.tenants.get(DEFAULT_TENANT).committer

    async def write(
        self,
        tenant: Tenant,
        session: str,
        sense: str,
        items: Sequence[Any],
        **kw: Unpack[WriteKwargs],
    ) -> list[str]:
        """Every HTTP write: the one library call, ``GroupCommitter.submit`` of the caller's
        tenant (the sense validates the items, the write is queued), run on the writer
        threads; returns the ids once the group commit stored them (OverloadedError at once
        when the queue is full: 503 + Retry-After)."""
        assert self.write_threads is not None
        queued = await self.write_threads.run(
            tenant.open_committer().submit, session, sense, items, **kw
        )
        return await asyncio.wrap_future(queued)

    async def write_body(
        self,
        tenant: Tenant,
        session: str,
        sense: str,
        parse: Callable[[], tuple[Any, WriteKwargs]],
    ) -> list[str]:
        """A write whose body still has to be parsed (``service/touch_body.py``): ``parse``
        (-> the items and their keywords) and ``GroupCommitter.submit`` run in ONE call on
        the writer threads, so neither parsing nor the sense's checks hold the event loop;
        returns the ids once the group commit stored them."""
        assert self.write_threads is not None

        def parse_and_submit() -> Future[list[str]]:
            items, kw = parse()
            return tenant.open_committer().submit(session, sense, items, **kw)

        queued = await self.write_threads.run(parse_and_submit)
        return await asyncio.wrap_future(queued)


def get_state(conn: HTTPConnection) -> ServiceState:
    return conn.app.state.tactus


def get_settings(state: Annotated[ServiceState, Depends(get_state)]) -> Settings:
    return state.settings


def get_write_threads(state: Annotated[ServiceState, Depends(get_state)]) -> WriteThreads:
    assert state.write_threads is not None  # started with the app (lifespan)
    return state.write_threads


StateDep = Annotated[ServiceState, Depends(get_state)]
WriteThreadsDep = Annotated[WriteThreads, Depends(get_write_threads)]
SettingsDep = Annotated[Settings, Depends(get_settings)]
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


#: the 401's detail and challenge, for the API routes and the MCP endpoint (service/mcp_http.py)
TOKEN_REFUSED = "missing or wrong bearer token: send 'Authorization: Bearer <token>'"
BEARER_CHALLENGE = {"WWW-Authenticate": 'Bearer realm="tactus"'}


def _caller(
    state: ServiceState, conn: HTTPConnection
) -> tuple[Principal | None, UnknownTenantError | None]:
    """The gate's principal for ``conn`` and its tenant opened, or why not: its tenant does
    not exist (a request never creates one)."""
    assert state.gate is not None and state.tenants is not None
    principal = state.gate.for_connection(conn)
    if principal is not None:
        try:
            state.tenants.get(principal.tenant)
        except UnknownTenantError as exc:
            return principal, exc
    return principal, None


async def authorize(conn: HTTPConnection, state: StateDep) -> Principal:
    """Every route but the open ones: the caller (``auth.Gate``: the operator's token, a key,
    or anyone on a store with neither; a WebSocket may pass ``?token=``) and whether its
    scope covers the one the route declares (``auth.needs``: ``Read``, ``Write``, ``Admin``
    below). 401 for no or a wrong key, 403 for a key whose scope falls short. A write,
    delete or key change is marked for the audit log (``middleware.AuditMiddleware``),
    refused or not.

    A key limited to sessions (``--sessions PREFIX``) is walled in here, for every route: a
    session in the path outside the prefix is a 404 like a missing session's, and the
    prefix is set for the rest of the request (``where.SESSION_PREFIX``), so each store read
    sees only the sessions under it (searches, listings, counts, items by id)."""
    principal, unknown = await run_in_threadpool(_caller, state, conn)  # scrypt, tenant open
    websocket = conn.scope["type"] == "websocket"
    if principal is None:
        how = " or ?token=" if websocket else ""
        raise HTTPException(401, TOKEN_REFUSED + how, headers=BEARER_CHALLENGE)
    route = conn.scope.get("route")
    need = declared_scope(route)
    if need is None or need == OPEN:  # the app is built wrong (tests/service: every route)
        raise RuntimeError(f"route {getattr(route, 'path', conn.url.path)} declares no scope")
    if need != "read":
        conn.state.audit = (principal, f"{'WS' if websocket else conn.scope['method']} "
                            f"{getattr(route, 'path', conn.url.path)}")  # fmt: skip
    if unknown is not None:  # 404 unknown-tenant (a refused write is logged all the same)
        raise unknown
    if not allows(principal.scope, need):
        raise HTTPException(
            403, f"this key's scope is {principal.scope!r}; this route needs {need!r}"
        )
    SESSION_PREFIX.set(principal.sessions)  # this request's context (its own task)
    session = conn.path_params.get("session")
    if session is not None and not session_visible(session):
        raise NotFoundError(f"no session {session!r}")
    return principal


#: the caller of the request (FastAPI runs ``authorize`` once per request however often named)
PrincipalDep = Annotated[Principal, Depends(authorize)]


def get_tenant(state: StateDep, principal: PrincipalDep) -> Tenant:
    """The caller's tenant: its memory and committer (every data route reaches the memory
    through here, so no route can read or write outside the caller's tenant)."""
    assert state.tenants is not None
    tenant = state.tenants.get(principal.tenant)
    if state.workers is not None:  # read-your-writes: another worker's acknowledged commits
        state.workers.refresh(tenant.memory)
    return tenant


TenantDep = Annotated[Tenant, Depends(get_tenant)]


def get_memory(tenant: TenantDep) -> Memory:
    return tenant.memory


#: the caller's tenant's ``tactus_memory.memory.main.Memory``
MemoryDep = Annotated[Memory, Depends(get_memory)]


def require_writable(state: StateDep) -> None:
    """Writes outside the HTTP write methods (a WebSocket stream) on a read-only store: 503
    (HTTP writes are refused by ``middleware.ReadOnlyMiddleware``, before their body)."""
    if state.read_only:
        raise ServiceUnavailable("the store is read-only: writes are refused")


def require_touch(state: StateDep, memory: MemoryDep) -> None:
    """Touch routes answer 503 when no touch sense is registered, naming why."""
    if "touch" not in memory.senses:
        why = state.touch_unavailable or "no sense named 'touch' is registered in this memory"
        raise ServiceUnavailable(f"touch is not available on this server: {why}")


Authorized = Depends(authorize)
#: the scope each route declares, in its decorator (``dependencies=[Read]``): a key of a
#: weaker scope is refused 403 (``authorize``); ``Open`` routes ask no key at all
Read, Write, Admin, Open = needs("read"), needs("write"), needs("admin"), needs(OPEN)
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
    Seconds | None,
    Query(description="Items still going on at or after (aligned); must be <= before (422)."),
]
BeforeQ = Annotated[
    Seconds | None,
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


ForceMinQ = Annotated[
    float | None,
    Query(description="Touch only: force (calibrated units: the sum of the taxels) >= this."),
]
ForceMaxQ = Annotated[float | None, Query(description="Touch only: force <= this.")]
AreaMinQ = Annotated[
    float | None,
    Query(ge=0.0, le=1.0, description="Touch only: contact area (share of the taxels) >= this."),
]
RegionsQ = Annotated[
    str | None,
    Query(
        max_length=400,
        pattern=REGIONS_PATTERN,
        description="Touch only: every one of these regions or pads active (comma-separated, "
        "e.g. `thumb,index`).",
    ),
]
GripQ = Annotated[
    Literal["none", "power", "press", "pinch", "tripod", "other"] | None,
    Query(description="Touch only: this grip (from the active regions; docs: touch facets)."),
]


SortQ = Annotated[
    Literal["force", "-force", "area", "-area", "t", "-t"] | None,
    Query(
        description="Order by a touch facet (`-force`: the firmest first; a moment by its "
        "firmest touch member) or by time, instead of the route's own order: /search and "
        "/moments order their best candidates' and return the first `k`; /count lists its "
        "occurrences in that order (the count is the same); /first and /last answer the two "
        "ends of it (`/first?sort=-force`: the firmest occurrence)."
    ),
]


@dataclass(frozen=True)
class FacetFilters:
    """The touch facet filters of a query string (one Depends, so routes stay short)."""

    force_min: float | None = None
    force_max: float | None = None
    area_min: float | None = None
    regions: str | None = None
    grip: str | None = None


def facet_filters(
    force_min: ForceMinQ = None,
    force_max: ForceMaxQ = None,
    area_min: AreaMinQ = None,
    regions: RegionsQ = None,
    grip: GripQ = None,
) -> FacetFilters:
    return FacetFilters(force_min, force_max, area_min, regions, grip)


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


def scope(
    base: Annotated[Scope, Depends(stream_scope)],
    facets: Annotated[FacetFilters, Depends(facet_filters)],
    session: SessionQ = None,
) -> Scope:
    """``sense`` (repeated), ``session``, ``source``, ``after``, ``before``, ``near``,
    ``frame`` and the touch facet filters -> one :class:`~tactus_memory.query.Scope`, what
    every search and temporal route passes down."""
    return replace(
        base,
        session=session,
        force_min=facets.force_min,
        force_max=facets.force_max,
        area_min=facets.area_min,
        regions=check_regions(facets.regions),
        grip=facets.grip,
    )


def place_scope(
    sense: SensesQ = None,
    session: SessionQ = None,
    source: SourceQ = None,
    after: AfterQ = None,
    before: BeforeQ = None,
    frame: FrameQ = None,
) -> Scope:
    """The scope of a route that takes its place in its own parameters (``GET /at``): as
    :func:`scope` without ``near``, so the schema offers only what the route takes."""
    frame = None if frame is None else validate_frame(frame)
    return Scope(session, sense, source, after, before, None, frame)


ScopeDep = Annotated[Scope, Depends(scope)]
PlaceScopeDep = Annotated[Scope, Depends(place_scope)]
StreamScopeDep = Annotated[Scope, Depends(stream_scope)]


#: how group=grasp scores a grasp (tactus_memory.search.grasps.POOLS)
GraspPool = Annotated[
    Literal["mean", "top", "max"],
    Query(
        description="With group=grasp: `mean` scores the pooled vector of every window of the "
        "grasp, `top` of its 3 windows closest to the query, `max` its best window."
    ),
]
