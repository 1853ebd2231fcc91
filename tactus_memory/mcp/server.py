"""The memory as MCP tools (the official ``mcp`` SDK, v2): :func:`build_server`.

```python
server = build_server(Memory.open("./memory"))          # read-only tools
server.run()                                            # stdio, for an agent that starts it
```

Tools: ``search``, ``last``, ``first``, ``count``, ``before``, ``after``, ``timeline``,
``sessions``, ``where`` and ``at`` (places, :mod:`tactus_memory.mcp.places`), and
``remember`` (store a note) only with ``allow_writes=True``. Arguments are
typed and documented (the JSON schema an agent sees); results are the compact models of
:mod:`tactus_memory.mcp.hits` (text content: one line of JSON; structured content:
the same object). A library error (unknown session, bad time range, ...) is a tool error
carrying the library's message; the server keeps serving.

The scope arguments (``session``, ``senses``, ``after``, ``before``) are one set of
``Annotated`` aliases shared by every tool (:mod:`tactus_memory.mcp.args`) and turned
into one :class:`~tactus_memory.query.Scope` by :func:`scope_of`; the place filter
(``near``: ``[x, y, z, r]``, ``frame``) and ``group`` are as HTTP's.
"""

from __future__ import annotations

import functools
import logging
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field, make_dataclass
from typing import Annotated, Any, TypeVar, cast

from mcp.server.mcpserver import Context, MCPServer
from mcp.server.mcpserver.exceptions import ToolError
from mcp.types import CallToolResult, ToolAnnotations
from pydantic import Field

import tactus_memory
from tactus_memory.errors import TactusError
from tactus_memory.limits import ID_PATTERN, MAX_ID_CHARS, MAX_TEXT_CHARS
from tactus_memory.matching import DEFAULT_MERGE_GAP, DEFAULT_WINDOW
from tactus_memory.mcp.args import (
    MAX_TOOL_ITEMS,
    AfterArg,
    AnchorSensesArg,
    BeforeArg,
    KArg,
    MergeGapArg,
    Number,
    QueryArg,
    SensesArg,
    SessionArg,
    TimeArg,
    WindowsArg,
    compact,
)
from tactus_memory.mcp.hits import (
    Compactor,
    ContextResult,
    CountResult,
    OccurrenceResult,
    Remembered,
    SearchResult,
    SessionsResult,
    Taught,
    TimelineResult,
)
from tactus_memory.mcp.places import (
    FrameArg,
    NearArg,
    PlaceTools,
    QuestionGroupArg,
    SearchGroupArg,
    TouchFilters,
    Within,
    group_of,
    near_of,
    scope_of,
)
from tactus_memory.memory.main import Memory
from tactus_memory.query import Scope
from tactus_memory.results import Moment, Occurrences
from tactus_memory.signatures import grouped

log = logging.getLogger(__name__)

INSTRUCTIONS = (
    "A robot's memory of what it touched, heard and was told, searchable in words. Times are "
    "seconds on each session's clock (`when` gives wall-clock time where known). Ask `sessions` "
    "first to learn the session ids and time spans; `search` finds items (touch windows carry a "
    "contact summary); `last`/`first`/`count` answer when and how often something happened; "
    "`before`/`after` list what happened around a moment; `timeline` reads a session in order; "
    "`where` says where something happened and `at` what happened near a place (metres)."
)

#: what a server that audits writes is told after each write (``remember``, ``teach``): the
#: request context of the call (the HTTP request, on HTTP), the tool, the status (201
#: stored, 422 refused) and the number of items stored
WriteHook = Callable[[Any, str, int, int], None]

R = TypeVar("R")


@dataclass(frozen=True)
class Question:
    """The arguments of ``last``, ``first`` and ``count``, one group
    (:func:`tactus_memory.signatures.grouped`, as :data:`ASK`); ``touch``: the facet filters
    and the order (``first`` and ``last`` answer its two ends: ``first`` with ``sort:
    '-force'`` is the firmest occurrence; ``count`` lists its occurrences in that order)."""

    query: QueryArg
    within: Within = Within()
    touch: TouchFilters = TouchFilters()
    merge_gap: MergeGapArg = DEFAULT_MERGE_GAP
    windows: WindowsArg = False
    group: QuestionGroupArg = None
    near: NearArg = None
    frame: FrameArg = None
    threshold: Annotated[
        Number | None,
        Field(
            description="Match bar on the calibrated score for every sense (default: per "
            "sense); a low bar (e.g. -10) lets every grasp scoring at least 0.4 x the best "
            "match, for 'the firmest'."
        ),
    ] = None

    def scope(self) -> Scope:
        return self.touch.scope(self.within.scope(self.near, self.frame))

    @property
    def grouping(self) -> str:
        return group_of(self.group, self.windows)

    def occurrences(self, memory: Memory) -> Occurrences:
        return memory.occurrences(
            self.query,
            merge_gap=self.merge_gap,
            group=self.grouping,
            scope=self.scope(),
            sort=self.touch.sort,
            threshold=self.threshold,
        )


