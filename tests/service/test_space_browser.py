"""The page on a served Qwen3-VL memory (tiny random model folder): image hits are drawn as
thumbnails, and "search by example" takes an image. Real uvicorn, Debian's Chromium."""

from __future__ import annotations

from pathlib import Path

import httpx
import pytest

pytest.importorskip("torch")
pytest.importorskip("transformers")

from tests.helpers.browser import ready_page  # noqa: E402
from tests.helpers.qwen_tiny import (
    build_tiny_qwen3vl,  # noqa: E402
    png_bytes,  # noqa: E402
)

pytestmark = pytest.mark.slow

TIMEOUT_MS = 60_000
HIT = "#results > li.hit"


def _thumb_loaded(page, selector: str) -> int:
    page.locator(selector).first.scroll_into_view_if_needed()
    page.wait_for_function(
        """sel => { const i = document.querySelector(sel);
                    return i !== null && i.complete && i.naturalWidth > 0; }""",
        arg=selector,
    )
    return page.eval_on_selector(selector, "i => i.naturalWidth")


def test_page_shows_image_thumbnails_and_searches_by_image(tmp_path: Path) -> None:
    from tests.helpers.servers import Server

    model = build_tiny_qwen3vl(tmp_path / "qwen")
    args = ("--space", "qwen3vl", "--space-path", str(model), "--no-touch")
    server = Server(tmp_path / "memory", tmp_path / "server.log", *args)
    picture = png_bytes(7, (120, 200))  # (H, W)
    try:
        with httpx.Client(base_url=server.base, timeout=120) as c:
            ids = []
            for i, body in enumerate([picture, png_bytes(8, (120, 200)), png_bytes(9, (90, 240))]):
                files = {"file": (f"p{i}.png", body, "image/png")}
                r = c.post("/sessions/cam/image", files=files, data={"t": str(float(i))})
                assert r.status_code == 201, r.text
                ids.append(r.json()["ids"][0])
        example = tmp_path / "example.png"
        example.write_bytes(picture)
        with ready_page(server.base, tmp_path / "profile", TIMEOUT_MS) as (page, errors):
            page.uncheck("#f-group")
            page.fill("#q", "a photo of a mug")
            page.click("#search-form button[type=submit]")
            page.wait_for_selector(HIT)
            senses = page.eval_on_selector_all(HIT, "els => els.map(e => e.dataset.sense)")
            assert set(senses) == {"image"} and len(senses) == 3
            assert _thumb_loaded(page, "#results img.thumb") == 160  # ?size=160, landscape
            alt = page.get_attribute("#results img.thumb", "alt")
            assert alt.startswith("Image in session cam")

            page.set_input_files("#like-file", str(example))
            page.click("#like-form button[type=submit]")
            page.wait_for_function(
                "() => document.querySelector('#search-status').textContent.includes('example.png')"
            )
            first = page.get_attribute(f"{HIT}:first-child", "data-id")
            assert first == ids[0]
            assert not page.is_hidden("#like-preview")
            assert not errors, errors
    finally:
        server.stop()
