"""The bearer token on EVERY route of ``app.routes`` (issue 16): enumerated from the app, so a
route added later, or one whose router forgets the dependency, fails here."""

from __future__ import annotations

import pytest
from fastapi import Depends
from fastapi.testclient import TestClient
from starlette.routing import Route, WebSocketRoute

from tactus_memory.service.app import create_app
from tactus_memory.service.auth import OPEN as OPEN_SCOPE
from tactus_memory.service.auth import declared_scope
from tactus_memory.service.deps import authorize
from tactus_memory.settings import Settings
from tests.helpers.routes import OPEN, _concrete, _is_open, flat_routes
from tests.helpers.service import assert_problem, make_memory

TOKEN = "s3cret"
BAD = ({}, {"Authorization": "Bearer nope"}, {"Authorization": f"Basic {TOKEN}"})


@pytest.fixture
def app(tmp_path):
    return create_app(Settings(token=TOKEN), memory=make_memory(tmp_path / "mem"))


def test_every_http_route_needs_the_token(app) -> None:
    checked: list[str] = []
    with TestClient(app) as c:
        for route in flat_routes(app):
            if not isinstance(route, Route) or _is_open(route.path):
                continue
            for method in sorted((route.methods or set()) - {"HEAD", "OPTIONS"}):
                url = _concrete(route.path)
                for bad in BAD:
                    r = c.request(method, url, headers=bad, json={})
                    assert r.status_code == 401, f"{method} {route.path} {bad}: {r.status_code}"
                    assert_problem(r, 401, "token")
                    assert r.headers["www-authenticate"].startswith("Bearer")
                checked.append(f"{method} {route.path}")
        # the right token passes the gate (whatever the route then says about the body)
        for entry in checked:
            method, path = entry.split(" ", 1)
            r = c.request(method, _concrete(path), headers={"Authorization": f"Bearer {TOKEN}"})
            assert r.status_code != 401, entry
    assert len(checked) >= 20, checked  # the API has ~30 routes; an empty walk cannot pass


def test_open_routes_are_only_the_documented_ones(app) -> None:
    with TestClient(app) as c:
        opened = []
        for route in flat_routes(app):
            is_get = isinstance(route, Route) and "GET" in (route.methods or set())
            if is_get and c.get(_concrete(route.path)).status_code != 401:
                opened.append(route.path)
    assert {p for p in opened if p not in OPEN} <= {"/static/{name}", "/static/api-docs/{name}"}, (
        opened
    )
    assert "/health" in opened


def test_every_websocket_route_needs_the_token(app) -> None:
    routes = [r for r in flat_routes(app) if isinstance(r, WebSocketRoute)]
    assert routes
    with TestClient(app) as c:
        for route in routes:
            for query in ("", "?token=nope"):
                with c.websocket_connect(_concrete(route.path) + query) as ws:
                    msg = ws.receive_json()
                    assert msg["type"] == "error" and msg["error"]["status"] == 401, msg


def test_every_route_declares_its_scope(app) -> None:
    """Each route states the scope it needs in its own declaration (``auth.needs``), never
    by its function's name: a route with none fails here (FastAPI's own schema route
    aside). The POSTs that only search or render are read routes; the open ones are the
    documented ones."""
    routes = [r for r in flat_routes(app) if r.path != app.openapi_url]
    assert len(routes) >= 30
    assert [r.path for r in routes if declared_scope(r) is None] == []
    scope = {r.name: declared_scope(r) for r in routes}
    for name in ("search_like", "search_like_image", "render_touch_png"):
        assert scope[name] == "read", name
    assert scope["touch_stream"] == "write" and scope["add_touch"] == "write"
    assert scope["delete_session"] == scope["add_sense"] == "admin"
    opened = {r.path for r in routes if declared_scope(r) == OPEN_SCOPE}
    assert {p for p in opened if not _is_open(p)} == set(), opened
    assert {"/live", "/health", "/ready", "/"} <= opened


def test_a_route_that_declares_no_scope_is_refused_by_the_gate(app, caplog) -> None:
    """The gate fails closed: a route added behind ``authorize`` with no scope is an error,
    never an open or a write route."""
    app.add_api_route("/unscoped", lambda: {"ok": True}, dependencies=[Depends(authorize)])
    with TestClient(app) as c:
        r = c.get("/unscoped", headers={"Authorization": f"Bearer {TOKEN}"})
    assert r.status_code == 500 and "ok" not in r.text
    assert "route /unscoped declares no scope" in caplog.text
