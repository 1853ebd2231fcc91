"""The serving path's pieces for a sensor of any shape (issue 35), without models: heat maps of
a 12x16 five-pad hand and a 16x16 skin, the shape errors of the HTTP edge, the ``--touch
NAME=CKPT`` setting, and a MultiArray whose layout is another sensor's. The whole path (real
models, a real server) is ``tests/service/test_sensor_serving.py``."""

from __future__ import annotations

from dataclasses import dataclass
from types import SimpleNamespace

import numpy as np
import pytest
from pydantic import ValidationError
from typer.testing import CliRunner

from tactus_memory.adapters.decode import touch_frame
from tactus_memory.cli.app import app as cli_app
from tactus_memory.errors import InvalidInputError, RecordingError
from tactus_memory.recordings.samples import FLOAT32_ARRAY
from tactus_memory.service.arrays import as_window_array
from tactus_memory.service.startup import StartupError, check_touch_senses, parse_touch_senses
from tactus_memory.settings import Settings
from tactus_memory.touch.profile import STAG_GLOVE, SensorProfile, taxel_mask_from_spec
from tactus_memory.touch.render import (
    BACKGROUND,
    SCALE,
    draw_window_png,
    profile_mask,
    window_rgba,
    window_values,
)
from tests.helpers.browser import png_size
from tests.helpers.sensors import HAND, HAND_MASK, HAND_PADS, SKIN


@dataclass(frozen=True)
class PaddedProfile(SensorProfile):
    """A profile that carries its taxel mask (how a pad layout reaches the renderer)."""

    @property
    def taxel_mask(self) -> np.ndarray:
        return HAND_MASK


def _hand_window(k: int = 3) -> np.ndarray:
    """(k, 12, 16) raw: every pad pressed a little harder frame by frame, gaps at the offset."""
    w = np.full((k, *HAND.shape), HAND.offset, np.float32)
    for i in range(k):
        w[i][HAND_MASK] = HAND.offset + 100.0 * (i + 1)
    return w


def test_a_hand_is_drawn_with_its_pads_at_their_places():
    profile = PaddedProfile(**{**HAND.__dict__})
    assert np.array_equal(profile_mask(profile), HAND_MASK)
    rgba = window_rgba(_hand_window(), profile=profile)
    assert rgba.shape[:2] == (12 * SCALE, 3 * 16 * SCALE + 2 * SCALE)
    gap = rgba[6 * SCALE, 1 * SCALE]  # row 6, column 1 of frame 0: between thumb and palm
    palm = rgba[6 * SCALE, 6 * SCALE]  # row 6, column 6: the palm, pressed
    assert tuple(gap) == BACKGROUND and tuple(palm) != BACKGROUND
    for _, rows, cols in HAND_PADS:  # every pad lights up in the last frame
        x0 = 2 * (16 + 1) * SCALE + cols.start * SCALE
        assert tuple(rgba[rows.start * SCALE, x0]) != BACKGROUND
    vals = window_values(_hand_window(), profile=profile)
    assert np.array(vals["taxels"], bool).tolist() == HAND_MASK.tolist()
    lay = vals["layout"]
    assert (lay["frame_rows"], lay["frame_cols"], lay["width"]) == (12, 16, rgba.shape[1])


def test_a_profile_without_a_mask_is_its_whole_grid_and_the_glove_its_taxels():
    assert profile_mask(SKIN).all() and profile_mask(SKIN).shape == (16, 16)
    assert np.array_equal(profile_mask(STAG_GLOVE), taxel_mask_from_spec())
    png = draw_window_png(np.full((2, 16, 16), 2300, np.int16), profile=SKIN, legend=False)
    assert png_size(png) == (2 * 16 * SCALE + SCALE, 16 * SCALE, "RGBA")
    with pytest.raises(InvalidInputError, match=r"\(2, 32, 32\), expected \(K, 16, 16\)"):
        draw_window_png(np.full((2, 32, 32), 600, np.int16), profile=SKIN)
    bad = PaddedProfile(**{**SKIN.__dict__})  # a 12x16 mask on a 16x16 sensor
    with pytest.raises(InvalidInputError, match=r"taxel mask \(12, 16\).*\(16, 16\)"):
        profile_mask(bad)


