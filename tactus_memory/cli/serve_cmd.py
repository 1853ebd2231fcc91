"""``tactus serve``: the HTTP service on uvicorn (one process; the memory serialises writes)."""

from __future__ import annotations

import os
import threading
import time
import traceback
from collections.abc import Callable
from pathlib import Path
from typing import Annotated, Any

import typer

from tactus_memory.cli.app import app
from tactus_memory.cli.common import ServiceData, TouchSenses, TouchStride, TouchWindow
from tactus_memory.cli.prefetch import record as record_start_files
from tactus_memory.cli.space_opts import SpaceDim, SpaceName, SpacePath


@app.command()
def serve(
    host: Annotated[str | None, typer.Option(help="Bind address (default 127.0.0.1).")] = None,
    port: Annotated[int | None, typer.Option(help="Port (default 8000).")] = None,
    data: ServiceData = None,
    token: Annotated[
        str | None,
        typer.Option(
            help="Require 'Authorization: Bearer <token>' on every route but the open ones "
            "(/health, /live, /ready, /, /static, /docs, /redoc, /openapi.json) (env "
            "TACTUS_TOKEN). Must not be empty. WebSocket clients may pass ?token= instead; "
            "it is redacted in the logs."
        ),
    ] = None,
    space: SpaceName = None,
    space_path: SpacePath = None,
    space_dim: SpaceDim = None,
    touch_checkpoint: Annotated[
        str | None,
        typer.Option(
            help="Tactus checkpoint for touch, trained in this space (tactus train --space ...); "
            "default the shipped MiniLM one (env TACTUS_TOUCH_CHECKPOINT)."
        ),
    ] = None,
    touch_sense: TouchSenses = None,
    max_body_bytes: Annotated[
        int | None,
        typer.Option(help="Largest request body, 413 beyond (env TACTUS_MAX_BODY_BYTES)."),
    ] = None,
    window: TouchWindow = None,
    stride: TouchStride = None,
    no_touch: Annotated[
        bool, typer.Option("--no-touch", help="Do not load the touch encoder.")
    ] = False,
    onnx: Annotated[
        str | None,
        typer.Option(
            help="Folder written by `tactus export-onnx` to serve from (default: a folder in "
            "the user's cache, MiniLM exported there on the first start; env TACTUS_ONNX)."
        ),
    ] = None,
    workers: Annotated[
        int | None,
        typer.Option(
            min=1,
            max=64,
            help="Server processes on one port and one store (SO_REUSEPORT; each with its own "
            "event loop, committer and models; worker 0 maintains; env TACTUS_WORKERS). "
            "Default: the cores this process may use, capped (settings.MAX_DEFAULT_WORKERS).",
        ),
    ] = None,
    torch: Annotated[
        bool,
        typer.Option(
            "--torch",
            help="Run MiniLM and the touch encoder on torch instead of ONNX Runtime (slower "
            "start, more memory; spaces other than MiniLM always do; env TACTUS_TORCH=1).",
        ),
    ] = False,
    no_maintain: Annotated[
        bool,
        typer.Option(
            "--no-maintain",
            help="Leave compaction and cleanup to another process (`tactus maintain`): for "
            "replicas sharing a store (env TACTUS_MAINTAIN=0).",
        ),
    ] = False,
    log_level: Annotated[str | None, typer.Option(help="uvicorn log level (default info).")] = None,
    config: Annotated[
        str | None,
        typer.Option(
            help="A TOML file of settings (the TACTUS_ names without the prefix, lower case: "
            'data = "/srv/memory"); flags and the environment win over it (env TACTUS_CONFIG).'
        ),
    ] = None,
    debug: Annotated[
        bool, typer.Option("--debug", help="Show the full traceback of a startup error.")
    ] = False,
) -> None:
    """Serve the memory over HTTP: writes, search, sessions, live touch (WebSocket).

    Every option can also come from the environment with the TACTUS_ prefix
    (TACTUS_DATA, TACTUS_TOKEN, TACTUS_MAX_BODY_BYTES, TACTUS_WINDOW, TACTUS_STRIDE, ...);
    options given here win. On a fresh store the default senses are registered: text, and
    touch with the shipped checkpoint.
    """
    from tactus_memory.service.startup import (
        check_checkpoint,
        check_location,
        check_space_options,
        check_touch_senses,
        explain,
        parse_touch_senses,
    )
    from tactus_memory.settings import Settings

    given = {
        "host": host,
        "port": port,
        "data": data,
        "token": token,
        "space": space,
        "space_path": space_path,
        "space_dim": space_dim,
        "touch_checkpoint": touch_checkpoint,
        "onnx": onnx,
        "workers": workers,
        "max_body_bytes": max_body_bytes,
        "window": window,
        "stride": stride,
        "log_level": log_level,
        "config": config,
    }
    overrides = {k: v for k, v in given.items() if v is not None}
    if no_touch:
        overrides["touch"] = False
    if no_maintain:
        overrides["maintain"] = False
    if torch:
        overrides["torch"] = True
    where = data or "the memory"
    try:
        if touch_sense:
            overrides["touch_senses"] = parse_touch_senses(touch_sense)
        settings = Settings(**overrides)
        where = settings.data
        check_location(settings.data)
        check_checkpoint(settings.touch_checkpoint if settings.touch else None)
        check_touch_senses(settings.touch_senses)
        check_space_options(settings.space_path, settings.onnx)
        settings = default_onnx(settings)
        if settings.workers > 1:  # forked before anything heavy is imported
            from tactus_memory.cli.workers import serve_workers, worker_torch_threads

            settings = worker_torch_threads(settings)
            say = lambda line: typer.echo(line, err=True)  # noqa: E731
            status = serve_workers(settings, settings.workers, say, (load_app, run_server), debug)
            if status:
                raise typer.Exit(status)
            return
        if settings.torch_threads is None and not settings.onnx:
            from tactus_memory.service.app import serving_torch_threads

            settings = settings.model_copy(update={"torch_threads": serving_torch_threads()})
        application = load_app(settings, say=lambda line: typer.echo(line, err=True))
    except typer.Exit:
        raise
    except Exception as exc:  # noqa: BLE001  (startup: one line and exit 2, unless --debug)
        if debug:  # the full traceback, printed here: the CLI's group turns errors into a line
            traceback.print_exc()
            raise typer.Exit(2) from None
        typer.echo(f"tactus serve: {explain(exc, where)}", err=True)
        raise typer.Exit(2) from None
    run_server(application, settings)
    failed = getattr(
        getattr(getattr(application, "state", None), "tactus", None), "load_error", None
    )
    if failed is not None:  # a model loading after the socket opened failed: same line, status
        if debug:
            traceback.print_exception(failed)
            raise typer.Exit(2)
        typer.echo(f"tactus serve: {explain(failed, where)}", err=True)
        raise typer.Exit(2)


