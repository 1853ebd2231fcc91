"""The app factory: ``create_app(settings=None, memory=None)``.

``memory`` injects a ready :class:`~tactus_memory.memory.main.Memory` (tests pass one with a small
space and a stand-in touch sense; its senses are then the caller's business). Without it the
memory at ``settings.data`` is opened in ``settings.space`` (``space_path``/``space_dim``; by
default the store's recorded space, see ``tactus_memory.spaces.resolve``); text is registered by the
memory itself, touch (the shipped ``TactusEncoder``) when ``settings.touch`` and importable,
an image sense when the space has vision. When touch cannot be loaded the reason is kept and
the touch routes answer 503 naming it.
"""

from __future__ import annotations

import asyncio
import ctypes
import logging
import os
from collections.abc import AsyncIterator, Callable
from contextlib import asynccontextmanager
from typing import Any

import anyio.to_thread
from fastapi import Depends, FastAPI
from fastapi.routing import APIRoute
from starlette.concurrency import run_in_threadpool

import tactus_memory
from tactus_memory.errors import UnknownTenantError
from tactus_memory.senses.plugins import create_sense, lookup
from tactus_memory.service.auth import Gate
from tactus_memory.service.deps import ServiceState, authorize
from tactus_memory.service.middleware import (
    AllowMiddleware,
    AuditMiddleware,
    BodyLimitMiddleware,
    ReadOnlyMiddleware,
    StartingMiddleware,
    WorkerHeaderMiddleware,
)
from tactus_memory.service.openapi import install_openapi
from tactus_memory.service.problems import install_problem_handlers, problem_responses
from tactus_memory.service.readiness import store_read_only
from tactus_memory.service.routers import (
    api_docs,
    health,
    images,
    items,
    labels,
    places,
    recordings,
    retention,
    search,
    senses,
    sessions,
    temporal,
    touch,
    touch_stream,
    ui,
)
from tactus_memory.service.startup import StartupError, check_named_checkpoint, recorded_checkpoint
from tactus_memory.settings import Settings
from tactus_memory.storage.audit import AuditLog
from tactus_memory.storage.keys import KeyStore
from tactus_memory.storage.tenants import store_root, tenant_names

log = logging.getLogger("tactus_memory.service")

DESCRIPTION = """
A robot memory in which touch, text, images and motion live in one vector space, searchable
in natural language.

* Write: `POST /sessions/{id}/touch` (raw sensor units by default), `/text`, `/image`,
  `/vectors`; live touch over the WebSocket `/sessions/{id}/touch/stream`; any windowed sense
  (touch, an IMU) at `POST /sessions/{id}/senses/{sense}/windows` and the WebSocket
  `/sessions/{id}/senses/{sense}/stream`.
* Read: `GET /search?q=...`, `POST /search/like`, `GET /sessions`, `GET /senses`.
* Where: `POST /sessions/{id}/poses` (the trajectory), `GET /where?q=...`,
  `GET /at?x=&y=&z=&r=`; every search takes `near=x,y,z,r` and `frame=`.
* Errors are RFC 9457 problem details (`application/problem+json`).
* Every write is acknowledged (201) only after its LanceDB commit.
* With a token configured, send `Authorization: Bearer <token>` on every route but the open
  ones: `/live`, `/health`, `/ready`, `/`, `/static/*`, `/docs`, `/redoc`, `/openapi.json`.
* Keys (`tactus keys create`) work as the token and scope every route to their tenant
  (`read`, `write`, `admin`): another tenant's session or item is a 404, like a missing one.
* Item ids belong to their session and sense: reusing another session's id is a 409.
* Cross-field rules JSON Schema cannot state (422 when broken): `t_end >= t`,
  `after <= before`, one `t`/`t_end`/`meta`/`ids` entry per window or vector.
"""


