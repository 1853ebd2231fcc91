"""Problem details (RFC 9457) and THE one place where exceptions become HTTP statuses.

Every error response of the service is ``application/problem+json``::

    {"type": "urn:tactus-memory:problem:invalid-input", "title": "Invalid input",
     "status": 422, "detail": "touch window contains NaN or inf", "instance": "/sessions/s1/touch"}

Library errors (``tactus_memory.errors``) map to statuses in ``errors.ERROR_STATUS``; request
validation errors (FastAPI/pydantic) become 422 with every failing field named in ``detail``;
anything unexpected is logged and answered with a 500 problem (never a bare traceback).

WebSocket routes use the same dependencies as HTTP routes and the same handlers: a refused
connection is accepted, sent ``{"type": "error", "error": {problem}}`` and closed with
1008 (policy violation) or, for a 503, 1013 (try again later).
"""

from __future__ import annotations

import json
import logging
import math
from collections.abc import Awaitable, Callable, Mapping
from typing import Any, TypedDict

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError, WebSocketRequestValidationError
from fastapi.responses import JSONResponse
from pydantic import BaseModel, ConfigDict, Field
from starlette.exceptions import HTTPException as StarletteHTTPException
from starlette.requests import HTTPConnection
from starlette.websockets import WebSocket
from typing_extensions import Unpack

from tactus_memory import errors
from tactus_memory.errors import ERROR_STATUS
from tactus_memory.service.readiness import is_store_failure, no_paths, short

log = logging.getLogger("tactus_memory.service")

PROBLEM_JSON = "application/problem+json"
TYPE_BASE = "urn:tactus-memory:problem:"


HTTP_TITLES = {
    400: "Bad request",
    401: "Unauthorized",
    403: "Forbidden",
    404: "Not found",
    405: "Method not allowed",
    406: "Not acceptable",
    409: "Conflict",
    413: "Content too large",
    415: "Unsupported media type",
    422: "Invalid input",
    429: "Too many requests",
    500: "Internal server error",
    503: "Service unavailable",
}


class Problem(BaseModel):
    """An RFC 9457 problem details object."""

    model_config = ConfigDict(
        json_schema_extra={
            "examples": [
                {
                    "type": TYPE_BASE + "invalid-input",
                    "title": "Invalid input",
                    "status": 422,
                    "detail": "touch window has shape (8, 32, 31), expected (K, 32, 32)",
                    "instance": "/sessions/s1/touch",
                }
            ]
        }
    )

    type: str = Field(TYPE_BASE + "about", description="URI naming the kind of problem.")
    title: str
    status: int
    detail: str = Field(description="What exactly is wrong, naming the field or value.")
    instance: str | None = None


class ServiceUnavailable(Exception):
    """A feature is not available in this server (e.g. no touch encoder): 503."""

    def __init__(self, detail: str, retry_after: int | None = None) -> None:
        super().__init__(detail)
        self.detail = detail
        self.retry_after = retry_after


def error_status(exc: BaseException) -> tuple[int, str, str] | None:
    for cls in type(exc).__mro__:
        if cls in ERROR_STATUS:
            return ERROR_STATUS[cls]
    return None


def problem_body(
    status: int,
    detail: str,
    *,
    slug: str | None = None,
    title: str | None = None,
    instance: str | None = None,
) -> dict[str, Any]:
    body: dict[str, Any] = {
        "type": TYPE_BASE + (slug or f"http-{status}"),
        "title": title or HTTP_TITLES.get(status, "Error"),
        "status": status,
        "detail": no_paths(detail) if status >= 500 else detail,  # never where the store is
    }
    if instance is not None:
        body["instance"] = instance
    return body


class ProblemFields(TypedDict, total=False):
    """The optional members of a problem body (:func:`problem_body`'s keywords)."""

    slug: str | None
    title: str | None
    instance: str | None


def problem_response(
    status: int,
    detail: str,
    *,
    headers: Mapping[str, str] | None = None,
    **fields: Unpack[ProblemFields],
) -> JSONResponse:
    return JSONResponse(
        problem_body(status, detail, **fields),
        status_code=status,
        media_type=PROBLEM_JSON,
        headers=headers,
    )


def problem_for_exception(exc: BaseException) -> dict[str, Any]:
    """Library error -> problem body (used by the WebSocket route for error messages)."""
    mapped = error_status(exc)
    if mapped is None:
        return problem_body(500, "internal error", slug="internal")
    status, slug, title = mapped
    return problem_body(status, str(exc), slug=slug, title=title)


#: WebSocket close codes (RFC 6455): a refused request, and a server that cannot serve now
POLICY_VIOLATION = 1008
TRY_AGAIN_LATER = 1013


async def refuse_websocket(websocket: WebSocket, body: dict[str, Any]) -> None:
    """Refuse a WebSocket with a problem: accept, send it as an error message, close."""
    await websocket.accept()
    await websocket.send_text(json.dumps({"type": "error", "error": body}))
    code = TRY_AGAIN_LATER if body["status"] == 503 else POLICY_VIOLATION
    await websocket.close(code=code, reason=str(body["detail"])[:120])


Handler = Callable[[Any, Any], Awaitable[JSONResponse]]


def _for_both(handler: Handler) -> Handler:
    """An HTTP problem handler that also refuses WebSockets with the same problem."""

    async def handle(conn: HTTPConnection, exc: Exception) -> Any:
        response = await handler(conn, exc)
        if conn.scope["type"] != "websocket":
            return response
        await refuse_websocket(conn, json.loads(bytes(response.body)))  # type: ignore[arg-type]
        return None

    return handle


