"""The memory browser (``/``) end to end in a real headless Chromium (Debian's package, driven by
Python Playwright) against a real uvicorn server (MiniLM space, LanceDB in tmp, the shipped
touch encoder or the stand-in: see ``tests/helpers/browser.py``), plus the heat-map renderer.

Screenshots go to pytest's tmp dir and are copied to ``runs/screenshots/`` (git-ignored).
Chromium missing is a FAILURE naming the install command, not a skip: CI installs it.
"""

from __future__ import annotations

import io
import json
import re
import shutil
import time

import httpx
import numpy as np
import pytest
from matplotlib import colormaps
from PIL import Image

from tactus_memory.datasets.home import CORE_SUBSET, data_home
from tactus_memory.errors import InvalidInputError
from tactus_memory.touch.profile import taxel_mask_from_spec
from tactus_memory.touch.render import (
    BACKGROUND,
    COLORMAP,
    GAP_COLOUR,
    LEGEND_PX,
    MIN_RANGE,
    OUTLINE_COLOUR,
    TouchScale,
    as_frames,
    calibrated_frames,
    contact_level,
    draw_window_png,
    pick_frames,
    touch_scale,
    window_rgba,
    window_values,
)
from tests.helpers.browser import (
    ROOT,
    SCREENSHOTS,
    TIMEOUT_MS,
    Server,
    add_notes,
    first_hit,
    launch,
    npy_bytes,
    png_size,
    shot,
    stag_windows,
    sync_playwright,
    synthetic_windows,
    wait_heatmaps_loaded,
)

STATIC = ROOT / "service" / "static"

# notes beside the touch windows (t = 1.5, 5.5, 9.5, 13.5: allen key set, ball, battery, eraser)
NOTES = [
    (1.0, "tightened a bolt with the allen key"),
    (5.0, "wiped the table with a soft wet sponge"),
    (9.0, "put the battery into the drawer"),
    (13.0, "picked up the blue mug by its handle"),
]


# ============================================================================ the renderer
def test_render_background_gaps_grid_and_colour_bar():
    window = np.full((3, 32, 32), 500.0, np.float32)  # raw units: rest
    window[1] = 650.0  # full scale
    rgba = window_rgba(window, scale=2, gap=1)
    assert rgba.shape == (64, 3 * 64 + 2 * 2, 4) and (rgba[..., 3] == 255).all()  # opaque
    mask = taxel_mask_from_spec()
    assert int(mask.sum()) == 548
    frame0 = rgba[::2, :64:2, :3]
    zero = np.array(colormaps[COLORMAP](0.0, bytes=True)[:3])
    assert (frame0[~mask] == BACKGROUND[:3]).all()  # unused taxels: background, not bars
    assert (frame0[mask] == zero).all()  # no contact: magma's darkest
    assert np.abs(np.array(BACKGROUND[:3]) - zero).sum() >= 30  # ... and the two differ
    assert (rgba[:, 64:66, :3] == GAP_COLOUR[:3]).all()  # the line between frames
    r, c = np.argwhere(mask)[0]
    full = rgba[2 * r, 66 + 2 * c, :3].astype(int)
    assert full.sum() > zero.sum() + 500  # bright at full pressure
    grid = window_rgba(np.zeros((8, 32, 32)), scale=1, columns=4)
    assert grid.shape == (2 * 33 - 1, 4 * 33 - 1, 4)  # 4 per row, 2 rows
    png = draw_window_png(window)
    assert png[:8] == b"\x89PNG\r\n\x1a\n"
    assert png_size(png) == (3 * 128 + 2 * 4, 128 + 4 + LEGEND_PX, "RGBA")  # + colour bar
    assert png_size(draw_window_png(window, legend=False)) == (3 * 128 + 2 * 4, 128, "RGBA")


