"""The app factory: ``create_app(settings=None, memory=None)``.

``memory`` injects a ready :class:`~tactus_memory.memory.Memory` (tests pass one with a small
space and a stand-in touch sense; its senses are then the caller's business). Without it the
memory at ``settings.data`` is opened with ``settings.space``; text is registered by the
memory itself, touch (the shipped ``TactusEncoder``) when ``settings.touch`` and importable,
an image sense when the space has vision. When touch cannot be loaded the reason is kept and
the touch routes answer 503 naming it.
"""

from __future__ import annotations

import logging
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from typing import Any

from fastapi import Depends, FastAPI
from starlette.concurrency import run_in_threadpool

import tactus_memory
from tactus_memory.service.deps import ServiceState, require_token
from tactus_memory.service.middleware import (
    AllowMiddleware,
    BodyLimitMiddleware,
    ReadOnlyMiddleware,
)
from tactus_memory.service.openapi import install_openapi
from tactus_memory.service.problems import install_problem_handlers, problem_responses
from tactus_memory.service.readiness import store_read_only
from tactus_memory.service.routers import (
    health,
    items,
    search,
    senses,
    sessions,
    temporal,
    touch,
    touch_stream,
    ui,
)
from tactus_memory.service.settings import Settings

log = logging.getLogger("tactus_memory.service")

DESCRIPTION = """
A robot memory in which touch, text, images and motion live in one vector space, searchable
in natural language.

* Write: `POST /sessions/{id}/touch` (raw sensor units by default), `/text`, `/image`,
  `/vectors`; live touch over the WebSocket `/sessions/{id}/touch/stream`.
* Read: `GET /search?q=...`, `POST /search/like`, `GET /sessions`, `GET /senses`.
* Errors are RFC 9457 problem details (`application/problem+json`).
* Every write is acknowledged (201) only after its LanceDB commit.
* With a token configured, send `Authorization: Bearer <token>` on every route but the open
  ones: `/live`, `/health`, `/ready`, `/`, `/static/*`, `/docs`, `/redoc`, `/openapi.json`.
* Item ids belong to their session and sense: reusing another session's id is a 409.
* Cross-field rules JSON Schema cannot state (422 when broken): `t_end >= t`,
  `after <= before`, one `t`/`t_end`/`meta`/`ids` entry per window or vector.
"""


def open_memory(settings: Settings) -> tuple[Any, str | None]:
    """Open the memory at ``settings.data`` and register the default senses.

    Returns (memory, why touch is unavailable or None).
    """
    from tactus_memory.memory import Memory
    from tactus_memory.spaces import get_space

    memory = Memory.open(settings.data, space=get_space(settings.space))
    return memory, register_default_senses(memory, settings)


def register_default_senses(memory: Any, settings: Settings) -> str | None:
    """Touch (shipped checkpoint) and image (vision spaces); text comes with the memory."""
    why: str | None = None
    if "touch" not in memory.senses:
        if not settings.touch:
            why = "disabled by settings (TACTUS_TOUCH=false)"
        else:
            try:
                from tactus_memory.adapters import TactusEncoder

                memory.add_sense(TactusEncoder())
            except Exception as exc:  # noqa: BLE001  (any failure: serve the rest, say why)
                why = f"the touch encoder could not be loaded ({type(exc).__name__}: {exc})"
                log.warning("touch disabled: %s", why)
    if "image" not in memory.senses and getattr(memory.space, "has_vision", False):
        from tactus_memory.senses import ImageSense

        memory.add_sense(ImageSense(memory.space))
    return why


def create_app(settings: Settings | None = None, memory: Any = None) -> FastAPI:
    settings = settings or Settings()
    if memory is None:
        memory, touch_why = open_memory(settings)
    else:
        touch_why = (
            None if "touch" in memory.senses else ("no touch sense is registered in this memory")
        )
    state = ServiceState(
        settings=settings,
        memory=memory,
        touch_unavailable=touch_why,
        read_only=store_read_only(memory.store.uri),
    )
    if state.read_only:
        log.warning(
            "the store at %s is read-only: serving reads, refusing writes", memory.store.uri
        )

    @asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        # Load the text model before the first request instead of during it.
        try:
            await run_in_threadpool(memory.space.embed_texts, ["warm up"], query=True)
        except Exception:  # noqa: BLE001
            log.exception("warming up the space failed")
        state.warm = True
        yield

    app = FastAPI(
        title="tactus-memory",
        version=tactus_memory.__version__,
        description=DESCRIPTION,
        lifespan=lifespan,
        responses=problem_responses(500),
    )
    app.state.tactus = state
    install_problem_handlers(app)
    app.add_middleware(BodyLimitMiddleware, max_body_bytes=settings.max_body_bytes)
    app.add_middleware(
        ReadOnlyMiddleware, read_only=lambda: state.read_only, where=memory.store.uri
    )
    app.add_middleware(AllowMiddleware)
    install_openapi(app, int(memory.space.dim), bool(getattr(memory.space, "has_vision", False)))

    auth = [Depends(require_token)]
    app.include_router(health.router)
    for module in (sessions, senses, search, items, touch, ui):
        app.include_router(module.router, dependencies=auth, responses=problem_responses(401))
    app.include_router(temporal.router, dependencies=auth, responses=problem_responses(401))
    app.include_router(touch_stream.router)  # checks the token itself (header or ?token=)
    app.include_router(ui.page_router)  # the browser page: static, no data, no token
    return app