def _loc(loc: tuple[Any, ...] | list[Any]) -> str:
    parts = [str(p) for p in loc]
    if parts and parts[0] in ("body", "query", "path", "header") and len(parts) > 1:
        return f"{parts[0]} field '{'.'.join(parts[1:])}'"
    return ".".join(parts) or "request"


#: body fields holding nested arrays, and the shape each must have: a wrong shape is said in
#: one line (as the library says it) instead of one error per number
ARRAY_FIELDS = {
    "frames": "(K, H, W) (H x W: the touch sense's frame shape, 32x32 on the glove)",
    "windows": "(B, K, H, W) (H x W: the touch sense's frame shape, 32x32 on the glove)",
    "vector": "(D,)",
    "vectors": "(N, D)",
}


def _shape(value: Any) -> tuple[int, ...]:
    """The shape of nested lists, read along the first elements."""
    shape: list[int] = []
    while isinstance(value, list):
        shape.append(len(value))
        if not value:
            break
        value = value[0]
    return tuple(shape)


def _array_shapes(exc: RequestValidationError) -> dict[str, str]:
    """Array fields of the body with more than one error, as ``{field: one line}``."""
    body = getattr(exc, "body", None)
    out: dict[str, str] = {}
    if not isinstance(body, dict):
        return out
    for name, expected in ARRAY_FIELDS.items():
        errs = [e for e in exc.errors() if tuple(e.get("loc", ()))[:2] == ("body", name)]
        if len(errs) > 1 and isinstance(body.get(name), list):
            got = _shape(body[name])
            out[name] = f"body field '{name}' must have shape {expected}, got {got}"
    return out


def validation_detail(exc: RequestValidationError) -> str:
    shapes = _array_shapes(exc)
    errors = [
        e for e in exc.errors() if tuple(e.get("loc", ()))[:2] not in {("body", n) for n in shapes}
    ]
    msgs = list(shapes.values())
    for err in errors[:10]:
        msg = str(err.get("msg", "invalid"))
        if err.get("type") == "json_invalid":
            ctx = err.get("ctx") or {}
            msg = f"body is not valid JSON: {ctx.get('error', msg)}"
            msgs.append(msg)
            continue
        msgs.append(f"{_loc(err.get('loc', ()))}: {msg}")
    more = len(errors) - 10
    if more > 0:
        msgs.append(f"and {more} more")
    return "; ".join(msgs) or "request validation failed"


def install_problem_handlers(app: FastAPI) -> None:
    """Register the handlers: library errors, HTTP errors, validation errors, the catch-all."""

    async def tactus_error(request: Request, exc: errors.TactusError) -> JSONResponse:
        status, slug, title = error_status(exc) or (422, "invalid-input", "Invalid input")
        retry = getattr(exc, "retry_after", None)  # OverloadedError: tell when to come back
        headers = None if retry is None else {"Retry-After": str(max(1, math.ceil(retry)))}
        return problem_response(
            status, str(exc), slug=slug, title=title, instance=request.url.path, headers=headers
        )

    async def http_error(request: Request, exc: StarletteHTTPException) -> JSONResponse:
        detail = exc.detail if isinstance(exc.detail, str) else json.dumps(exc.detail)
        return problem_response(
            exc.status_code, detail, instance=request.url.path, headers=exc.headers
        )

    async def validation_error(request: Request, exc: RequestValidationError) -> JSONResponse:
        return problem_response(
            422,
            validation_detail(exc),
            slug="invalid-input",
            title="Invalid input",
            instance=request.url.path,
        )

    async def unavailable(request: Request, exc: ServiceUnavailable) -> JSONResponse:
        retry = None if exc.retry_after is None else {"Retry-After": str(exc.retry_after)}
        return problem_response(
            503,
            exc.detail,
            slug="unavailable",
            title="Service unavailable",
            instance=request.url.path,
            headers=retry,
        )

    async def unexpected(request: Request, exc: Exception) -> JSONResponse:
        method = getattr(request, "method", "WEBSOCKET")
        if is_store_failure(exc):  # a damaged or vanished store file: say so, no traceback
            log.error("store failure on %s %s: %s", method, request.url.path, short(exc))
            return problem_response(
                503,
                f"the store could not be read or written: {short(exc)}",
                slug="store-unavailable",
                title="Service unavailable",
                instance=request.url.path,
            )
        return await internal(request, exc)

    async def internal(request: Request, exc: Exception) -> JSONResponse:
        log.exception(
            "unhandled error on %s %s", getattr(request, "method", "WEBSOCKET"), request.url.path
        )
        return problem_response(
            500,
            f"internal error ({type(exc).__name__}); see the server log",
            slug="internal",
            instance=request.url.path,
        )

    handlers: list[tuple[type[Exception], Handler]] = [
        (errors.TactusError, tactus_error),
        (StarletteHTTPException, http_error),
        (RequestValidationError, validation_error),
        (WebSocketRequestValidationError, validation_error),
        (ServiceUnavailable, unavailable),
        # RuntimeError/OSError (LanceDB's I/O errors among them) are answered here, inside
        # the app, so that they are logged once; the catch-all below is Starlette's last
        # resort, which logs and then re-raises to the server.
        (RuntimeError, unexpected),
        (OSError, unexpected),
        (Exception, unexpected),
    ]
    for cls, handler in handlers:
        app.add_exception_handler(cls, _for_both(handler))


#: ``responses=`` for routes: the problem model documented for the error statuses.
def problem_responses(*statuses: int) -> dict[int | str, dict[str, Any]]:
    return {
        s: {
            "model": Problem,
            "description": HTTP_TITLES.get(s, "Error"),
            "content": {PROBLEM_JSON: {}},
        }
        for s in statuses
    }
