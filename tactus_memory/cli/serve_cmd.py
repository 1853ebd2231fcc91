"""``tactus serve``: the HTTP service on uvicorn (one process; the memory serialises writes)."""

from __future__ import annotations

from typing import Annotated

import typer

from tactus_memory.cli.app import app


@app.command()
def serve(
    host: Annotated[str | None, typer.Option(help="Bind address (default 127.0.0.1).")] = None,
    port: Annotated[int | None, typer.Option(help="Port (default 8000).")] = None,
    data: Annotated[
        str | None,
        typer.Option(help="Memory directory or URI (s3://, gs://, az://) (env TACTUS_DATA)."),
    ] = None,
    token: Annotated[
        str | None,
        typer.Option(
            help="Require 'Authorization: Bearer <token>' on every route but the open ones "
            "(/health, /live, /ready, /, /static, /docs, /redoc, /openapi.json) (env "
            "TACTUS_TOKEN). Must not be empty. WebSocket clients may pass ?token= instead; "
            "it is redacted in the logs."
        ),
    ] = None,
    space: Annotated[
        str | None, typer.Option(help="Space for a fresh store (default minilm).")
    ] = None,
    max_body_bytes: Annotated[
        int | None,
        typer.Option(help="Largest request body, 413 beyond (env TACTUS_MAX_BODY_BYTES)."),
    ] = None,
    window: Annotated[
        int | None, typer.Option(help="Default frames per window on touch streams (default 8).")
    ] = None,
    stride: Annotated[
        int | None, typer.Option(help="Frames between window starts on touch streams (default 8).")
    ] = None,
    no_touch: Annotated[
        bool, typer.Option("--no-touch", help="Do not load the touch encoder.")
    ] = False,
    log_level: Annotated[str | None, typer.Option(help="uvicorn log level (default info).")] = None,
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
    import uvicorn

    from tactus_memory.service.logs import log_config
    from tactus_memory.service.startup import check_location, explain

    given = {
        "host": host,
        "port": port,
        "data": data,
        "token": token,
        "space": space,
        "max_body_bytes": max_body_bytes,
        "window": window,
        "stride": stride,
        "log_level": log_level,
    }
    overrides = {k: v for k, v in given.items() if v is not None}
    if no_touch:
        overrides["touch"] = False
    where = data or "the memory"
    try:
        from tactus_memory.service.app import create_app
        from tactus_memory.service.settings import Settings

        settings = Settings(**overrides)
        where = settings.data
        check_location(settings.data)
        application = create_app(settings)
    except Exception as exc:  # noqa: BLE001  (startup: one line and exit 2, unless --debug)
        if debug:
            raise
        typer.echo(f"tactus serve: {explain(exc, where)}", err=True)
        raise typer.Exit(2) from None
    state = getattr(getattr(application, "state", None), "tactus", None)
    read_only = bool(getattr(state, "read_only", False))
    typer.echo(
        f"tactus-memory serving {settings.data} on http://{settings.host}:{settings.port} "
        f"(docs at /docs; token {'required' if settings.token else 'off'}"
        f"{'; READ-ONLY store: writes answer 503' if read_only else ''})",
        err=True,
    )
    uvicorn.run(
        application,
        host=settings.host,
        port=settings.port,
        log_level=settings.log_level,
        log_config=log_config(),
        ws_max_size=settings.max_ws_message_bytes,
        ws_per_message_deflate=False,  # noisy sensor frames hardly compress; save the CPU
        timeout_graceful_shutdown=5,
    )
