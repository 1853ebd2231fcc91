"""The page's top-down map (issue 23) in a real headless Chromium against a real uvicorn
server (MiniLM, LanceDB in tmp; ``tests/helpers/browser.py``): a session's trajectory is drawn,
and a search in the session puts its hits where they happened."""

from __future__ import annotations

import math

import httpx
import numpy as np
import pytest

from tests.helpers.browser import Server, add_notes, ready_page, shot

pytestmark = pytest.mark.slow

TIMEOUT_MS = 60_000
# an L-shaped walk: 10 s along x at 1 m/s, then 10 s along y; poses at 10 Hz
T = np.round(np.arange(0.0, 20.0 + 1e-9, 0.1), 6)
X = np.minimum(T, 10.0)
Y = np.maximum(T - 10.0, 0.0)
NOTES = [
    (2.0, "picked up the cordless drill"),
    (15.0, "put the coffee mug on the shelf"),
    (8.0, "opened the fridge door"),
]


@pytest.fixture(scope="module")
def served(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("browser-map")
    server = Server(tmp / "memory", tmp / "server.log")
    try:
        with httpx.Client(base_url=server.base, timeout=120) as c:
            ids = add_notes(c, "walk", NOTES)
            body = {"t": T.tolist(), "position": np.column_stack([X, Y, 0 * T]).tolist()}
            r = c.post("/sessions/walk/poses", json=body)  # after the notes: backfill
            assert r.status_code == 201, r.text
            r = c.post("/sessions/no-poses/text", json={"text": "a note", "t": 1.0})
            assert r.status_code == 201, r.text
        yield {"server": server, "ids": ids, "tmp": tmp}
    finally:
        server.stop()


@pytest.fixture
def page(served):
    profile = served["tmp"] / "chromium-profile"
    with ready_page(served["server"].base, profile, TIMEOUT_MS) as (page, errors):
        yield page
        assert not errors, f"JavaScript errors on the page: {errors}"


def _vertices(page) -> list[tuple[float, float]]:
    pts = page.get_attribute("#map polyline.trajectory", "points") or ""
    return [tuple(map(float, p.split(","))) for p in pts.split()]  # type: ignore[misc]


def test_map_draws_the_trajectory_and_the_hits_where_they_happened(page, served, tmp_path):
    page.click("#tab-sessions")
    page.click(".session-button[data-session=walk]")
    page.wait_for_selector("#map polyline.trajectory")
    assert page.get_attribute("#map polyline.trajectory", "data-poses") == str(T.size)
    verts = _vertices(page)
    assert len(verts) == T.size
    # top-down, y up: the first leg goes right, the second goes up the screen
    assert verts[100][0] > verts[0][0] and abs(verts[100][1] - verts[0][1]) < 1e-6
    assert verts[200][1] < verts[100][1] and abs(verts[200][0] - verts[100][0]) < 1e-6
    # one scale for both axes: both legs are 10 m long
    assert math.dist(verts[0], verts[100]) == pytest.approx(math.dist(verts[100], verts[200]))
    assert "201 poses in frame map" in page.text_content("#map-status")

    page.fill("#map-q", "where was I holding the drill?")
    page.click("#map-form button[type=submit]")
    page.wait_for_selector("#map circle.map-hit")
    best = page.locator("#map circle.map-hit.best")
    assert best.get_attribute("data-id") == served["ids"]["picked up the cordless drill"]
    assert best.get_attribute("data-rank") == "1"
    # drawn on the trajectory where the robot was at t = 2 s (pose 20)
    cx, cy = float(best.get_attribute("cx")), float(best.get_attribute("cy"))
    assert math.dist((cx, cy), verts[20]) < 0.02
    mug = page.locator(
        f'#map circle.map-hit[data-id="{served["ids"]["put the coffee mug on the shelf"]}"]'
    )
    assert (
        math.dist((float(mug.get_attribute("cx")), float(mug.get_attribute("cy"))), verts[150])
        < 0.02
    )
    assert page.locator("#map circle.map-hit").count() == len(NOTES)
    assert "3 of 3 hits" in page.text_content("#map-status")
    listed = page.text_content("#map-hits")
    assert "at (2.00, 0.00, 0.00) in map" in listed
    shot(page, tmp_path, "browser-map")
    # the keyboard reaches a hit and Enter opens its evidence beside the timeline
    best.focus()
    page.keyboard.press("Enter")
    page.wait_for_selector("#evidence:not([hidden])")
    assert "cordless drill" in page.text_content("#evidence")
    assert "(2.00, 0.00, 0.00) in map" in page.text_content("#evidence")


def test_session_without_poses_says_so(page, served):
    page.click("#tab-sessions")
    page.click(".session-button[data-session=no-poses]")
    page.wait_for_selector("#map-panel:not([hidden])")
    page.wait_for_function("document.querySelector('#map-status').textContent.length > 0")
    assert "No poses for this session" in page.text_content("#map-status")
    assert page.locator("#map polyline").count() == 0
    assert page.is_hidden("#map-form")