#: a :class:`Question` from its arguments with ``within``'s and ``touch``'s spelt out (the
#: tools' group)
ASK = grouped(within=Within, touch=TouchFilters)(Question)


def around_args(side: str) -> type:
    """The arguments of the ``before`` or ``after`` tool (``side``), one group: the anchor,
    the window on that side of it, and where to look."""
    window = Field(gt=0, le=1e6, description=f"Seconds {side} it.")
    return make_dataclass(
        f"{side.title()}Args",
        [
            (
                "anchor",
                Annotated[QueryArg, Field(description=f"The moment to look {side}, in words.")],
            ),
            ("window", Annotated[Number, window], field(default=DEFAULT_WINDOW)),
            ("session", SessionArg, field(default=None)),
            ("senses", SensesArg, field(default=None)),
            ("anchor_senses", AnchorSensesArg, field(default=None)),
            ("near", NearArg, field(default=None)),
            ("frame", FrameArg, field(default=None)),
        ],
        frozen=True,
    )


#: the tools that embed a text (the others read the store only and answer while models load)
MODEL_TOOLS = frozenset(
    {"search", "last", "first", "count", "before", "after", "where", "remember", "teach"}
)
#: how long a tool call waits for models still loading before it answers "loading"
LOADING_WAIT_S = 3.0


class Loading:
    """The models loading in a background thread: ``tactus mcp`` over stdio answers
    ``initialize`` (and ``tools/list``, and the tools that need no model) at once; a tool that
    embeds a text waits up to :data:`LOADING_WAIT_S` for them, then is a tool error that says
    it is loading."""

    def __init__(self, memory: Memory) -> None:
        self.done = threading.Event()
        self.error: BaseException | None = None
        self.started = time.monotonic()
        threading.Thread(target=self._run, args=(memory,), name="mcp-warm", daemon=True).start()

    def _run(self, memory: Memory) -> None:
        try:
            warm(memory)
        except Exception as exc:  # noqa: BLE001  (told to every tool call that needs a model)
            self.error = exc
            log.warning("loading the models failed: %s", exc)
        finally:
            self.done.set()

    def check(self) -> None:
        """Return once the models are loaded; else a tool error naming the state."""
        if not self.done.wait(LOADING_WAIT_S):
            took = time.monotonic() - self.started
            raise ToolError(
                f"loading: the memory is still loading its models ({took:.0f} s so far); "
                "ask again in a few seconds (sessions, timeline and at answer now)"
            )
        if self.error is not None:
            raise ToolError(f"the models failed to load: {self.error}")


def tool_errors(fn: Callable[..., R]) -> Callable[..., R]:
    """The library's typed errors become tool errors with its message (anything else is the
    SDK's unexpected-error path: logged with its traceback, the server keeps serving). A tool
    that embeds a text first waits for the models (:class:`Loading`) when they load behind."""
    needs_model = fn.__name__ in MODEL_TOOLS

    @functools.wraps(fn)
    def wrapper(*args: Any, **kwargs: Any) -> R:
        loading = getattr(args[0], "loading", None) if args else None
        if needs_model and loading is not None:
            loading.check()
        try:
            return fn(*args, **kwargs)
        except TactusError as exc:
            raise ToolError(str(exc)) from exc

    return wrapper