def test_render_scale_fits_light_real_grasps():
    """Light contact (raw 540 = 0.27 calibrated, where real grasps sit) is drawn bright, not
    near-black as on a linear 0-1 scale; a quiet window's noise is not stretched."""
    window = np.full((2, 32, 32), 512, np.int16)  # rest
    window[:, 0:3, 0:10] = 540  # light contact on 60 taxels
    assert contact_level() == pytest.approx((520 - 500) / 150)  # raw 520: above the pedestal
    cal = calibrated_frames(as_frames(window))
    ts = touch_scale(cal, taxel_mask_from_spec())
    assert ts.hi == pytest.approx(40 / 150) and ts.gamma == 0.5
    rgba = window_rgba(window, scale=1)
    assert rgba[1, 5, :3].astype(int).sum() > 600  # the patch: magma's bright end
    assert (rgba[1, 20, :3] == colormaps[COLORMAP](0.0, bytes=True)[:3]).all()  # rest: dark
    quiet = np.full((1, 32, 32), 519, np.int16)
    quiet[0, 0, 0] = 523  # noise just above the contact level
    ts = touch_scale(calibrated_frames(quiet), taxel_mask_from_spec())
    assert ts.hi == pytest.approx(ts.lo + MIN_RANGE)  # not stretched to full brightness
    assert ts.unit(np.float32(ts.lo + MIN_RANGE / 4)) == pytest.approx(0.5, abs=1e-3)


