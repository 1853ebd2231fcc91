"""Facets on synthetic grasps whose answers are known by construction: a five-pad robot hand
(examples/sensors/five-pad-hand.toml) and a 16x16 skin without regions."""

from __future__ import annotations

import numpy as np
import pytest

from tactus_memory.errors import InvalidInputError
from tactus_memory.touch.facets import (
    ACTIVE_SHARE,
    CAPTION_RULE,
    FIRM_PRESSURE,
    LIGHT_PRESSURE,
    LONG_HOLD_S,
    SLIP_SPEED,
    caption,
    grasp_facets,
    grip_of,
    window_facets,
)
from tactus_memory.touch.profile import STAG_GLOVE, SensorProfile
from tactus_memory.touch.regions import STAG_REGIONS, regions_of
from tactus_memory.touch.sensor_file import load_profile_toml
from tactus_memory.touch.windows import contact_level
from tests.helpers.hand_synth import HAND_TOML

HAND = load_profile_toml(HAND_TOML)  # thumb, index, middle, ring 4x4 in rows 0-3; palm 8x8
SKIN = SensorProfile("skin16", offset=0.0, span=1.0, shape=(16, 16))
PAD_AT = {p.name: (p.top, p.left) for p in HAND.pads}


def press(frames: np.ndarray, pad: str, value: float, rows: int = 2, cols: int = 2) -> None:
    """Set a rows x cols block at the top-left of ``pad`` to ``value`` in every frame."""
    r, c = PAD_AT[pad]
    frames[..., r : r + rows, c : c + cols] = value


def hand_window(pads: dict[str, float], k: int = 4, rows: int = 2) -> np.ndarray:
    w = np.zeros((k, *HAND.shape), np.float32)
    for pad, v in pads.items():
        press(w, pad, v, rows=rows, cols=rows)
    return w


def test_window_facets_of_a_pinch_on_the_five_pad_hand() -> None:
    w = hand_window({"thumb": 0.5, "index": 0.25})  # 4 taxels each, every frame
    f = window_facets(w, HAND).row(0)
    assert f["force"] == pytest.approx(4 * 0.5 + 4 * 0.25)
    taxels = 4 * 16 + 64  # the pads' taxels: the profile's mask
    assert f["area"] == pytest.approx(8 / taxels)
    assert f["peak"] == pytest.approx(0.5)
    assert f["regions"] == pytest.approx(
        {"thumb": 2 / 3, "index": 1 / 3, "middle": 0, "ring": 0, "palm": 0}
    )
    # contact-load-weighted position: thumb block rows 0-1 cols 0-1, index cols 4-5
    assert f["centroid"] == pytest.approx([0.5, (2 / 3) * 0.5 + (1 / 3) * 4.5])
    assert f["grip"] == "pinch"


@pytest.mark.parametrize(
    ("pads", "grip"),
    [
        ({"thumb": 0.5, "index": 0.5}, "pinch"),
        ({"thumb": 0.5, "index": 0.5, "middle": 0.5}, "tripod"),
        ({"index": 0.4, "middle": 0.4, "ring": 0.4, "palm": 0.6}, "power"),
        ({"palm": 0.6}, "press"),
        ({"middle": 0.6}, "press"),
        ({"index": 0.5, "middle": 0.5}, "other"),
        ({}, "none"),
    ],
)
def test_grip_rule_on_synthetic_grasps(pads: dict[str, float], grip: str) -> None:
    assert window_facets(hand_window(pads), HAND).row(0)["grip"] == grip


def test_grip_rule_ignores_a_region_under_the_active_share() -> None:
    # thumb and index carry the load, the palm a sliver (1 taxel at 0.2 of 4.2): still a pinch
    w = hand_window({"thumb": 0.5, "index": 0.5})
    w[:, 6, 6] = 0.2
    f = window_facets(w, HAND).row(0)
    assert 0 < f["regions"]["palm"] < ACTIVE_SHARE
    assert f["grip"] == "pinch"
    assert grip_of({"thumb": 0.45, "index": 0.45, "palm": 0.10}) == "power"