class MemoryTools(PlaceTools):
    """The tools over one memory (each a method; :func:`build_server` registers them)."""

    def __init__(self, memory: Memory, on_write: WriteHook | None = None) -> None:
        self.memory = memory
        self.compactor = Compactor(memory.store)
        self.on_write = on_write
        #: the models loading behind (build_server's ``load_in_background``), or None
        self.loading: Loading | None = None

    def _known(self, session: str | None) -> None:
        """An unknown session is a tool error (``no session 'ID'``), as HTTP answers 404,
        never an empty answer that reads like "it never happened"."""
        if session is not None:
            self.memory.session(session)

    @tool_errors
    @grouped(within=Within, touch=TouchFilters)
    def search(
        self,
        query: QueryArg,
        k: KArg = 5,
        within: Within = Within(),
        windows: WindowsArg = False,
        group: SearchGroupArg = None,
        near: NearArg = None,
        frame: FrameArg = None,
        touch: TouchFilters = TouchFilters(),
    ) -> SearchResult:
        """Find remembered things (touch grasps, notes, ...) that match a description, best
        first. Each hit says when (t, t_end), which sense, its score and its id; a touch hit
        is a grasp of ``grasp_windows`` windows unless ``windows`` asks for single ones, with
        its ``facets`` (force, area, regions, grip, ...), which ``force_min``, ``force_max``,
        ``area_min``, ``regions``, ``grip`` filter and ``sort`` orders by ('-force': the
        firmest first). ``group='moment'`` also lists the moments (hits are each moment's best
        item)."""
        self._known(within.session)
        grouping = group_of(group, windows)
        scope = touch.scope(within.scope(near, frame))
        found = self.memory.search(query, k, group=grouping, scope=scope, sort=touch.sort)
        if grouping == "moment":  # as HTTP: the hits are each moment's best member
            moments_found = cast(list[Moment], found)  # group="moment" answers moments
            best = [next(h for h in m.hits if h.id == m.best) for m in moments_found]
            moments = self.compactor.moments(moments_found)
            result = SearchResult(query=query, hits=self.compactor.items(best), moments=moments)
        else:
            result = SearchResult(query=query, hits=self.compactor.items(found))
        return compact(result)

    def _occurrence(self, which: int, ask: Question) -> OccurrenceResult:
        memory, query = self.memory, ask.query
        self._known(ask.within.session)
        moments = ask.occurrences(memory).moments
        if not moments:
            return OccurrenceResult(query=query, found=False)
        (moment,) = self.compactor.moments([moments[which]])
        return OccurrenceResult(query=query, found=True, moment=moment)

    @tool_errors
    @grouped(ask=ASK)
    def last(self, ask: Question) -> OccurrenceResult:
        """When did this last happen? The most recent occurrence (found: false if never)."""
        return compact(self._occurrence(-1, ask))

    @tool_errors
    @grouped(ask=ASK)
    def count(self, ask: Question) -> CountResult:
        """How many distinct times did this happen? Also answers yes/no (count > 0)."""
        self._known(ask.within.session)
        occ = ask.occurrences(self.memory)
        moments = self.compactor.moments(occ.moments)
        result = CountResult(
            query=ask.query, count=occ.count, capped=occ.capped, occurrences=moments
        )
        return compact(result)

    @tool_errors
    @grouped(ask=ASK)
    def first(self, ask: Question) -> OccurrenceResult:
        """When did this first happen? The earliest occurrence (found: false if never)."""
        return compact(self._occurrence(0, ask))

    def _around(self, side: str, ask: Any) -> CallToolResult:
        fn = self.memory.before if side == "before" else self.memory.after
        self._known(ask.session)
        scope = scope_of(ask.session, ask.senses, None, None, ask.near, ask.frame)
        ctx = fn(ask.anchor, ask.window, scope=scope, anchor_senses=ask.anchor_senses)
        if ctx is None:
            return compact(ContextResult(side=side, window=ask.window, items=[]))
        items = self.compactor.items([ctx.anchor, *ctx.items])
        result = ContextResult(side=side, window=ask.window, anchor=items[0], items=items[1:])
        return compact(result)

    @tool_errors
    @grouped(ask=around_args("before"))
    def before(self, ask: Any) -> ContextResult:
        """What happened just before something? The anchor's best match, then the items of its
        session that start in the `window` seconds before it."""
        return self._around("before", ask)

    @tool_errors
    @grouped(ask=around_args("after"))
    def after(self, ask: Any) -> ContextResult:
        """What happened just after something? The anchor's best match, then the items of its
        session that start in the `window` seconds after it ends."""
        return self._around("after", ask)

    @tool_errors
    def timeline(
        self,
        session: Annotated[
            str, Field(pattern=ID_PATTERN, max_length=MAX_ID_CHARS, description="Session id.")
        ],
        senses: SensesArg = None,
        after: AfterArg = None,
        before: BeforeArg = None,
        limit: Annotated[
            int, Field(ge=1, le=MAX_TOOL_ITEMS, description="Most items returned.")
        ] = 50,
        near: NearArg = None,
        frame: FrameArg = None,
    ) -> TimelineResult:
        """A session's items in time order (narrow with after/before for long sessions)."""
        items = self.memory.timeline(
            session,
            senses=senses,
            after=after,
            before=before,
            limit=limit,
            near=near_of(near),
            frame=frame,
        )
        result = TimelineResult(session=session, items=self.compactor.items(items))
        return compact(result)

    @tool_errors
    def sessions(self) -> SessionsResult:
        """Every session: its id, item counts per sense, and its time span (t_min, t_max)."""
        return compact(SessionsResult(sessions=self.memory.sessions()))

    @tool_errors
    def remember(
        self,
        session: Annotated[
            str,
            Field(pattern=ID_PATTERN, max_length=MAX_ID_CHARS, description="Session id."),
        ],
        text: Annotated[
            str, Field(min_length=1, max_length=MAX_TEXT_CHARS, description="The note.")
        ],
        t: Annotated[TimeArg | None, Field(description="When (s); default: now (unix).")] = None,
        meta: Annotated[
            dict[str, Any] | None, Field(description="Free JSON stored with the note.")
        ] = None,
        ctx: Context | None = None,
    ) -> Remembered:
        """Store a note in the memory (e.g. what the robot was told or decided)."""
        t = time.time() if t is None else t
        try:
            item_id = self.memory.add(session, "text", text, t=t, meta=meta)
        except TactusError:
            self._written(ctx, "remember", 422, 0)
            raise
        self._written(ctx, "remember", 201, 1)
        return compact(Remembered(id=item_id, session=session, t=t))

    def _written(self, ctx: Context | None, tool: str, status: int, count: int) -> None:
        """Tell the write hook (the audit log of ``tactus mcp --http``) about one write."""
        if self.on_write is not None:
            request = None
            if ctx is not None:
                try:
                    request = ctx.request_context.request
                except ValueError:  # no request (called outside a session)
                    request = None
            self.on_write(request, tool, status, count)

    @tool_errors
    def teach(
        self,
        session: Annotated[
            str,
            Field(pattern=ID_PATTERN, max_length=MAX_ID_CHARS, description="Session id."),
        ],
        label: Annotated[
            str, Field(min_length=1, max_length=64, description="What was held, e.g. 'drill'.")
        ],
        after: Annotated[TimeArg | None, Field(description="Span start (s).")] = None,
        before: Annotated[TimeArg | None, Field(description="Span end (s).")] = None,
        ctx: Context | None = None,
    ) -> Taught:
        """Teach an object: the touch windows of the session between after and before were a
        grasp of `label`. Afterwards `search` and `last` find that object by its name."""
        try:
            got = self.memory.teach(label, session=session, after=after, before=before)
        except TactusError:
            self._written(ctx, "teach", 422, 0)
            raise
        self._written(ctx, "teach", 201, got.windows)
        out = Taught(**{k: v for k, v in got.to_dict().items() if k in Taught.model_fields})
        return compact(out)

    #: the place tools (:class:`~tactus_memory.mcp.places.PlaceTools`), as the others
    where = tool_errors(PlaceTools.where)
    at = tool_errors(PlaceTools.at)


