"""``/docs`` and ``/redoc`` render with no network: their HTML names no other host, and every
script, stylesheet and icon it loads is served by the app itself (from the installed
package), without a token, as the docs pages are open routes."""

from __future__ import annotations

import re

import pytest
from fastapi.testclient import TestClient

from tactus_memory.service.app import create_app
from tactus_memory.settings import Settings
from tests.helpers.service import make_memory

TOKEN = "s3cret"
LINKED = re.compile(r"""(?:src|href)\s*=\s*["']([^"']+)["']""")
URL_IN_SCRIPT = re.compile(r"""(?:url|spec-url)\s*[:=]\s*["']([^"']+)["']""")


@pytest.fixture
def client(tmp_path):
    app = create_app(Settings(token=TOKEN), memory=make_memory(tmp_path / "mem"))
    with TestClient(app) as c:
        yield c


@pytest.mark.parametrize(
    ("page", "assets"),
    [
        ("/docs", {"swagger-ui-bundle.js", "swagger-ui.css", "favicon.png"}),
        ("/redoc", {"redoc.standalone.js", "favicon.png"}),
    ],
)
def test_api_pages_load_everything_from_the_server(client, page: str, assets: set[str]) -> None:
    r = client.get(page)
    assert r.status_code == 200 and r.headers["content-type"].startswith("text/html")
    html = r.text
    assert not re.search(r"(?:https?:)?//[A-Za-z0-9.-]+\.[A-Za-z]{2,}", html), html
    linked = LINKED.findall(html)
    assert {u.rsplit("/", 1)[-1] for u in linked} >= assets, linked
    assert "/openapi.json" in URL_IN_SCRIPT.findall(html) + [
        m for m in re.findall(r"""spec-url=["']([^"']+)""", html)
    ]
    for url in linked:
        assert url.startswith("/"), url  # the same server, no other host
        got = client.get(url)  # no token: open like the page
        assert got.status_code == 200, (url, got.status_code)
        assert len(got.content) > 1000, url
        kind = got.headers["content-type"]
        assert kind.split(";")[0] in {"text/javascript", "text/css", "image/png"}, (url, kind)


def test_only_the_shipped_assets_are_served(client) -> None:
    assert client.get("/static/api-docs/core.py").status_code == 404
    assert client.get("/static/api-docs/..%2F__init__.py").status_code == 404
    assert client.get("/docs/oauth2-redirect").status_code == 200
    assert client.get("/sessions").status_code == 401  # the API itself stays behind the token
