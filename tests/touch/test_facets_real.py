"""Facets and the glove's hand regions on the real STAG recordings (skipped without them; a
failure under TACTUS_REQUIRE_REAL_DATA=1). Nothing of the data is stored: the windows are
read from the files at run time."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from tactus_memory.touch.facets import grasp_facets, window_facets
from tactus_memory.touch.profile import STAG_GLOVE
from tactus_memory.touch.regions import STAG_REGIONS, STAG_TAXELS
from tactus_memory.touch.windows import contact_level
from tactus_memory.training.data import StagData, load_stag
from tests.conftest import _no_real_data

K = 8  # frames per window, the shipped model's


@pytest.fixture(scope="module")
def coords(stag_dir: Path) -> list[tuple[int, int]]:
    """The 548 public taxel coordinates (x = row, y = column), sensor_coords.json."""
    path = stag_dir / "sensor_coords.json"
    if not path.is_file():
        _no_real_data(path)
    d = json.loads(path.read_text())
    return list(zip(d["x"], d["y"], strict=True))


@pytest.fixture(scope="module")
def subsets(stag_subset: Callable[..., Path]) -> dict[str, StagData]:
    return {
        name: load_stag(stag_subset(name)) for name in ("weights_lite", "blindfolded_lite_train")
    }


def test_region_map_is_the_public_taxel_coordinates(coords: list[tuple[int, int]]) -> None:
    covered = {(int(r), int(c)) for r, c in np.argwhere(STAG_REGIONS.index >= 0)}
    assert len(coords) == STAG_TAXELS == len(set(coords))
    assert covered == set(coords)
    sizes = {n: int(STAG_REGIONS.taxels(n).sum()) for n in STAG_REGIONS.names}
    assert sizes == {"thumb": 56, "index": 42, "middle": 42, "ring": 42, "little": 42, "palm": 324}


def _region_by_rule(r: int, c: int) -> str:
    """The region of taxel (r, c) spelled out cell by cell (the docstring's derivation), not
    through the module's block table."""
    if r >= 18:
        return "thumb"
    if c >= 14:
        return "palm"
    for name, rows in (("little", (0, 1, 2)), ("ring", (6, 7, 8)), ("middle", (10, 11, 12))):
        if r in rows:
            return name
    return "index"


def _windows(d: StagData, n: int) -> tuple[np.ndarray, np.ndarray]:
    """n windows of K consecutive frames of one recording, each ending at a valid (held)
    frame, evenly over the file: raw (n, K, 32, 32) and their first frames' times."""
    starts = [
        i - K + 1
        for i in np.flatnonzero(d.valid)
        if i >= K - 1 and d.recording_id[i - K + 1] == d.recording_id[i]
    ]
    pick = np.asarray(starts)[np.linspace(0, len(starts) - 1, n).astype(int)]
    return np.stack([d.pressure[i : i + K] for i in pick]), d.ts[pick]


def test_facets_match_an_independent_computation(
    subsets: dict[str, StagData], coords: list[tuple[int, int]]
) -> None:
    """Force, area, peak, centroid and region shares of real windows, against a loop over the
    548 public coordinates with the calibration written out (no module code on that side)."""
    lvl = contact_level(STAG_GLOVE)
    in_contact = 0
    for d in subsets.values():
        raw, _ = _windows(d, 24)
        got = window_facets(STAG_GLOVE.calibrate(raw), STAG_GLOVE).rows()
        for w, f in zip(raw, got, strict=True):
            vals = np.array(
                [
                    [min(max((float(fr[r, c]) - 500.0) / 150.0, 0.0), 1.0) for r, c in coords]
                    for fr in w
                ]  # fmt: skip
            )  # (K, 548)
            assert f["force"] == pytest.approx(vals.sum(axis=1).mean(), rel=1e-5)
            assert f["area"] == pytest.approx((vals >= lvl).sum(axis=1).mean() / 548)
            assert f["peak"] == pytest.approx(vals.max(), abs=1e-6)
            load = np.where(vals >= lvl, vals, 0.0).sum(axis=0)  # (548,)
            if load.sum() == 0:
                assert f["centroid"] is None
                continue
            in_contact += 1
            pos = np.array(coords, np.float64)
            assert f["centroid"] == pytest.approx(load @ pos / load.sum(), abs=1e-6)
            shares: dict[str, float] = {}
            for (r, c), v in zip(coords, load, strict=True):
                name = _region_by_rule(r, c)
                shares[name] = shares.get(name, 0.0) + v / load.sum()
            for name in STAG_REGIONS.names:
                assert f["regions"][name] == pytest.approx(shares.get(name, 0.0), abs=1e-6)
    assert in_contact >= 24  # most of the 48 windows hold something: the shares were checked


def _shares(d: StagData, obj: str) -> dict[str, float]:
    """The region shares of the contact load over every valid frame of ``obj``."""
    idx = np.flatnonzero(d.valid & (d.object_id == d.objects.index(obj)))
    f = window_facets(STAG_GLOVE.calibrate(d.pressure[idx])[:, None], STAG_GLOVE)
    g = grasp_facets(f, d.ts[idx], d.ts[idx])
    return g["regions"]


@pytest.mark.parametrize("subset", ["weights_lite", "blindfolded_lite_train"])
def test_regions_on_real_grasps(subsets: dict[str, StagData], subset: str) -> None:
    """Measured (thresholds with a margin): the brain, squeezed in the hand, loads the palm
    most (0.58 and 0.86 of the contact load); a mug, a cat figure, a tea box and a kiwano,
    held with the fingertips, load the thumb (0.18-0.51) and the fingers, not the palm
    (0.00-0.10)."""
    d = subsets[subset]
    brain = _shares(d, "brain")
    assert brain["palm"] > 0.5 and brain["palm"] == max(brain.values())
    for obj in ("mug", "cat", "tea_box", "kiwano"):
        s = _shares(d, obj)
        assert s["palm"] < 0.15, (obj, s)
        assert s["thumb"] > 0.15, (obj, s)
        assert sum(s[f] for f in ("index", "middle", "ring", "little")) > 0.3, (obj, s)


def test_real_grasp_facets_are_consistent(subsets: dict[str, StagData]) -> None:
    d = subsets["blindfolded_lite_train"]
    raw, t = _windows(d, 6)
    f = window_facets(STAG_GLOVE.calibrate(raw), STAG_GLOVE)
    g = grasp_facets(f, t, t + 1.0)
    assert g["force"] == pytest.approx(max(r["force"] for r in f.rows()))
    assert g["onset"] == t.min() and g["release"] == t.max() + 1.0
    assert g["ramp"] >= 0 and g["slip"] >= 0
    assert sum(g["regions"].values()) == pytest.approx(1.0)