def open_store(settings: Settings) -> Any:
    """The memory at ``settings.data`` in the configured space, no senses added yet."""
    from tactus_memory.memory.main import Memory

    memory = Memory.open(
        settings.data,
        space=settings.space,
        space_path=settings.space_path,
        space_dim=settings.space_dim,
        read_consistency_interval=settings.read_consistency,
        maintenance=settings.maintenance(),
    )
    if settings.onnx:
        from tactus_memory.spaces.minilm import MiniLMSpace

        if not isinstance(memory.space, MiniLMSpace):
            raise StartupError(
                f"ONNX Runtime serves the MiniLM space; this memory is in "
                f"{memory.space.name!r}: serve it with --torch (and no --onnx)"
            )
        memory.space.use_onnx(settings.onnx)
    return memory


def key_store(memory: Any) -> KeyStore:
    """The keys of the store ``memory`` (any tenant's) lives in: the ``keys`` table of the
    store's root (never of a tenant's database), re-read every read consistency interval
    (1 s when it never re-reads)."""
    store = memory.store
    every = store.read_consistency.total_seconds() if store.read_consistency is not None else 1.0
    root = store_root(store.uri, memory.tenant)
    return KeyStore(root, storage_options=store.storage_options, refresh=every)


def audit_log(memory: Any) -> AuditLog:
    """The audit log of the store ``memory`` (any tenant's) lives in, in the store's root
    (tidied here when this process maintains the store)."""
    store = memory.store
    policy = store.maintenance
    retain = policy.retain_seconds if policy.maintain else None
    root = store_root(store.uri, memory.tenant)
    return AuditLog(root, storage_options=store.storage_options, retain_seconds=retain)


def open_memory(settings: Settings) -> tuple[Any, str | None]:
    """Open the memory at ``settings.data`` and register the default senses.

    Returns (memory, why touch is unavailable or None).
    """
    memory = open_store(settings)
    return memory, register_default_senses(memory, settings)


def register_default_senses(memory: Any, settings: Settings) -> str | None:
    """The senses the store records, rebuilt from their records (``memory.restore_senses``),
    then the defaults still missing, by registered name (:mod:`tactus_memory.senses.plugins`): touch
    (``settings.touch_checkpoint`` or the shipped checkpoint) and image (vision spaces); text
    comes with the memory. The extra touch senses of ``settings.touch_senses`` (name ->
    checkpoint, on torch) are registered first, as the glove's named checkpoint is. Returns
    why touch is unavailable, or None."""
    onnx = {"onnx": settings.onnx} if settings.onnx else {}
    if settings.touch and settings.touch_checkpoint and "touch" not in memory.senses:
        # asked for by name: it must be the store's own (one encoder per sense), and a failure
        # stops the start
        check_named_checkpoint(memory, "touch", settings.touch_checkpoint)
        memory.add_sense(
            create_sense("touch", memory.space, checkpoint=settings.touch_checkpoint, **onnx)
        )
    elif settings.touch and onnx and "touch" not in memory.senses and _shipped_or_none(memory):
        # the shipped checkpoint on ONNX Runtime, where the store records it (or no touch):
        # a store re-embedded to another checkpoint is opened with that one (restored below)
        memory.add_sense(create_sense("touch", memory.space, **onnx))
    for name, checkpoint in settings.touch_senses.items():
        # touch senses beside the glove (--touch NAME=CKPT), each with its checkpoint's sensor
        # profile; asked for by name, like the glove's checkpoint: a failure stops the start
        check_named_checkpoint(memory, name, checkpoint)
        memory.add_sense(create_sense("touch", memory.space, checkpoint=checkpoint, name=name))
    for name, reason in memory.restore_senses(skip=() if settings.touch else ("touch",)).items():
        log.warning("sense %r is searchable but not rebuilt: %s", name, reason)
    why: str | None = None
    if not settings.touch:
        why = "disabled by settings (TACTUS_TOUCH=false)"
    elif "touch" not in memory.senses:
        try:
            memory.add_sense(create_sense("touch", memory.space))
        except Exception as exc:  # noqa: BLE001  (any failure: serve the rest, say why)
            why = f"the touch encoder could not be loaded ({type(exc).__name__}: {exc})"
            log.warning("touch disabled: %s", why)
    if "image" not in memory.senses and memory.space.has_vision:
        memory.add_sense(create_sense("image", memory.space))
    for sense in list(memory.senses.values()):
        # what a first write or search would pay (touch: the grasp captions' embeddings),
        # before the server is ready
        sense.warm(memory.space)
    return why


