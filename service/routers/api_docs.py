"""``/docs`` (Swagger UI) and ``/redoc`` (ReDoc) with their assets served from the installed
``fastapi-offline`` package, not a CDN: the API pages render on a robot with no network.
Open routes like the page (no token: they describe the routes, not the memory)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import fastapi_offline
from fastapi import APIRouter, HTTPException, Request
from fastapi.openapi.docs import (
    get_redoc_html,
    get_swagger_ui_html,
    get_swagger_ui_oauth2_redirect_html,
)
from fastapi.responses import FileResponse, HTMLResponse

from tactus_memory.service.deps import Open

#: Swagger UI's and ReDoc's own builds, as the package ships them
ASSETS = Path(fastapi_offline.__file__).resolve().parent / "static"
ASSET_TYPES = {
    "swagger-ui-bundle.js": "text/javascript; charset=utf-8",
    "swagger-ui.css": "text/css; charset=utf-8",
    "redoc.standalone.js": "text/javascript; charset=utf-8",
    "favicon.png": "image/png",
}
ASSET_PREFIX = "/static/api-docs"
OPENAPI_URL = "/openapi.json"
OAUTH2_REDIRECT_URL = "/docs/oauth2-redirect"

router = APIRouter(include_in_schema=False)


def _root(request: Request) -> str:
    return str(request.scope.get("root_path", "")).rstrip("/")


def _page(root: str, viewer: str) -> dict[str, Any]:
    """What both API pages take: the OpenAPI document under the app's root, and a title."""
    return {"openapi_url": root + OPENAPI_URL, "title": f"tactus-memory - {viewer}"}


@router.get("/docs", dependencies=[Open], response_class=HTMLResponse)
def swagger_ui(request: Request) -> HTMLResponse:
    root = _root(request)
    return get_swagger_ui_html(
        **_page(root, "Swagger UI"),
        oauth2_redirect_url=root + OAUTH2_REDIRECT_URL,
        swagger_js_url=f"{root}{ASSET_PREFIX}/swagger-ui-bundle.js",
        swagger_css_url=f"{root}{ASSET_PREFIX}/swagger-ui.css",
        swagger_favicon_url=f"{root}{ASSET_PREFIX}/favicon.png",
    )


@router.get(OAUTH2_REDIRECT_URL, dependencies=[Open], response_class=HTMLResponse)
def swagger_ui_redirect() -> HTMLResponse:
    return get_swagger_ui_oauth2_redirect_html()


@router.get("/redoc", dependencies=[Open], response_class=HTMLResponse)
def redoc(request: Request) -> HTMLResponse:
    root = _root(request)
    return get_redoc_html(
        **_page(root, "ReDoc"),
        redoc_js_url=f"{root}{ASSET_PREFIX}/redoc.standalone.js",
        redoc_favicon_url=f"{root}{ASSET_PREFIX}/favicon.png",
        with_google_fonts=False,
    )


@router.get(ASSET_PREFIX + "/{name}", dependencies=[Open])
def asset(name: str) -> FileResponse:
    if name not in ASSET_TYPES or not (ASSETS / name).is_file():
        raise HTTPException(404, f"no API docs asset {name!r}")
    return FileResponse(ASSETS / name, media_type=ASSET_TYPES[name])
