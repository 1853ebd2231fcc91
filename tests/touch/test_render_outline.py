"""Heat maps with the sensor's parts outlined (``outline=True``, what the page asks for): the
outline pixels are exactly the region edges of the glove's derived hand map, drawn in a colour
the magma map never reaches, and nothing else of the picture changes; a sensor without named
parts is drawn as without the option."""

from __future__ import annotations

import numpy as np
from matplotlib import colormaps

from tactus_memory.touch.profile import STAG_GLOVE
from tactus_memory.touch.regions import STAG_REGIONS
from tactus_memory.touch.render import COLORMAP, OUTLINE_COLOUR, region_edges, window_rgba
from tests.helpers.sensors import SKIN


def test_region_edges_of_a_small_map():
    idx = np.array([[0, 0, 1], [0, 0, 1], [-1, -1, -1]])
    got = region_edges(idx, 2)
    want = np.zeros((6, 6), bool)
    want[0:4, 3] = True  # region 0 | region 1: the last pixel column of column 1
    want[3, 0:4] = True  # region 0 above no region: the last pixel row of row 1
    want[3, 4:6] = True  # region 1 above no region
    assert np.array_equal(got, want), got.astype(int)
    assert not region_edges(np.full((3, 3), -1), 2).any()  # no regions: no outline


def test_the_glove_is_drawn_with_its_hand_regions_outlined():
    rng = np.random.default_rng(0)
    window = rng.integers(505, 700, size=(3, 32, 32)).astype(np.float32)
    plain = window_rgba(window, profile=STAG_GLOVE, scale=5)
    lined = window_rgba(window, profile=STAG_GLOVE, scale=5, outline=True)
    edges = region_edges(STAG_REGIONS.index, 5)
    assert edges.sum() > 100
    changed = np.any(plain != lined, axis=-1)
    for f in range(3):  # every frame: the changed pixels are the edges, drawn in the outline
        x0 = f * 33 * 5
        frame_changed = changed[:, x0 : x0 + 160]
        assert np.array_equal(
            frame_changed, edges & np.any(plain[:, x0 : x0 + 160] != OUTLINE_COLOUR, axis=-1)
        )
        assert (lined[:, x0 : x0 + 160][edges] == OUTLINE_COLOUR).all()
    # the colour is not one magma draws, so an outline never reads as pressure
    magma = colormaps[COLORMAP](np.linspace(0, 1, 256), bytes=True)[:, :3].astype(int)
    assert np.abs(magma - np.array(OUTLINE_COLOUR[:3])).sum(axis=1).min() > 100


def test_a_sensor_without_named_parts_is_drawn_as_without_the_option():
    window = np.full((2, *SKIN.shape), SKIN.offset + 300.0, np.float32)
    plain = window_rgba(window, profile=SKIN)
    assert np.array_equal(window_rgba(window, profile=SKIN, outline=True), plain)