def _shipped_or_none(memory: Any) -> bool:
    """Whether the store records the shipped touch checkpoint, or no touch sense at all."""
    recorded = recorded_checkpoint(memory, "touch")
    return recorded is None or recorded[1] == lookup("sense", "touch").shipped_sha256()


async def _load_in_background(state: ServiceState, loader: Loader) -> None:
    try:
        why = await run_in_threadpool(loader, state)
    except Exception as exc:  # noqa: BLE001  (the command decides: one line, exit 2)
        log.error("loading the models failed: %s", exc)
        state.starting = f"failed: {exc}"
        state.load_error = exc
        return
    state.touch_unavailable = why
    state.warm = True
    state.starting = None
    return_freed_heap()


def return_freed_heap() -> bool:
    """Give the heap pages freed while the models loaded (tokenizer, weight-loading and
    warm-up temporaries) back to the OS, which glibc's allocator otherwise keeps: an ONNX
    server's idle RSS is ~15 MB lower for it (``benchmarks/light_server.py``). False where
    the C library has no ``malloc_trim`` (not glibc)."""
    try:
        trim = ctypes.CDLL(None).malloc_trim
    except (OSError, AttributeError):
        return False
    trim(0)
    return True


def serving_torch_threads() -> int:
    """Torch threads per call for a server (``tactus serve`` without TACTUS_TORCH_THREADS):
    half the cores, so the committer's encoder batch and a search's query embedding each get
    their own instead of fighting over all of them (oversubscribed OpenMP threads spin: on
    the shared 2-core box, encoder batches measured 3x slower with 2 threads than with 1).
    """
    return max(1, (os.cpu_count() or 2) // 2)


def operation_id(route: APIRoute) -> str:
    """An operation's id is its route's name, which says what it does (``search``,
    ``add_touch``, ``last``), so a client generated from ``/openapi.json`` has methods of
    those names (FastAPI's default, ``search_search_get``, repeats the path and the method).
    Route names are unique across the app (tests/service/test_openapi_names.py checks it)."""
    return route.name


#: what a background loader gets and returns: the state (to name its step in
#: ``state.starting``) -> why touch is unavailable, or None
Loader = Callable[[ServiceState], "str | None"]


def maintain_every_tenant(state: ServiceState) -> list[str]:
    """One idle tick: a maintenance pass, where one is due, of every tenant of the store
    (``tenants.tenant_names``: the default, each folder under ``tenants/``, each tenant a
    key names), each opened if no request has opened it yet, so a tenant nobody asks still
    expires and erases. Returns the tenants ticked; one tenant's failure is logged and the
    others are ticked all the same."""
    assert state.tenants is not None
    store = state.memory.store
    names = tenant_names(store.uri, state.key_tenants())
    ticked = []
    for name in names:
        try:
            state.tenants.get(name).memory.maintain_if_due()
            ticked.append(name)
        except UnknownTenantError:
            continue  # a key names it, its database is gone: nothing to maintain
        except Exception:  # noqa: BLE001  (retried on the next tick)
            log.exception("scheduling maintenance of tenant %r failed; retried next tick", name)
    return ticked


async def _maintenance_ticks(state: ServiceState, interval: float) -> None:
    """Every ``interval`` seconds, a maintenance pass of every tenant when one is due
    without a commit (retention, erasure of deleted rows): commits alone schedule it
    otherwise."""
    while True:
        await asyncio.sleep(interval)
        try:
            await run_in_threadpool(maintain_every_tenant, state)
        except Exception:  # noqa: BLE001  (retried on the next tick)
            log.exception("scheduling maintenance failed; retried on the next tick")


def create_app(
    settings: Settings | None = None,
    memory: Any = None,
    *,
    loader: Loader | None = None,
) -> FastAPI:
    """The app. With ``loader`` (``tactus serve``), the lifespan returns at once, so the
    socket opens, and ``loader`` loads the models on a worker thread; until it returns,
    ``state.starting`` names the step (probes 503, data routes 503 + Retry-After). If it
    raises, ``state.load_error`` keeps the exception (the command stops the server)."""
    settings = settings or Settings()
    if settings.torch_threads is not None and not settings.onnx:
        # Before any worker thread exists: threads take the count when they first run torch.
        import torch

        torch.set_num_threads(settings.torch_threads)
    if memory is None:
        memory, touch_why = open_memory(settings)
    elif loader is not None:
        touch_why = None  # the loader says, once it has tried
    else:
        touch_why = (
            None if "touch" in memory.senses else ("no touch sense is registered in this memory")
        )
    read_only = store_read_only(memory.store.uri)
    state = ServiceState(
        settings=settings,
        memory=memory,
        touch_unavailable=touch_why,
        read_only=read_only,
        starting="loading the models" if loader is not None else None,
        gate=Gate(settings, key_store(memory)),
        audit=None if read_only else audit_log(memory),
    )
    damage = memory.store.integrity.damage(0)
    if damage:  # served (reads where they can), but unhealthy and refusing writes
        log.error("the store is damaged, writes are refused: %s", "; ".join(map(str, damage)))
    if state.read_only:
        log.warning(
            "the store at %s is read-only: serving reads, refusing writes", memory.store.uri
        )

    @asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        # Reads (sync routes, run_in_threadpool) use the default thread pool; writes never
        # do (the group committer has its own thread, prepares run on the write threads' limiter),
        # so bounding it bounds the reads alone.
        anyio.to_thread.current_default_thread_limiter().total_tokens = settings.read_threads
        for tenant in state.tenants:
            tenant.open_committer()
        loading: asyncio.Task[None] | None = None
        if loader is not None:
            # the socket opens now; the models load on a worker thread (see /ready)
            loading = asyncio.create_task(_load_in_background(state, loader))
        else:
            # Load the text model before the first request instead of during it.
            try:
                await run_in_threadpool(memory.space.embed_texts, ["warm up"], query=True)
            except Exception:  # noqa: BLE001
                log.exception("warming up the space failed")
            state.warm = True
        ticking = asyncio.create_task(_maintenance_ticks(state, settings.maintain_interval))
        yield
        ticking.cancel()
        if loading is not None and not loading.done():
            loading.cancel()  # the worker thread finishes its step; nothing waits for it
        # Commit what is queued (its clients are waiting for their acks), then stop.
        for tenant in state.tenants:
            if tenant.committer is not None:
                await run_in_threadpool(tenant.committer.close, 30.0)
        if state.audit is not None:
            await run_in_threadpool(state.audit.close)

    app = FastAPI(
        title="tactus-memory",
        version=tactus_memory.__version__,
        description=DESCRIPTION,
        lifespan=lifespan,
        responses=problem_responses(500),
        generate_unique_id_function=operation_id,
        docs_url=None,  # /docs and /redoc: service/routers/api_docs.py, assets from the package
        redoc_url=None,
    )
    app.state.tactus = state
    install_problem_handlers(app)
    app.add_middleware(BodyLimitMiddleware, max_body_bytes=settings.max_body_bytes)
    app.add_middleware(ReadOnlyMiddleware, read_only=lambda: state.read_only)
    app.add_middleware(AuditMiddleware)
    app.add_middleware(AllowMiddleware)
    app.add_middleware(StartingMiddleware, starting=lambda: state.starting)
    app.add_middleware(
        WorkerHeaderMiddleware,
        worker=lambda: None if state.workers is None else state.workers.index,
    )
    install_openapi(app, int(memory.space.dim), bool(getattr(memory.space, "has_vision", False)))

    auth = [Depends(authorize)]
    app.include_router(health.router)
    for module in (
        sessions, senses, images, search, items, touch, touch_stream, ui, recordings, places,
        retention, labels,
    ):  # fmt: skip
        app.include_router(module.router, dependencies=auth, responses=problem_responses(401, 403))
    for router in (touch.windows_router, touch_stream.windows_router):  # any windowed sense
        app.include_router(router, dependencies=auth, responses=problem_responses(401, 403))
    app.include_router(temporal.router, dependencies=auth, responses=problem_responses(401, 403))
    app.include_router(ui.page_router)  # the browser page: static, no data, no token
    app.include_router(api_docs.router)  # /docs and /redoc, served offline; no token
    return app