def test_render_values_match_the_picture():
    rng = np.random.default_rng(3)
    window = rng.integers(505, 700, size=(6, 32, 32)).astype(np.int16)
    vals = window_values(window, scale=3, columns=4)
    lay = vals["layout"]
    assert (lay["columns"], lay["rows"], lay["scale"], lay["gap"]) == (4, 2, 3, 1)
    rgba = window_rgba(window, scale=3, columns=4)
    assert rgba.shape[:2] == (lay["height"], lay["width"])
    cal = calibrated_frames(window)
    assert np.allclose(vals["values"], cal, atol=1e-4) and vals["frames"] == list(range(6))
    assert np.array_equal(np.array(vals["taxels"], bool), taxel_mask_from_spec())
    ts = TouchScale(**vals["scale"])
    f, r, c = 5, 16, 3  # frame 5 sits in row 1, column 1 of the grid
    x, y = (f % 4) * 33 * 3 + c * 3, (f // 4) * 33 * 3 + r * 3
    want = colormaps[COLORMAP](ts.unit(cal[f, r, c]), bytes=True)[:3]
    assert tuple(rgba[y + 1, x + 1, :3]) == tuple(want)


def test_render_calibration_frames_and_errors():
    cal = np.full((2, 32, 32), 1.0, np.float32)
    raw = np.full((2, 32, 32), 650.0, np.float32)
    assert np.array_equal(window_rgba(cal), window_rgba(raw))  # 0..1 taken as calibrated
    assert np.array_equal(window_rgba(raw), window_rgba(raw, calibrated=False))
    assert png_size(draw_window_png(np.zeros((32, 32)), legend=False))[:2] == (128, 128)
    assert list(pick_frames(5)) == [0, 1, 2, 3, 4]
    picked = pick_frames(100, 16)
    assert len(picked) == 16 and picked[0] == 0 and picked[-1] == 99
    one_row = draw_window_png(np.zeros((100, 32, 32)), scale=1, legend=False)
    assert png_size(one_row)[:2] == (16 * 33 - 1, 32)
    for bad in (np.zeros((2, 32, 31)), np.full((1, 32, 32), np.nan), np.zeros((0, 32, 32))):
        with pytest.raises(InvalidInputError):
            draw_window_png(bad)
    with pytest.raises(InvalidInputError):
        draw_window_png(np.zeros((1, 32, 32)), scale=0)
    with pytest.raises(InvalidInputError):
        draw_window_png(np.zeros((1, 32, 32)), columns=0)


# ============================================================================ server + data
@pytest.fixture(scope="module")
def served(tmp_path_factory):
    """A real server with two sessions: notes, touch windows, motion vectors. The touch
    windows are real STAG grasps when the data folder has them (``data_home()``), otherwise
    STAG-format synthetic ones, so the page is tested on a fresh clone too; the test of a
    real grasp (``test_real_grasp_heat_map_shows_the_contact_area``) needs the real ones."""
    tmp = tmp_path_factory.mktemp("browser")
    stag = data_home().stag
    real = (stag / CORE_SUBSET / "metadata.mat").is_file()
    windows = stag_windows(stag, 6) if real else synthetic_windows(6)
    server = Server(tmp / "memory", tmp / "server.log")
    try:
        with httpx.Client(base_url=server.base, timeout=120) as c:
            ids = add_notes(c, "kitchen-demo", NOTES)
            for i, (w, name) in enumerate(windows[:4]):
                t = 1.5 + 4 * i
                body = {"frames": w.tolist(), "t": t, "t_end": t + 8 / 30, "meta": {"object": name}}
                r = c.post("/sessions/kitchen-demo/touch", json=body)
                assert r.status_code == 201, r.text
                ids[name] = r.json()["ids"][0]
            r = c.post("/senses", json={"name": "motion", "dim": 384, "encoder": "imu-demo"})
            assert r.status_code == 201, r.text
            vecs = np.random.default_rng(0).standard_normal((3, 384)).round(4).tolist()
            r = c.post(
                "/sessions/kitchen-demo/vectors",
                json={"sense": "motion", "vectors": vecs, "t": [0.5, 6.0, 12.0]},
            )
            assert r.status_code == 201, r.text
            for i, (w, name) in enumerate(windows[4:]):  # the .npy write path
                r = c.post(
                    "/sessions/glove-bench/touch",
                    content=npy_bytes(w),
                    params={"t": 100.0 + i},
                    headers={"content-type": "application/x-npy"},
                )
                assert r.status_code == 201, r.text
                ids[name] = r.json()["ids"][0]
            r = c.post("/sessions/glove-bench/text", json={"text": "bench check", "t": 100.0})
            assert r.status_code == 201, r.text
        yield {"server": server, "ids": ids, "windows": windows, "tmp": tmp, "real": real}
    finally:
        server.stop()


@pytest.fixture(scope="module")
def browser_context(served):
    with sync_playwright() as pw:
        context = launch(pw, served["tmp"] / "chromium-profile")
        try:
            yield context
        finally:
            context.close()


@pytest.fixture
def page(browser_context, served):
    """A fresh tab on the page; every request it makes is recorded."""
    page = browser_context.new_page()
    page.set_default_timeout(TIMEOUT_MS)
    requests: list[str] = []
    errors: list[str] = []
    page.on("request", lambda r: requests.append(r.url))
    page.on("pageerror", lambda e: errors.append(str(e)))
    page.goto(served["server"].base + "/")
    page.wait_for_selector("body[data-ready=true]")
    page.requests = requests  # type: ignore[attr-defined]
    page.js_errors = errors  # type: ignore[attr-defined]
    yield page
    assert not errors, f"JavaScript errors on the page: {errors}"
    own = served["server"].base + "/"
    foreign = [u for u in requests if not u.startswith((own, "data:", "blob:"))]
    assert not foreign, f"the page asked another origin: {foreign}"
    page.close()


#: plain hits, and the hits inside moments (the page groups into moments when the server can)
HIT = "#results li.hit:not(.moment)"


def top_result(page) -> dict:
    """The first result: a hit, or a moment with its member hits."""
    return page.eval_on_selector(
        "#results > li.hit",
        """li => { const hits = li.classList.contains('moment')
                       ? [...li.querySelectorAll('li.hit')] : [li];
                   return {moment: li.classList.contains('moment'),
                           ids: hits.map(h => h.dataset.id),
                           texts: hits.map(h => h.querySelector('.hit-text')?.textContent)}; }""",
    )


# ============================================================================ browser tests


def tab_to(page, element_id: str, presses: int = 60) -> None:
    """Move the focus with the Tab key alone until ``element_id`` has it."""
    for _ in range(presses):
        if page.evaluate("document.activeElement?.id") == element_id:
            return
        page.keyboard.press("Tab")
    assert page.evaluate("document.activeElement?.id") == element_id, (
        f"#{element_id} not reachable by Tab"
    )


@pytest.mark.slow
def test_keyboard_search_finds_the_note_first(page, served, tmp_path):
    # keyboard only: Tab to the sense filters and untick touch and motion with Space (with the
    # real touch encoder a squishy grasp may rightly outrank the note), then Tab to the query
    # box, type, Enter
    for sense in ("touch", "motion"):
        assert page.locator(f"#sense-{sense}").count() == 1, f"no #sense-{sense} box"
        tab_to(page, f"sense-{sense}")
        page.keyboard.press("Space")
        assert not page.is_checked(f"#sense-{sense}")
    page.keyboard.press("Shift+Tab")
    for _ in range(60):
        if page.evaluate("document.activeElement?.id") == "q":
            break
        page.keyboard.press("Shift+Tab")
    assert page.evaluate("document.activeElement?.id") == "q", "query box not reachable by Tab"
    page.keyboard.type("cleaning with something squishy")
    page.keyboard.press("Enter")
    page.wait_for_selector("#results > li.hit")
    top = top_result(page)
    sponge = "wiped the table with a soft wet sponge"
    assert served["ids"][sponge] in top["ids"], top
    # a moment must hold the note's text; a plain hit must be the note itself
    if top["moment"]:
        assert sponge in top["texts"] and len(top["ids"]) == len(top["texts"]), top
    else:
        assert top["texts"][0] == sponge, top
    status = page.text_content("#search-status")
    assert re.search(r"\d+ (hits?|moments?) for", status), status
    assert page.get_attribute("#search-status", "aria-live") == "polite"
    # every hit shows rank, sense badge, score, session and time
    head = page.text_content("#results > li.hit > .hit-head")
    assert "#1" in head and "score" in head and "session kitchen-demo" in head and " s" in head
    shot(page, tmp_path, "browser-search-text")


@pytest.mark.slow
def test_touch_hits_show_heat_maps(page, served, tmp_path):
    for sense in ("text", "motion"):
        page.uncheck(f"#sense-{sense}")
    page.fill("#f-session", "kitchen-demo")  # the windows ingested with an "object" meta
    page.uncheck("#f-group")  # plain ranked hits, whether or not they clear the match bar
    page.fill("#q", "gripping a small metal tool")
    page.click("#search-form button[type=submit]")
    page.wait_for_selector(HIT)
    senses = page.eval_on_selector_all(HIT, "els => els.map(e => e.dataset.sense)")
    assert senses and set(senses) == {"touch"}, senses
    wait_heatmaps_loaded(page, "#results img.heatmap")
    width = page.eval_on_selector("#results img.heatmap", "i => i.naturalWidth")
    assert width == 4 * 33 * 5 - 5  # 4 frames per row at 5 px per taxel, 5 px lines between
    alt = page.get_attribute("#results img.heatmap", "alt")
    assert alt.startswith("Pressure heat map of the touch window")
    # the hand regions outlined on every frame, in a colour the heat map never uses
    src = page.eval_on_selector("#results img.heatmap", "i => i.src")
    assert "outline=true" in src, src
    with Image.open(io.BytesIO(httpx.get(src, timeout=60).content)) as im:
        drawn = np.asarray(im.convert("RGBA"))
    assert (drawn == OUTLINE_COLOUR).all(axis=-1).sum() > 100
    # every hit says its sense's match bar; the status counts the hits that clear it
    bars = page.eval_on_selector_all(f"{HIT} .bar", "els => els.map(e => e.textContent)")
    assert len(bars) == len(senses) and all(re.search(r"bar \d+\.\d\d", b) for b in bars), bars
    assert re.search(r"\d+ clear the match bar", page.text_content("#search-status"))
    assert "object" in page.text_content(f"{HIT} .meta:not(.facets)")  # the user's meta
    assert "force" in page.text_content(f"{HIT} .meta.facets")  # the touch facets beside it
    # touch answers are grasps by default; "Touch as single windows" asks for windows
    grasps = page.eval_on_selector_all(f"{HIT} .grasp", "els => els.map(e => e.textContent)")
    assert grasps and all(re.fullmatch(r"grasp of \d+ windows?", g) for g in grasps), grasps
    page.check("#f-windows")
    page.click("#search-form button[type=submit]")
    page.wait_for_function(
        "() => document.querySelectorAll('#results li.hit').length > 0"
        " && document.querySelectorAll('#results li.hit .grasp').length === 0"
    )
    page.uncheck("#f-windows")
    # the same sense boxes again: all checked -> search every sense
    for sense in ("text", "motion"):
        page.check(f"#sense-{sense}")
    path = shot(page, tmp_path, "browser-search-touch")
    shutil.copy(path, SCREENSHOTS / "browser.png")  # the one for the report


#: a taxel is drawn "above no contact" when its colour differs from magma's darkest by more
#: than this (sum of |dR|+|dG|+|dB|; the first contact step is >= 25 away, screenshots are exact)
LIT = 12
#: contact in the raw data: above the resting pedestal (510-516 raw, stag-format.md) + margin
CONTACT_RAW = 520


@pytest.mark.slow
def test_real_grasp_heat_map_shows_the_contact_area(page, served, tmp_path, stag_dir):
    """A real STAG grasp of a known object (the ball), as a person sees it in the browser: in
    a screenshot of its heat map, the share of taxels drawn brighter than "no contact" matches
    the share of taxels in contact in the raw data; pointing at a taxel shows its value."""
    assert served["real"], f"the server was given synthetic windows although {stag_dir} exists"
    name = "ball"
    raw = next(w for w, n in served["windows"] if n == name)  # (8, 32, 32) int16
    item = served["ids"][name]
    for sense in ("text", "motion"):
        page.uncheck(f"#sense-{sense}")
    page.fill("#f-session", "kitchen-demo")
    page.uncheck("#f-group")
    page.fill("#q", "holding a ball")
    page.click("#search-form button[type=submit]")
    sel = f'{HIT}[data-id="{item}"] img.heatmap'
    page.wait_for_selector(sel)
    wait_heatmaps_loaded(page, sel)
    img = page.locator(sel)
    natural = img.evaluate("i => i.naturalWidth")
    SCREENSHOTS.mkdir(parents=True, exist_ok=True)
    crop = SCREENSHOTS / f"heatmap-real-{name}.png"
    img.screenshot(path=str(crop))
    shot(page, tmp_path, "browser-real-grasp")
    with Image.open(crop) as im:
        pix = np.asarray(im.convert("RGB"), dtype=np.int32)
    k = pix.shape[1] / natural  # screenshot px per image px (1 unless the page shrank it)
    mask = taxel_mask_from_spec()
    zero = np.array(colormaps[COLORMAP](0.0, bytes=True)[:3], np.int32)
    rows, cols = np.nonzero(mask)
    lit = []
    for f in range(raw.shape[0]):
        ox, oy = (f % 4) * 33 * 5, (f // 4) * 33 * 5  # 4 per row, 5 px per taxel
        ys = ((oy + rows * 5 + 2.5) * k).astype(int)
        xs = ((ox + cols * 5 + 2.5) * k).astype(int)
        lit.append(np.abs(pix[ys, xs] - zero).sum(axis=1) > LIT)
    drawn = float(np.mean(lit))
    contact = float(np.mean(raw[:, mask] > CONTACT_RAW))
    print(f"{name}: contact taxels in the data {contact:.3f}, drawn above background {drawn:.3f}")
    assert contact >= 0.03, "the chosen grasp should touch something"
    assert abs(drawn - contact) <= 0.01 + 0.05 * contact
    # the unused taxels are background, never lit
    off = np.argwhere(~mask)[100]
    y, x = (np.array(off) * 5 + 2.5) * k
    assert np.abs(pix[int(y), int(x)] - np.array(BACKGROUND[:3])).sum() <= LIT
    # hover the firmest taxel of frame 1: its calibrated value is shown
    cal = calibrated_frames(raw)
    r, c = np.unravel_index(int(np.argmax(np.where(mask, cal[0], -1))), mask.shape)
    want = f"frame 1, row {r}, column {c}: "
    readout = page.locator(f'{HIT}[data-id="{item}"] output.taxel-value')
    deadline = time.monotonic() + TIMEOUT_MS / 1000  # a liveness bound, as every wait here
    attempt = 0
    while True:  # the first hover fetches touch.json; later ones read it
        img.hover(position={"x": (c * 5 + 1 + attempt % 3) / k, "y": (r * 5 + 2) / k})
        if readout.text_content() or time.monotonic() > deadline:
            break
        attempt += 1
        page.wait_for_timeout(100)
    text = readout.text_content()
    assert text.startswith(want) and text.endswith(" calibrated (contact)"), text
    shown = float(text[len(want) :].split()[0])  # stored as float16, shown to 3 decimals
    assert shown == pytest.approx(float(cal[0, r, c]), abs=1.5e-3)
    assert img.get_attribute("title") == text


@pytest.mark.slow
def test_session_timeline_and_evidence(page, served, tmp_path):
    page.click("#tab-sessions")
    page.click(".session-button[data-session=kitchen-demo]")
    page.wait_for_selector("#timeline .lane")
    lanes = page.eval_on_selector_all(
        "#timeline .lane .track .point", "ps => [...new Set(ps.map(p => p.dataset.sense))].sort()"
    )
    assert lanes == ["motion", "text", "touch"], lanes
    n_points = page.eval_on_selector_all("#timeline .point", "ps => ps.length")
    assert n_points == len(NOTES) + 4 + 3
    status = page.text_content("#timeline-status")
    assert f"{n_points} items, from" in status, status
    # the force-over-time strip under the touch lane (issue 50): one vertex per window, the
    # firmest at the top of the strip
    strip = page.eval_on_selector(
        "#timeline .force-strip[data-sense=touch]",
        """s => ({label: s.getAttribute('aria-label'),
                 ys: s.querySelector('polyline').getAttribute('points').trim().split(' ')
                      .map(p => Number(p.split(',')[1]))})""",
    )
    assert len(strip["ys"]) == 4 and "touch force over time: 4 windows" in strip["label"]
    assert min(strip["ys"]) == pytest.approx(1.0)  # 23 - 22 x force / the firmest
    # a touch point: heat map + its meta
    touch_id = served["ids"]["ball"]
    page.click(f'#timeline .point[data-id="{touch_id}"]')
    page.wait_for_selector("#evidence:not([hidden])")
    wait_heatmaps_loaded(page, "#evidence img.heatmap")
    evidence = page.text_content("#evidence")
    assert "ball" in evidence and touch_id in evidence and "touch" in evidence
    assert "null" not in evidence
    if "session-filtered search" in status:  # fallback: the filler query's scores are hidden
        assert page.query_selector("#evidence .score") is None
    shot(page, tmp_path, "browser-timeline-touch")
    # keyboard: arrows move along the lane, Enter opens the evidence
    page.focus(f'#timeline .point[data-id="{touch_id}"]')
    page.keyboard.press("ArrowRight")
    focused = page.evaluate("document.activeElement.dataset.id")
    assert focused == served["ids"]["battery"]
    page.keyboard.press("ArrowUp")  # the lane above: text, nearest in time
    assert page.evaluate("document.activeElement.dataset.sense") == "text"
    page.keyboard.press("Enter")
    page.wait_for_selector("#evidence blockquote.hit-text")
    assert page.text_content("#evidence blockquote.hit-text") in {n for _, n in NOTES}
    # a hit's session link opens the timeline on that item
    page.click("#tab-search")
    page.fill("#q", "bench check")
    page.keyboard.press("Enter")
    page.wait_for_selector("#results > li.hit")
    page.click(f"{HIT} .session-link")
    page.wait_for_selector("#timeline .point.selected")
    assert page.text_content("#timeline-title") == "Timeline of glove-bench"


@pytest.mark.slow
def test_grouped_moments_or_graceful_fallback(page, served, tmp_path):
    paths = httpx.get(served["server"].base + "/openapi.json").json()["paths"]
    search_params = {p["name"] for p in paths["/search"]["get"].get("parameters", [])}
    supported = "/moments" in paths or "group" in search_params
    box = page.locator("#f-group")
    # this server has the grouped routes; the fallback is test_degrades_without_moments_...
    assert supported, "the server lost /moments and search?group="
    assert box.is_enabled() and box.is_checked() and page.is_hidden("#group-note")
    page.fill("#q", "the allen key")
    page.keyboard.press("Enter")
    page.wait_for_selector("#results > li.moment")
    assert re.search(r"\d+ moments? for", page.text_content("#search-status"))
    members = page.eval_on_selector_all(
        "#results > li.moment", "ms => ms.map(m => m.querySelectorAll('li.hit').length)"
    )
    assert members and all(n >= 1 for n in members)
    moments = page.eval_on_selector_all("#results > li.moment", "ms => ms.map(m => m.textContent)")
    # real grasps leave the note on top; synthetic windows (no real data) may outrank it
    assert "tightened a bolt with the allen key" in (
        moments[0] if served["real"] else " ".join(moments)
    )
    shot(page, tmp_path, "browser-moments")
    # the page says when the moments shown hold no matching touch window (issue 26)
    base = served["server"].base
    grouped = httpx.get(base + "/search", params={"q": "the allen key", "group": "moment"}).json()
    shown = [x for m in grouped["moments"] for x in m["hits"]]
    touch_shown = any(x["sense"] == "touch" and x["match"] for x in shown)
    nearest = httpx.get(base + "/search", params={"q": "the allen key", "sense": "touch", "k": 3})
    best = nearest.json()["hits"][0]
    if touch_shown:
        assert page.is_hidden("#touch-note")
    else:
        page.wait_for_selector("#touch-note:not([hidden])")
        note = page.text_content("#touch-note")
        assert f"the nearest touch window scores {best['score']:.2f}" in note, note
        assert "Group into moments" in note or "below the match bar" in note, note
    page.uncheck("#f-group")  # back to plain hits
    page.click("#search-form button[type=submit]")
    page.wait_for_selector("#results > li.hit:not(.moment)")


@pytest.mark.slow
def test_search_by_example_upload_npy_and_json(page, served, tmp_path):
    window, name = served["windows"][2]
    path = tmp_path / "example.npy"
    np.save(path, window.astype(np.uint16))
    page.set_input_files("#like-file", str(path))
    page.click("#like-form button[type=submit]")
    page.wait_for_selector("#results > li.hit")
    assert first_hit(page)["id"] == served["ids"][name]
    assert "the example example.npy (8 frames)" in page.text_content("#search-status")
    wait_heatmaps_loaded(page, "#like-preview img")
    wait_heatmaps_loaded(page, "#results img.heatmap")
    shot(page, tmp_path, "browser-search-by-example")

    window, name = served["windows"][5]  # stored through the .npy write path
    jpath = tmp_path / "example.json"
    jpath.write_text(json.dumps({"frames": window.tolist(), "calibrated": False}))
    page.set_input_files("#like-file", str(jpath))
    page.click("#like-form button[type=submit]")
    page.wait_for_function(
        "id => document.querySelector('#results > li.hit')?.dataset.id === id",
        arg=served["ids"][name],
    )
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps([[1, 2, 3]]))
    page.set_input_files("#like-file", str(bad))
    page.click("#like-form button[type=submit]")
    page.wait_for_function(
        "() => document.querySelector('#search-status').dataset.kind === 'error'"
    )
    # a 1x3 "frame": no touch sense reads it; the page names the shapes the senses read
    status = page.text_content("#search-status")
    assert "no touch sense reads 1×3 frames" in status and "touch 32×32" in status, status


@pytest.mark.slow
def test_senses_view_and_tab_keys(page, served, tmp_path):
    page.focus("#tab-search")
    page.keyboard.press("ArrowRight")
    page.keyboard.press("ArrowRight")
    assert page.evaluate("document.activeElement.id") == "tab-senses"
    page.wait_for_selector("#senses-list .sense-card")
    text = page.text_content("#senses-list")
    assert "imu-demo" in text and "Provenance" in text
    encoder = served["server"].touch_encoder
    assert encoder == "TactusEncoder (shipped checkpoint)", encoder
    assert "stand-in-touch" not in text and "tactus-lite" in text
    assert page.is_hidden("#view-search") and page.is_visible("#view-senses")
    shot(page, tmp_path, "browser-senses")


@pytest.mark.slow
def test_degrades_without_moments_and_timeline_routes(browser_context, served):
    """A server without GET /moments and GET /sessions/{id}/timeline (its OpenAPI schema
    rewritten in the browser): plain hits, and the timeline from a session-filtered search."""
    base = served["server"].base
    spec = httpx.get(base + "/openapi.json").json()
    for path in ("/moments", "/sessions/{session}/timeline"):
        spec["paths"].pop(path, None)
    search = spec["paths"]["/search"]["get"]  # and no GET /search?group=moment either
    search["parameters"] = [p for p in search["parameters"] if p["name"] not in ("group", "gap")]
    page = browser_context.new_page()
    page.set_default_timeout(TIMEOUT_MS)
    try:
        page.route(
            "**/openapi.json",
            lambda route: route.fulfill(
                status=200, content_type="application/json", body=json.dumps(spec)
            ),
        )
        page.goto(base + "/")
        page.wait_for_selector("body[data-ready=true]")
        assert page.locator("#f-group").is_disabled() and page.is_visible("#group-note")
        page.fill("#q", "put the battery away")
        page.keyboard.press("Enter")
        page.wait_for_selector("#results > li.hit:not(.moment)")
        assert page.query_selector("#results > li.moment") is None
        page.goto(base + "/#sessions/kitchen-demo")
        page.wait_for_selector("#timeline .lane")
        status = page.text_content("#timeline-status")
        assert "11 items, from a session-filtered search" in status, status
        page.click(f'#timeline .point[data-id="{served["ids"]["battery"]}"]')
        page.wait_for_selector("#evidence img.heatmap")
        assert page.query_selector("#evidence .score") is None  # the filler query's scores
    finally:
        page.close()


@pytest.mark.slow
def test_token_protected_server(browser_context, served, tmp_path):
    """With a token the page itself loads, says what is missing, and works once it is typed
    (heat maps are then fetched with the header and shown from blob: URLs)."""
    tmp = served["tmp"]
    server = Server(tmp / "memory-token", tmp / "server-token.log", token="s3cret")
    page = browser_context.new_page()
    page.set_default_timeout(TIMEOUT_MS)
    try:
        window, name = served["windows"][0]
        auth = {"Authorization": "Bearer s3cret"}
        with httpx.Client(base_url=server.base, headers=auth, timeout=120) as c:
            body = {"frames": window.tolist(), "t": 2.0, "meta": {"object": name}}
            assert c.post("/sessions/locked/touch", json=body).status_code == 201
            r = c.post("/sessions/locked/text", json={"text": "a secret grasp", "t": 2.0})
            assert r.status_code == 201
        assert httpx.get(f"{server.base}/items/x/touch.png").status_code == 401
        page.goto(server.base + "/")
        page.wait_for_selector("body[data-ready=true]")
        assert "access token" in page.text_content("#sense-filter")
        page.click(".token summary")
        page.fill("#token", "s3cret")
        page.keyboard.press("Enter")
        page.wait_for_selector("#sense-touch")
        page.uncheck("#sense-text")
        page.uncheck("#f-group")  # plain hits: moments keep only matches over the bar
        page.fill("#q", "a firm grasp")
        page.keyboard.press("Enter")
        page.wait_for_selector(HIT)
        wait_heatmaps_loaded(page, "#results img.heatmap")
        assert page.get_attribute("#results img.heatmap", "src").startswith("blob:")
        shot(page, tmp_path, "browser-token")
    finally:
        page.close()
        server.stop()


# ============================================================================ HTTP checks
@pytest.mark.slow
def test_png_routes_and_no_external_origin(served):
    base = served["server"].base
    ids = served["ids"]
    with httpx.Client(base_url=base, timeout=60) as c:
        r = c.get(f"/items/{ids['ball']}/touch.png")
        assert r.status_code == 200 and r.headers["content-type"] == "image/png"
        assert png_size(r.content) == (8 * 128 + 7 * 4, 128 + 4 + LEGEND_PX, "RGBA")
        q = {"scale": 1, "max_frames": 2, "legend": False}
        r = c.get(f"/items/{ids['ball']}/touch.png", params=q)
        assert png_size(r.content)[:2] == (2 * 32 + 1, 32)
        q = {"scale": 5, "columns": 4}
        r = c.get(f"/items/{ids['ball']}/touch.png", params=q)
        assert png_size(r.content)[:2] == (4 * 165 - 5, 2 * 165 - 5 + 4 + LEGEND_PX)
        v = c.get(f"/items/{ids['ball']}/touch.json", params=q).json()
        assert np.asarray(v["values"]).shape == (8, 32, 32) and v["frames"] == list(range(8))
        assert (v["layout"]["columns"], v["layout"]["rows"]) == (4, 2)
        assert v["scale"]["colormap"] == COLORMAP and v["scale"]["lo"] < v["scale"]["hi"]
        raw = [w for w, name in served["windows"] if name == "ball"][0]
        # the touch sense stores the calibrated window as float16: 1e-3 near 1
        assert np.allclose(v["values"], calibrated_frames(raw), atol=1e-3)
        assert c.get(f"/items/{ids[NOTES[0][1]]}/touch.json").status_code == 422
        r = c.get(f"/items/{ids[NOTES[0][1]]}/touch.png")
        assert r.status_code == 422 and "no touch window" in r.json()["detail"]
        assert r.headers["content-type"].startswith("application/problem+json")
        assert c.get("/items/nope/touch.png").status_code == 404
        assert c.get("/items/bad id!/touch.png").status_code == 422
        window = served["windows"][0][0]
        r = c.post("/render/touch.png", json={"frames": window.tolist()})
        assert r.status_code == 200 and png_size(r.content)[1] == 128 + 4 + LEGEND_PX
        assert c.post("/render/touch.png", json={"frames": [[1.0]]}).status_code == 422
        # the page and its assets: served, and no http(s) origin anywhere in them
        texts = {"/": c.get("/")}
        for name in ("app.js", "style.css"):
            texts[name] = c.get(f"/static/{name}")
        for name, resp in texts.items():
            assert resp.status_code == 200, name
            urls = re.findall(r"(?:https?:)?//[A-Za-z0-9.-]+\.[A-Za-z]{2,}", resp.text)
            assert not urls, f"{name} references external origins: {urls}"
        assert texts["/"].headers["content-type"].startswith("text/html")
        assert texts["app.js"].headers["content-type"].startswith("text/javascript")
        assert c.get("/static/../app.py").status_code == 404
        assert c.get("/static/nothing.js").status_code == 404
    assert {p.name for p in STATIC.iterdir()} >= {"index.html", "app.js", "style.css"}