def test_the_edge_names_both_shapes_and_the_sense():
    with pytest.raises(InvalidInputError, match=r"\(8, 32, 32\), expected \(K, 12, 16\).*'hand'"):
        as_window_array(np.zeros((8, 32, 32), np.float32), "K", "frames", HAND.shape, "hand")
    with pytest.raises(InvalidInputError, match=r"\(2, 8, 16, 16\), expected \(B, K, 12, 16\)"):
        as_window_array(np.zeros((2, 8, 16, 16), np.float32), "BK", "windows", HAND.shape, "hand")
    with pytest.raises(InvalidInputError, match=r"\(32, 32\), expected \(16, 16\)"):
        as_window_array([[500.0] * 32] * 32, "", "frame 3", SKIN.shape, "skin")
    assert as_window_array(np.zeros((1, 12, 16), np.float32), "K", "frames", HAND.shape).shape == (
        1,
        12,
        16,
    )


def test_touch_senses_setting_flag_and_environment(tmp_path, monkeypatch):
    ck = tmp_path / "skin.safetensors"
    ck.write_bytes(b"x")
    assert parse_touch_senses([f"skin={ck}", "hand=h.safetensors"]) == {
        "skin": str(ck),
        "hand": "h.safetensors",
    }
    for bad, why in (("skin", "NAME=CHECKPOINT"), ("=x", "NAME=CHECKPOINT")):
        with pytest.raises(StartupError, match=why):
            parse_touch_senses([bad])
    with pytest.raises(StartupError, match="named twice"):
        parse_touch_senses(["a=x", "a=y"])
    with pytest.raises(StartupError, match=r"--touch hand=nope.safetensors: .*not a file"):
        check_touch_senses({"skin": str(ck), "hand": "nope.safetensors"})
    with pytest.raises(ValidationError, match="glove's"):
        Settings(touch_senses={"touch": str(ck)})
    with pytest.raises(ValidationError, match="must match"):
        Settings(touch_senses={"Left-Hand": str(ck)})
    monkeypatch.setenv("TACTUS_TOUCH_SENSES", f'{{"skin": "{ck}"}}')
    assert Settings().touch_senses == {"skin": str(ck)}


def test_serve_refuses_a_touch_flag_it_cannot_use(tmp_path):
    r = CliRunner().invoke(cli_app, ["serve", "--data", str(tmp_path / "m"), "--touch", "skin"])
    assert r.exit_code == 2 and "expected NAME=CHECKPOINT" in r.output, r.output
    r = CliRunner().invoke(
        cli_app, ["serve", "--data", str(tmp_path / "m"), "--touch", "skin=missing.safetensors"]
    )
    assert r.exit_code == 2 and "missing.safetensors" in r.output, r.output


def _array_msg(values: np.ndarray, dims: tuple[int, ...]) -> SimpleNamespace:
    layout = SimpleNamespace(dim=[SimpleNamespace(size=d) for d in dims])
    return SimpleNamespace(layout=layout, data=values.reshape(-1).tolist())


def test_a_multiarray_is_read_in_the_sense_shape_its_layout_names():
    frame = np.arange(12 * 16, dtype=np.float32).reshape(12, 16)
    got = touch_frame(_array_msg(frame, (12, 16)), FLOAT32_ARRAY, HAND.shape, "t")
    assert np.array_equal(got, frame)
    assert touch_frame(_array_msg(frame, (1, 12, 16)), FLOAT32_ARRAY, HAND.shape, "t").shape
    assert touch_frame(_array_msg(frame, ()), FLOAT32_ARRAY, HAND.shape, "t").shape == (12, 16)
    # the same 192 values laid out 16x12 are another sensor: named, never reshaped
    with pytest.raises(RecordingError, match=r"layout is 16x12, but the sense reads 12x16"):
        touch_frame(_array_msg(frame, (16, 12)), FLOAT32_ARRAY, HAND.shape, "t")
