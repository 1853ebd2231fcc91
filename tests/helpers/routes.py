import re

from starlette.routing import BaseRoute


def flat_routes(app) -> list[BaseRoute]:
    """``app.routes`` with included routers expanded (FastAPI >= 0.16x keeps an included
    router as one lazy entry that expands to its effective, prefixed routes)."""
    out: list[BaseRoute] = []
    for route in app.routes:
        expand = getattr(route, "effective_route_contexts", None)
        if expand is None:
            out.append(route)
            continue
        for ctx in expand():
            out.append(ctx.starlette_route or ctx.original_route)
    return out


def _concrete(path: str) -> str:
    return re.sub(r"\{[^}]+\}", "s1", path)  # every path parameter: a valid id


def _is_open(path: str) -> bool:
    return path in OPEN or path.startswith(OPEN_PREFIXES)


#: the documented open routes (README "Trust"): /live, /health, /ready, the static page, plus
#: FastAPI's own schema/doc pages (no data: they describe the routes, not the memory)
OPEN = {
    "/live",
    "/health",
    "/ready",
    "/",
    "/openapi.json",
    "/docs",
    "/docs/oauth2-redirect",
    "/redoc",
}


OPEN_PREFIXES = ("/static",)