#: the read-only tools, in the order an agent sees them
READ_TOOLS = (
    "sessions", "search", "last", "first", "count", "before", "after", "timeline", "where", "at"
)  # fmt: skip
#: the tools that write, offered only with ``allow_writes``
WRITE_TOOLS = ("remember", "teach")


def warm(memory: Memory) -> None:
    """Load the models a tool call needs (the space's text encoder, the store's tables and
    calibrations) now, so the first call is as fast as the next: ``tactus mcp --http`` calls
    this before its port answers."""
    memory.search("warm up", 1)
    for sense in list(memory.senses.values()):
        sense.warm(memory.space)  # touch: the grasp captions' embeddings


def build_server(
    memory: Memory,
    *,
    allow_writes: bool = False,
    on_write: WriteHook | None = None,
    load_in_background: bool = False,
) -> MCPServer:
    """An MCP server whose tools read (and with ``allow_writes``, add notes to) ``memory``;
    ``on_write`` is told of every write (:data:`WriteHook`: the audit log).
    ``load_in_background``: the models start loading now, in a thread (:class:`Loading`), and
    the server answers at once (``tactus mcp`` over stdio)."""
    server = MCPServer(
        "tactus-memory", instructions=INSTRUCTIONS, version=tactus_memory.__version__
    )
    tools = MemoryTools(memory, on_write)
    if load_in_background:
        tools.loading = Loading(memory)
    read_only = ToolAnnotations(read_only_hint=True, open_world_hint=False)
    for name in READ_TOOLS:
        server.add_tool(getattr(tools, name), name=name, annotations=read_only)
    if allow_writes:
        writes = ToolAnnotations(read_only_hint=False, destructive_hint=False)
        for name in WRITE_TOOLS:
            server.add_tool(getattr(tools, name), name=name, annotations=writes)
    return server