@app.command("export-onnx")
def export_onnx(
    out: Annotated[str, typer.Argument(help="Folder to write minilm.onnx, touch.onnx into.")],
    touch_checkpoint: Annotated[
        str | None, typer.Option(help="Touch checkpoint to export (default: the shipped one).")
    ] = None,
) -> None:
    """Export MiniLM and the touch encoder to ONNX for `tactus serve --onnx OUT` (needs torch
    and the onnx extra here; the server then needs ONNX Runtime only)."""
    from tactus_memory.export.onnx import export_minilm, export_touch

    export_minilm(out)
    export_touch(out, touch_checkpoint)
    typer.echo(f"wrote {out}: serve with `tactus serve --onnx {out}`")


def default_onnx(settings: Any) -> Any:
    """``settings`` with ``onnx`` set to the default cache folder
    (:mod:`tactus_memory.export.cache`) when the server runs on ONNX Runtime by default: no
    folder named, no ``--torch``, and the MiniLM space (the default). The folder is filled,
    if it has to be, while the server starts (``load_app``)."""
    folder = None if settings.onnx else default_folder_of(settings)
    return settings.model_copy(update={"onnx": str(folder)}) if folder else settings


def page_url(settings: Any, port: int | None = None) -> str:
    """The browser page's URL (a wildcard bind address is reached through localhost)."""
    host = settings.host if settings.host not in ("0.0.0.0", "::", "") else "127.0.0.1"
    host = f"[{host}]" if ":" in host else host
    return f"http://{host}:{port or settings.port}/"


