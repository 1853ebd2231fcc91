"""Pure ASGI middleware: the request body size limit (413).

The limit is enforced twice: up front on ``Content-Length`` (the body is never read), and
while the body streams in for requests without it (chunked transfer): the wrapped ``receive``
counts bytes and raises a 413 ``HTTPException`` as soon as the limit is passed, which the
problem handlers turn into ``application/problem+json``. Should the exception reach this
middleware unhandled (no response started yet), it answers the 413 itself.

Before answering a 413 the rest of the body is read and dropped (up to :data:`DRAIN_FACTOR`
times the limit): a client that sends the whole body before it reads the answer (Python's
urllib does) would otherwise see its connection reset instead of the 413.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Sequence
from typing import Any

import anyio
from starlette.exceptions import HTTPException
from starlette.routing import Match
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from tactus_memory.errors import TactusError
from tactus_memory.identity import TENANT_HEADER
from tactus_memory.service.auth import bearer
from tactus_memory.service.deps import OPEN_PATHS, OPEN_PREFIXES
from tactus_memory.service.problems import PROBLEM_JSON, problem_body


async def send_problem(
    send: Send, status: int, problem: dict[str, Any], headers: Sequence[tuple[bytes, bytes]] = ()
) -> None:
    """Answer with a problem+json body straight from ASGI (before any route), plus ``headers``."""
    body = json.dumps(problem).encode()
    await send(
        {
            "type": "http.response.start",
            "status": status,
            "headers": [
                (b"content-type", PROBLEM_JSON.encode()),
                (b"content-length", str(len(body)).encode()),
                *headers,
            ],
        }
    )
    await send({"type": "http.response.body", "body": body})


class BodyTooLarge(HTTPException):
    def __init__(self, limit: int, seen: int | None = None) -> None:
        what = f"{seen} bytes" if seen is not None else f"more than {limit} bytes"
        super().__init__(413, f"request body is {what}; the limit is {limit} bytes")


#: a too-large body is drained (read and dropped) up to this many times the limit
DRAIN_FACTOR = 4


#: ... and for at most this many seconds (a client may declare more than it sends)
DRAIN_SECONDS = 5.0


async def drain(receive: Receive, budget: int) -> None:
    """Read and drop the request body until its end, a disconnect, ``budget`` bytes or
    :data:`DRAIN_SECONDS`."""
    seen = 0
    with anyio.move_on_after(DRAIN_SECONDS):
        while seen <= budget:
            message = await receive()
            if message["type"] != "http.request":
                return
            seen += len(message.get("body", b""))
            if not message.get("more_body", False):
                return


class BodyLimitMiddleware:
    def __init__(self, app: ASGIApp, max_body_bytes: int) -> None:
        self.app = app
        self.limit = int(max_body_bytes)

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        limit = self.limit
        for name, value in scope.get("headers", ()):
            if name == b"content-length":
                try:
                    declared = int(value)
                except ValueError:
                    await self._reply(send, 400, "Content-Length header is not an integer")
                    return
                if declared > limit:
                    await drain(receive, DRAIN_FACTOR * limit)
                    await self._reply(send, 413, str(BodyTooLarge(limit, declared).detail))
                    return
        received = 0
        started = False

        async def limited_receive() -> Message:
            nonlocal received
            message = await receive()
            if message["type"] == "http.request":
                received += len(message.get("body", b""))
                if received > limit:
                    if message.get("more_body", False):
                        await drain(receive, DRAIN_FACTOR * limit)
                    raise BodyTooLarge(limit)
            return message

        async def tracking_send(message: Message) -> None:
            nonlocal started
            if message["type"] == "http.response.start":
                started = True
            await send(message)

        try:
            await self.app(scope, limited_receive, tracking_send)
        except BodyTooLarge as exc:
            if started:
                raise
            await drain(receive, DRAIN_FACTOR * limit)
            await self._reply(send, 413, str(exc.detail))

    @staticmethod
    async def _reply(send: Send, status: int, detail: str) -> None:
        title = "Content too large" if status == 413 else "Bad request"
        problem = problem_body(status, detail, title=title)
        await send_problem(send, status, problem, [(b"connection", b"close")])


#: POST routes that only read (search by example, drawing a window): allowed on a read-only store
READ_ONLY_POSTS = ("/search/like", "/search/like/image", "/render/touch.png")
WRITE_METHODS = frozenset({"POST", "PUT", "PATCH", "DELETE"})


class ReadOnlyMiddleware:
    """On a read-only store, writes (POST/PUT/PATCH/DELETE but the read-only POSTs) answer
    503 before reaching a route; reads go through. ``read_only()`` is asked per request."""

    def __init__(self, app: ASGIApp, read_only: Callable[[], bool]) -> None:
        self.app = app
        self.read_only = read_only

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if (
            scope["type"] == "http"
            and scope["method"] in WRITE_METHODS
            and scope["path"] not in READ_ONLY_POSTS
            and self.read_only()
        ):
            detail = (
                "the store is read-only: writes and deletes are refused; "
                "reads and searches work (serve a writable copy to write)"
            )
            problem = problem_body(503, detail, slug="read-only", title="Store is read-only")
            await send_problem(send, 503, problem)
            return
        await self.app(scope, receive, send)


#: what answers while the models load: the probes (they say "starting" themselves), the page
#: and the API docs; every other route answers 503 + Retry-After naming the step
OPEN_WHILE_STARTING = ("/live", "/ready", "/health", "/", "/docs", "/redoc", "/openapi.json")
#: seconds a client is told to wait while the server starts
STARTING_RETRY_AFTER_S = 1


class StartingMiddleware:
    """While ``starting()`` names a step (the text model or the touch encoder is loading in
    the background, the socket already open), data routes and WebSocket streams answer 503
    with ``Retry-After`` and that step instead of waiting in a queue."""

    def __init__(self, app: ASGIApp, starting: Callable[[], str | None]) -> None:
        self.app = app
        self.starting = starting

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        step = self.starting() if scope["type"] in ("http", "websocket") else None
        path = scope.get("path", "")
        if step is None or path in OPEN_WHILE_STARTING or path.startswith("/static/"):
            await self.app(scope, receive, send)
            return
        detail = f"starting: {step}; retry in a moment (GET /ready answers 200 when ready)"
        if scope["type"] == "websocket":
            await send({"type": "websocket.close", "code": 1013, "reason": detail[:120]})
            return
        problem = problem_body(503, detail, slug="starting", title="Server is starting")
        retry = [(b"retry-after", str(STARTING_RETRY_AFTER_S).encode())]
        await send_problem(send, 503, problem, retry)


CANDIDATE_METHODS = ("GET", "HEAD", "POST", "PUT", "PATCH", "DELETE")
UNAUTHORIZED = "missing or wrong bearer token: send 'Authorization: Bearer <token>'"
BEARER_REALM = b'Bearer realm="tactus"'


def _without_body(send: Send) -> Send:
    """``send`` for a HEAD answered by its GET route: status and headers, no body bytes."""

    async def head_send(message: Message) -> None:
        if message["type"] == "http.response.body":
            message = {**message, "body": b""}
        await send(message)

    return head_send


def _token_ok_for(scope: Scope) -> bool:
    """Whether an ``OPTIONS`` request may see the path's methods: the path is one of the open
    routes (:data:`~tactus_memory.service.deps.OPEN_PATHS`), or the request carries the token
    its routes need."""
    path = scope["path"]
    if path in OPEN_PATHS or path.startswith(OPEN_PREFIXES):
        return True
    headers = dict(scope.get("headers", ()))
    header = headers.get(b"authorization", b"").decode("latin-1")
    tenant = headers.get(TENANT_HEADER.encode(), b"").decode("latin-1") or None
    try:
        return scope["app"].state.tactus.gate.principal(bearer(header), tenant) is not None
    except TactusError:  # a malformed tenant header: refused like a wrong token
        return False


class AllowMiddleware:
    """``OPTIONS`` and 405 answers name every method the path takes (RFC 9110 ``Allow``), and
    ``HEAD`` is served wherever ``GET`` is.

    Starlette stops at the first route whose path matches, so on a path served by several
    routes (``GET`` and ``DELETE /sessions/{id}``) its 405 said ``Allow: GET``. Here the
    methods of every matching route are collected: ``OPTIONS`` answers 204 with them (behind
    the same bearer token as the route: 401 without it), any other method the path does not
    take answers a 405 problem with them. ``HEAD`` on a ``GET`` route runs the ``GET`` (its
    token check included) and sends its status and headers without the body (RFC 9110 9.3.2).
    """

    def __init__(self, app: ASGIApp) -> None:
        self.app = app

    @staticmethod
    def _methods(routes: Any, scope: Scope) -> set[str]:
        """The methods some route fully matches for this path (Starlette's own matching)."""
        methods: set[str] = set()
        for method in CANDIDATE_METHODS:
            probe = {**scope, "method": method}
            if any(route.matches(probe)[0] == Match.FULL for route in routes):
                methods.add(method)
        return methods

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        routes = scope["app"].router.routes
        method = scope["method"]
        if method != "OPTIONS" and any(r.matches(scope)[0] == Match.FULL for r in routes):
            await self.app(scope, receive, send)  # the common case: one pass over the routes
            return
        methods = self._methods(routes, scope)
        if "GET" in methods and "HEAD" not in methods:
            methods.add("HEAD")
            if method == "HEAD":
                await self.app({**scope, "method": "GET"}, receive, _without_body(send))
                return
        if not methods or method in methods:
            await self.app(scope, receive, send)
            return
        allow = ", ".join(sorted(methods | {"OPTIONS"}))
        if method == "OPTIONS":
            if not _token_ok_for(scope):
                problem = problem_body(401, UNAUTHORIZED, instance=scope["path"])
                await send_problem(send, 401, problem, [(b"www-authenticate", BEARER_REALM)])
                return
            await send(
                {
                    "type": "http.response.start",
                    "status": 204,
                    "headers": [(b"allow", allow.encode())],
                }
            )
            await send({"type": "http.response.body", "body": b""})
            return
        detail = f"{method} is not allowed on {scope['path']}; allowed: {allow}"
        problem = problem_body(405, detail, instance=scope["path"])
        await send_problem(send, 405, problem, [(b"allow", allow.encode())])


def _audit_count(body: bytes, status: int) -> int:
    """How many items an answer says it wrote or removed (``count``, ``deleted``; 1 for
    another success, 0 for a failure)."""
    if status >= 400:
        return 0
    try:
        out = json.loads(body)
    except ValueError:
        return 1
    if isinstance(out, dict):
        for key in ("count", "deleted", "stored"):
            if isinstance(out.get(key), int):
                return int(out[key])
    return 1


class AuditMiddleware:
    """Logs each HTTP request the gate marked (a write, delete or key change,
    ``deps.authorize``) once answered: key id, tenant, route template, status and the
    count its answer gives (:mod:`tactus_memory.storage.audit`; never the key or the body)."""

    def __init__(self, app: ASGIApp) -> None:
        self.app = app

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        audit = scope["app"].state.tactus.audit
        if scope["type"] != "http" or scope["method"] in ("GET", "HEAD") or audit is None:
            await self.app(scope, receive, send)
            return
        status, body = [0], bytearray()
        state = scope.setdefault("state", {})  # shared with the copies inner layers make

        async def keep(message: Message) -> None:
            if message["type"] == "http.response.start":
                status[0] = message["status"]
            elif message["type"] == "http.response.body" and len(body) < 65536:
                body.extend(message.get("body", b""))
            await send(message)

        try:
            await self.app(scope, receive, keep)
        finally:
            marked = state.get("audit")
            if marked is not None:
                principal, route = marked
                count = _audit_count(bytes(body), status[0])
                audit.record(principal.key_id, principal.tenant, route, status[0], count)


class WorkerHeaderMiddleware:
    """``tactus serve --workers N``: every HTTP answer says which worker gave it
    (``X-Tactus-Worker: i``), for the operator and for the read-your-writes test."""

    def __init__(self, app: ASGIApp, worker: Callable[[], int | None]) -> None:
        self.app = app
        self.worker = worker

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        index = self.worker() if scope["type"] == "http" else None
        if index is None:
            await self.app(scope, receive, send)
            return

        async def tagged(message: Message) -> None:
            if message["type"] == "http.response.start":
                headers = list(message.get("headers", []))
                headers.append((b"x-tactus-worker", str(index).encode()))
                message = {**message, "headers": headers}
            await send(message)

        await self.app(scope, receive, tagged)