def test_below_the_contact_level_is_force_but_not_contact() -> None:
    lvl = contact_level(HAND)
    w = hand_window({"palm": lvl * 0.9})
    f = window_facets(w, HAND).row(0)
    assert f["force"] == pytest.approx(4 * lvl * 0.9, rel=1e-6)
    assert f["area"] == 0 and f["centroid"] is None and f["grip"] == "none"


def test_skin_without_regions_force_area_centroid_spread() -> None:
    """A 16x16 skin: a 4x4 block at rows 2-5, cols 8-11, at 0.5 in frame 0 and 1.0 in frame 1."""
    w = np.zeros((2, 16, 16), np.float32)
    w[0, 2:6, 8:12] = 0.5
    w[1, 2:6, 8:12] = 1.0
    f = window_facets(w, SKIN).row(0)
    assert f["force"] == pytest.approx((16 * 0.5 + 16 * 1.0) / 2)
    assert f["area"] == pytest.approx(16 / 256)
    assert f["peak"] == 1.0
    assert f["centroid"] == pytest.approx([3.5, 9.5])
    assert f["spread"] == pytest.approx(np.sqrt(2 * 1.25))  # var of 0..3 is 1.25, per axis
    assert f["regions"] == {} and f["grip"] is None
    assert regions_of(SKIN) is None


def test_newtons_factor_scales_force_only() -> None:
    w = np.zeros((1, 16, 16), np.float32)
    w[0, 0, 0] = 0.5
    f = window_facets(w, SKIN, newtons_per_unit=20.0).row(0)
    assert f["force"] == pytest.approx(10.0) and f["peak"] == 0.5


def test_window_facets_are_vectorised_over_windows() -> None:
    rng = np.random.default_rng(0)
    batch = rng.uniform(0, 0.4, (5, 3, *HAND.shape)).astype(np.float32)
    together = window_facets(batch, HAND).rows()
    one_by_one = [window_facets(b, HAND).row(0) for b in batch]
    assert together == one_by_one


def test_grasp_facets_onset_release_peak_ramp_slip() -> None:
    """Four windows of 1 s, every 0.5 s; force 1, 3, 2, 1; the contact slides one taxel per
    window along the skin's row 8 (a slip of 1 taxel per 0.5 s = 2 taxels/s)."""
    wins = np.zeros((4, 2, 16, 16), np.float32)
    for i, level in enumerate((1.0, 3.0, 2.0, 1.0)):
        wins[i, :, 8, 2 + i : 2 + i + 4] = level / 4  # 4 taxels; force = level
    t = np.array([10.0, 10.5, 11.0, 11.5])
    perm = [2, 0, 3, 1]  # windows in any order: sorted by t inside
    g = grasp_facets(window_facets(wins[perm], SKIN), t[perm], t[perm] + 1.0)
    assert g["force"] == pytest.approx(3.0)
    assert (g["onset"], g["release"], g["duration"]) == (10.0, 12.5, 2.5)
    assert g["peak_time"] == pytest.approx(11.0)  # the middle of the window at 10.5-11.5
    assert g["ramp"] == pytest.approx((3.0 - 1.0) / 0.5)
    assert g["slip"] == pytest.approx(2.0)
    assert g["grip"] is None and g["regions"] == {}


def test_grasp_regions_weigh_windows_by_load_and_name_the_grip() -> None:
    a = hand_window({"thumb": 0.5, "index": 0.5})  # pinch, load 4
    b = hand_window({"palm": 0.5, "index": 0.5, "middle": 0.5})  # power, load 6
    f = window_facets(np.stack([a, b]), HAND)
    g = grasp_facets(f, np.array([0.0, 1.0]), np.array([1.0, 2.0]))
    assert g["regions"]["thumb"] == pytest.approx(2 / 10)
    assert g["regions"]["index"] == pytest.approx(4 / 10)
    assert g["grip"] == "power"
    one = grasp_facets(window_facets(a[None], HAND), np.array([0.0]), np.array([1.0]))
    assert one["grip"] == "pinch" and one["slip"] == 0.0 and one["ramp"] == 0.0