def load_app(
    settings: Any, say: Callable[[str], None], on_ready: Callable[[], None] | None = None
) -> Any:
    """Open the store now (step 1: a damaged store or a bad setting stops the command before
    anything listens), and build the app whose lifespan loads the text model and the touch
    encoder (steps 2 and 3, seconds each on a CPU; on the first start of the default ONNX
    server, step 2 exports MiniLM first) on a worker thread once the socket is
    open, saying what loads and how long each step took; ``/ready`` answers 503 naming the
    step until then."""
    from tactus_memory.export.cache import is_ready, prepare
    from tactus_memory.service.app import create_app, open_store, register_default_senses

    steps = 3
    folder = Path(settings.onnx) if settings.onnx else None
    # the default folder, on the first start: exported (and checked) before MiniLM loads
    export = folder is not None and not is_ready(folder) and folder == default_folder_of(settings)

    def step(i: int, what: str, fn: Callable[[], Any], state: Any = None) -> Any:
        say(f"[{i}/{steps}] {what} ...")
        if state is not None:
            state.starting = f"[{i}/{steps}] {what}"
        t0 = time.perf_counter()
        out = fn()
        say(f"[{i}/{steps}] {what}: done in {time.perf_counter() - t0:.1f} s")
        return out

    memory = step(1, f"opening the memory at {settings.data}", lambda: open_store(settings))
    name = getattr(memory.space, "name", settings.space)

    def text_model() -> None:
        if export:
            prepare(folder, settings.touch_checkpoint if settings.touch else None, say)
        memory.space.embed_texts(["warm up"], query=True)

    def finish(state: Any) -> str | None:
        text = f"loading the text model ({name})"
        step(2, text, text_model, state)
        touch = "loading the touch encoder"
        why = step(3, touch, lambda: register_default_senses(memory, settings), state)
        if why:
            say(f"touch is off: {why}")
        # what this start read, for the next start to read ahead (a thread: not on the way
        # to /ready)
        folders = [folder] if folder is not None else []
        threading.Thread(target=record_start_files, args=(folders,), daemon=True).start()
        if on_ready is not None:
            on_ready()  # a worker of several: /ready answers 200 once every one is
            say("ready: GET /ready answers 200 once every worker is")
        else:
            say("ready: GET /ready answers 200")
        return why

    return create_app(settings, memory=memory, loader=finish)


def default_folder_of(settings: Any) -> Path | None:
    """The default ONNX folder ``settings`` would get (None where it gets none)."""
    from tactus_memory.export.cache import default_folder

    if settings.torch or settings.space_path or settings.space not in (None, "minilm", "minilm-l6"):
        return None
    return default_folder(settings.touch_checkpoint if settings.touch else None)


def run_server(
    application: Any, settings: Any, sockets: list[Any] | None = None, worker: Any = None
) -> None:
    """uvicorn (tokens redacted in its logs); once it listens, print the page's URL.
    ``sockets``: listen there (a worker of ``--workers``, :mod:`tactus_memory.cli.workers`,
    whose ``worker`` group says which one it is)."""
    import uvicorn

    from tactus_memory.service.logs import log_config

    state = getattr(getattr(application, "state", None), "tactus", None)
    models = f"ONNX Runtime ({settings.onnx})" if settings.onnx else "torch"
    maintenance = "on" if settings.maintain else "off (tactus maintain)"
    if worker is not None:
        maintenance = "on" if settings.maintain else "off (worker 0 maintains)"
        maintenance += f"\n  worker:         {worker.index} of {worker.count}, pid {os.getpid()}"
    read_only = bool(getattr(state, "read_only", False))

    config = uvicorn.Config(
        application,
        host=settings.host,
        port=settings.port,
        log_level=settings.log_level,
        log_config=log_config(settings.log_level),
        ws_max_size=settings.max_ws_message_bytes,
        ws_per_message_deflate=False,  # noisy sensor frames hardly compress; save the CPU
        timeout_graceful_shutdown=5,
    )

    class Server(uvicorn.Server):
        async def on_tick(self, counter: int) -> bool:
            if getattr(state, "load_error", None) is not None:
                return True  # a model that loads after the socket opened failed: stop
            return await super().on_tick(counter)

        async def startup(self, sockets: Any = None) -> None:
            await super().startup(sockets=sockets)
            if self.started and worker is not None and worker.index != 0:
                # one banner for the group (worker 0's); the others say only who they are
                typer.echo(
                    f"  worker:         {worker.index} of {worker.count}, pid {os.getpid()}: "
                    "serving",
                    err=True,
                )
            elif self.started:
                bound = [s.getsockname() for srv in self.servers for s in (srv.sockets or [])]
                port = bound[0][1] if bound else settings.port  # --port 0: the one it got
                url = page_url(settings, port)
                typer.echo(
                    f"tactus-memory is serving {settings.data}\n"
                    f"  memory browser: {url}\n"
                    f"  API docs:       {url}docs\n"
                    f"  token:          {'required' if settings.token else 'off'}\n"
                    f"  maintenance:    {maintenance}\n"
                    f"  models run on:  {models}\n"
                    + ("  READ-ONLY store: writes answer 503\n" if read_only else "")
                    + "  (models load now: GET /ready answers 200 once 'ready' is printed; "
                    "Ctrl+C stops it)",
                    err=True,
                )

    Server(config).run(sockets=sockets)
