"""The page with a sensor that is not the glove (issue 35): a real ``tactus serve --touch
hand=CKPT`` (the five-pad hand of ``tests/helpers/sensors.py``, trained here), the page in Debian's
Chromium. The Senses tab shows the hand's frame shape and what it recognises; search by
example with a 12x16 ``.npy`` picks the hand sense by its shape, finds the stored window, and
the heat maps of the example and of the hits load."""

from __future__ import annotations

import httpx
import numpy as np
import pytest

from tactus_memory.touch.render import LEGEND_PX
from tests.helpers.browser import TIMEOUT_MS, first_hit, ready_page, wait_heatmaps_loaded
from tests.helpers.sensors import session_checkpoint, stag, windows  # noqa: F401  (fixtures)
from tests.helpers.servers import Server

pytestmark = pytest.mark.slow


def test_the_page_reads_a_hand(tmp_path, tmp_path_factory, stag, windows, minilm_space):  # noqa: F811
    # the hand checkpoint of tests/service/test_sensor_serving.py, trained once per session
    ck = session_checkpoint(tmp_path_factory, "hand", stag, minilm_space)
    server = Server(tmp_path / "memory", tmp_path / "server.log", "--touch", f"hand={ck}")
    raw = windows.of("hand")  # (N, 8, 12, 16)
    try:
        with httpx.Client(base_url=server.base, timeout=120) as c:
            body = {"windows": raw.tolist(), "t": [float(i) for i in range(len(raw))]}
            r = c.post("/sessions/bench/touch", params={"sense": "hand"}, json=body)
            assert r.status_code == 201, r.text
            ids = r.json()["ids"]
        example = tmp_path / "hand_example.npy"
        np.save(example, raw[3].astype(np.uint16))
        with ready_page(server.base, tmp_path / "chromium-profile", TIMEOUT_MS) as (page, errors):
            page.click("#tab-senses")
            page.wait_for_selector("#senses-list .sense-card")
            text = page.text_content("#senses-list")
            assert "12 × 16 taxels" in text and "32 × 32 taxels" in text, text
            page.click("#tab-search")
            page.set_input_files("#like-file", str(example))
            page.click("#like-form button[type=submit]")
            page.wait_for_selector("#results > li.hit")
            top = first_hit(page)
            assert top["id"] == ids[3] and top["sense"] == "hand", top
            # the window's facets beside its heat map (issue 50); this hand has no regions
            facets = page.text_content("#results > li.hit .facets")
            assert "force" in facets and "area" in facets and "peak" in facets, facets
            wait_heatmaps_loaded(page, "#like-preview img")
            wait_heatmaps_loaded(page, "#results img.heatmap")
            size = page.eval_on_selector(
                "#results img.heatmap", "i => [i.naturalWidth, i.naturalHeight]"
            )
            # the page draws 4 frames a row at 5 px a taxel: 2 rows of 16 x 12 taxel frames
            px, gap = 5, 5
            want = [4 * 16 * px + 3 * gap, 2 * 12 * px + gap + 4 + LEGEND_PX]
            assert size == want, size
            assert not errors, errors
    finally:
        server.stop()
