"""The bearer token on EVERY route of ``app.routes`` (issue 16): enumerated from the app, so a
route added later, or one whose router forgets the dependency, fails here."""

from __future__ import annotations

import pytest
from fastapi.testclient import TestClient
from starlette.routing import Route, WebSocketRoute

from tactus_memory.service.app import create_app
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