def test_stag_glove_counts_its_548_taxels_only() -> None:
    w = np.full((1, 32, 32), 0.2, np.float32)  # every pixel above the contact level
    f = window_facets(w, STAG_GLOVE).row(0)
    assert f["area"] == pytest.approx(1.0)  # the 476 pixels that are no taxel do not count
    assert f["force"] == pytest.approx(548 * 0.2, rel=1e-5)
    assert sum(f["regions"].values()) == pytest.approx(1.0)
    assert f["regions"]["palm"] == pytest.approx(324 / 548)
    assert set(f["regions"]) == set(STAG_REGIONS.names)


def test_bad_shapes_are_refused() -> None:
    with pytest.raises(InvalidInputError, match="reads"):
        window_facets(np.zeros((2, 16, 16)), HAND)
    with pytest.raises(InvalidInputError, match="B, K, H, W"):
        window_facets(np.zeros((16, 16)), SKIN)
    with pytest.raises(InvalidInputError, match="one span each"):
        grasp_facets(window_facets(np.zeros((2, 16, 16)), SKIN), np.zeros(2), np.zeros(2))


def test_caption_says_firmness_from_force_grip_regions_and_motion() -> None:
    """Rule 3: the firmness is the force over the sensor's taxels (the peak taxel plays no
    part), banded at LIGHT_PRESSURE / FIRM_PRESSURE; a grasp's motion is said in words."""
    f = {"grip": "pinch", "regions": {"thumb": 0.6, "index": 0.4, "palm": 0.0}, "taxels": 548}
    firm, light = FIRM_PRESSURE * 548, 0.99 * LIGHT_PRESSURE * 548
    assert caption({**f, "force": firm, "peak": 0.1, "duration": 2.3, "slip": SLIP_SPEED}) == (
        "slipping, squeezing hard, a firm pinch"  # a grasp's caption names no region
    )
    assert caption({**f, "force": light, "peak": 1.0, "duration": 0.5, "slip": 0.5}) == (
        "a brief touch, touching lightly, a light pinch"
    )
    power = {"force": 0.097 * 548, "grip": "power", "duration": LONG_HOLD_S, "slip": 0.0}
    power["regions"] = {"palm": 0.5, "index": 0.2, "middle": 0.3}
    assert caption({**power, "taxels": 548}) == "a long steady hold, a steady power grasp"
    assert caption({**power, "duration": 4.0}, taxels=548) == "a steady power grasp"  # held
    window = {k: v for k, v in power.items() if k not in ("duration", "slip")}
    assert caption(window, taxels=548) == "a steady power grasp with palm, middle and index"
    assert caption({**window, "force": firm}, taxels=548) == (
        "squeezing hard, a firm power grasp with palm, middle and index"
    )
    # relative to the sensor: the same force is firm on 100 taxels, light on 1000
    assert caption({"force": 20.0, "taxels": 100}) == "squeezing hard, a firm touch"
    assert caption({"force": 20.0, "taxels": 1000}) == "touching lightly, a light touch"
    assert caption({"force": 20.0, "grip": None, "regions": {}}) == "a steady touch"  # unknown


def test_grasp_facets_carry_their_caption_and_rule() -> None:
    wins = np.stack([hand_window({"thumb": 0.9, "index": 0.9}, rows=4) for _ in range(3)])
    f = window_facets(wins, HAND)
    assert f.taxels == 4 * 16 + 64 and f.row(0)["taxels"] == f.taxels
    g = grasp_facets(f, np.array([0.0, 0.5, 1.0]), np.array([1, 1.5, 2]))
    assert g["force"] / g["taxels"] >= FIRM_PRESSURE  # 32 taxels at 0.9 of 128
    assert g["caption"] == "squeezing hard, a firm pinch"  # 2.0 s, no slip: held
    assert g["caption_rule"] == CAPTION_RULE
