"""STAG data path: reader (v5 + v7.3), masks, calibration, combine, dynamic-range gate, CLI."""

from __future__ import annotations

import json
from pathlib import Path

import h5py
import numpy as np
import pytest
from typer.testing import CliRunner

from tactus_memory.errors import DataFormatError, DynamicRangeError, InvalidInputError
from tactus_memory.touch.profile import (
    PROFILES,
    RAW_OFFSET,
    RAW_SPAN,
    STAG_GLOVE,
    SensorProfile,
    calibrate,
    check_dynamic_range,
    dynamic_range_report,
    get_profile,
    taxel_mask_from_data,
    taxel_mask_from_spec,
)
from tactus_memory.training.data import StagData, UnknownSplitError, combine, load_stag
from tests.helpers.stag_synth import (
    OBJECTS,
    make_fields,
    spec_mask,
    write_subset,
    write_v5,
    write_v73,
)

PER_FRAME = ("pressure", "object_id", "recording_id", "batch_id", "split_id", "frame", "ts")
PER_FRAME += ("valid", "balanced", "subset")


def assert_same_data(a: StagData, b: StagData) -> None:
    for name in PER_FRAME:
        x, y = getattr(a, name), getattr(b, name)
        assert x.dtype == y.dtype, name
        np.testing.assert_array_equal(x, y, err_msg=name)
    assert (a.objects, a.recordings, a.splits, a.batches) == (
        b.objects,
        b.recordings,
        b.splits,
        b.batches,
    )
    assert sorted(a.extra) == sorted(b.extra)
    for k in a.extra:
        np.testing.assert_array_equal(a.extra[k], b.extra[k], err_msg=k)
    assert a.frame_extra == b.frame_extra


# --------------------------------------------------------------------------- calibration


def test_calibration_constants() -> None:
    assert (RAW_OFFSET, RAW_SPAN) == (500, 150)
    raw = np.array([500, 650, 575, 1000, 446, 512], dtype=np.int16)
    frames = np.tile(raw[:, None, None], (1, 32, 32))
    out = calibrate(frames)
    assert out.dtype == np.float32 and out.shape == (6, 32, 32)
    np.testing.assert_allclose(out[:, 3, 7], [0.0, 1.0, 0.5, 1.0, 0.0, 12 / 150], rtol=1e-6)


def test_calibration_does_not_depend_on_the_data_range() -> None:
    """The same raw value calibrates identically whatever else is in the subset (no max
    scaling): a weights-like subset (max 654) and a saturating one (max 1000)."""
    rng = np.random.default_rng(0)
    low = rng.integers(510, 655, size=(50, 32, 32)).astype(np.int16)
    high = rng.integers(510, 1001, size=(50, 32, 32)).astype(np.int16)
    low[0, 0, 0] = high[0, 0, 0] = 600
    a, b = calibrate(low), calibrate(high)
    assert a[0, 0, 0] == b[0, 0, 0] == np.float32(100 / 150)
    np.testing.assert_array_equal(a[:1], calibrate(low[:1]))  # per-frame, not per-batch
    both = calibrate(np.concatenate([low, high]))
    np.testing.assert_array_equal(both[:50], a)
    np.testing.assert_array_equal(both[50:], b)


def test_calibration_rejects_bad_shapes_and_nan() -> None:
    with pytest.raises(InvalidInputError, match="32"):
        calibrate(np.zeros((4, 16, 16)))
    bad = np.full((1, 32, 32), 600.0)
    bad[0, 1, 1] = np.nan
    with pytest.raises(InvalidInputError, match="NaN"):
        calibrate(bad)


def test_profile_roundtrip_and_registry() -> None:
    assert get_profile("stag-glove") is STAG_GLOVE is PROFILES["stag-glove"]
    assert (STAG_GLOVE.offset, STAG_GLOVE.span, STAG_GLOVE.shape) == (500, 150, (32, 32))
    other = SensorProfile("other-glove", 100.0, 400.0, (16, 16), rest_raw=120.0)
    back = SensorProfile.from_dict(json.loads(json.dumps(other.to_dict())))
    assert back == other
    x = np.full((2, 16, 16), 300)
    np.testing.assert_allclose(back.calibrate(x), 0.5)
    with pytest.raises(InvalidInputError, match="unknown sensor profile"):
        get_profile("nope")
    with pytest.raises(InvalidInputError, match="span"):
        SensorProfile("bad", 0.0, 0.0)


# --------------------------------------------------------------------------- reader


def test_v5_loads_with_int64_ids_from_uint8_and_float64(tmp_path: Path) -> None:
    a = load_stag(write_subset(tmp_path, "u8", make_fields(seed=3, id_dtype=np.uint8)))
    b = load_stag(write_subset(tmp_path, "f64", make_fields(seed=3, id_dtype=np.float64)))
    for d in (a, b):
        assert d.pressure.dtype == np.int16 and d.pressure.shape == (115, 32, 32)
        assert d.pressure.flags.c_contiguous
        for name in ("object_id", "recording_id", "batch_id", "split_id", "frame"):
            assert getattr(d, name).dtype == np.int64 and getattr(d, name).shape == (115,)
        assert d.valid.dtype == bool and d.balanced.dtype == bool
        assert d.objects == OBJECTS
        assert d.n_frames == 115 and d.n_recordings == 4
    np.testing.assert_array_equal(a.recording_id, b.recording_id)
    np.testing.assert_array_equal(a.valid, b.valid)
    np.testing.assert_array_equal(a.object_id, np.repeat([0, 1, 2, 3], [40, 30, 25, 20]))


def test_v73_same_content_loads_identically(tmp_path: Path) -> None:
    fields = make_fields("classification", seed=5)
    a = load_stag(write_v5(tmp_path / "a.mat", fields))
    b = load_stag(write_v73(tmp_path / "b.mat", fields))
    assert_same_data(a, b)
    assert a.fingerprint() == b.fingerprint()
    # the file really is in MATLAB's transposed layout, with MATLAB's header and cellstr
    with h5py.File(tmp_path / "b.mat", "r") as f:
        assert f["pressure"].shape == (32, 32, 115)
        assert f["objectId"].shape == (1, 115)
        assert f["objects"].shape == (27, 1) and f["objects"].dtype == h5py.ref_dtype
        first = f[f["objects"][0, 0]]
        assert first.dtype == np.uint16 and first.attrs["MATLAB_class"] == b"char"
    assert (tmp_path / "b.mat").read_bytes()[:19] == b"MATLAB 7.3 MAT-file"


def test_v73_restores_orientation_of_asymmetric_frames(tmp_path: Path) -> None:
    """A transpose bug would swap rows and columns; mark single pixels to catch it."""
    fields = make_fields("weights", [3, 2], seed=1)
    p = fields["pressure"]
    p[:] = 510
    p[0, 2, 30] = 900  # row 2, column 30
    p[4, 20, 26] = 777  # a thumb taxel
    for fmt in ("v5", "v73"):
        d = load_stag(write_subset(tmp_path, fmt, fields, fmt))
        assert d.pressure[0, 2, 30] == 900 and d.pressure[0, 30, 2] == 510
        assert d.pressure[4, 20, 26] == 777 and d.pressure[4, 26, 20] == 510


def test_v73_without_userblock_and_with_empty_string(tmp_path: Path) -> None:
    fields = make_fields("weights", [4, 4], seed=2)
    fields["recordings"] = ["", "001-ünïcode"]
    d = load_stag(write_v73(tmp_path / "m.mat", fields, userblock=False))
    assert d.recordings == ["", "001-ünïcode"]
    assert d.objects == OBJECTS


def test_folder_or_file_path(tmp_path: Path) -> None:
    folder = write_subset(tmp_path, "weights", make_fields("weights", [5, 6]))
    a, b = load_stag(folder), load_stag(folder / "metadata.mat")
    assert_same_data(a, b)
    assert a.sources == [str(folder / "metadata.mat")]


@pytest.mark.parametrize("fmt", ["v5", "v73"])
@pytest.mark.parametrize("missing", ["pressure", "objectId", "recordingId", "objects", "ts"])
def test_missing_field_is_named(tmp_path: Path, fmt: str, missing: str) -> None:
    fields = make_fields(seed=0)
    del fields[missing]
    with pytest.raises(DataFormatError, match=missing):
        load_stag(write_subset(tmp_path, "x", fields, fmt))


def test_missing_valid_mask_and_split_pairs(tmp_path: Path) -> None:
    fields = make_fields(seed=0)
    del fields["hasValidLabel"]
    with pytest.raises(DataFormatError, match="hasValidLabel"):
        load_stag(write_v5(tmp_path / "a.mat", fields))
    fields = make_fields(seed=0)
    del fields["splits"]
    with pytest.raises(DataFormatError, match="splits"):
        load_stag(write_v5(tmp_path / "b.mat", fields))


def test_bad_shapes_and_values(tmp_path: Path) -> None:
    fields = make_fields("weights", [4, 4])
    fields["pressure"] = fields["pressure"][:, :16, :]
    with pytest.raises(DataFormatError, match=r"pressure must be \(N, 32, 32\)"):
        load_stag(write_v5(tmp_path / "a.mat", fields))
    fields = make_fields("weights", [4, 4])
    fields["objectId"] = fields["objectId"][:-1]
    with pytest.raises(DataFormatError, match="objectId"):
        load_stag(write_v5(tmp_path / "b.mat", fields))
    fields = make_fields("weights", [4, 4])
    fields["recordingId"] = fields["recordingId"] + 5
    with pytest.raises(DataFormatError, match="recordingId out of range"):
        load_stag(write_v5(tmp_path / "c.mat", fields))
    fields = make_fields("weights", [4, 4])
    fields["pressure"] = fields["pressure"] / 1000.0  # normalised floats, not raw readings
    with pytest.raises(DataFormatError, match="raw integer"):
        load_stag(write_v5(tmp_path / "d.mat", fields))
    with pytest.raises(DataFormatError, match="no STAG metadata"):
        load_stag(tmp_path / "nowhere")
    (tmp_path / "junk.mat").write_bytes(b"not a mat file at all" * 10)
    with pytest.raises(DataFormatError):
        load_stag(tmp_path / "junk.mat")


# --------------------------------------------------------------------------- masks


def test_grasp_filter_is_has_valid_label_not_sparse_markers(tmp_path: Path) -> None:
    fields = make_fields("classification", seed=7)
    d = load_stag(write_v5(tmp_path / "c.mat", fields))
    np.testing.assert_array_equal(d.valid, fields["hasValidLabel"].ravel().astype(bool))
    np.testing.assert_array_equal(d.balanced, fields["isBalanced"].ravel().astype(bool))
    # isTransition / isGrasp are kept as extras, never folded into the valid mask
    assert {"isTransition", "isGrasp"} <= set(d.extra)
    assert d.valid.sum() > (d.valid & d.extra["isGrasp"].astype(bool)).sum()
    train = d.split_mask("train")
    np.testing.assert_array_equal(d.valid_mask("train"), d.valid & train)
    np.testing.assert_array_equal(d.anchor_mask("train"), d.valid & train & d.balanced)
    np.testing.assert_array_equal(d.anchor_mask(), d.valid & d.balanced)


def test_weights_grasp_valid_is_the_mask(tmp_path: Path) -> None:
    fields = make_fields("weights", [30, 20, 10], seed=4)
    d = load_stag(write_v73(tmp_path / "w.mat", fields))
    np.testing.assert_array_equal(d.valid, fields["graspValid"].ravel().astype(bool))
    assert d.balanced.all()
    assert (d.split_id == -1).all() and d.splits == []
    assert not d.split_mask("test").any() and not d.split_mask("train").any()
    with pytest.raises(UnknownSplitError, match="valid"):
        d.split_mask("valid")
    assert "graspIndex" in d.frame_extra and d.extra["weights"].shape == (27,)
    assert "graspValid" not in d.extra


def test_split_lookup_is_by_name_in_swapped_order(tmp_path: Path) -> None:
    ref = load_stag(write_v5(tmp_path / "a.mat", make_fields(seed=9)))
    swapped = load_stag(write_v5(tmp_path / "b.mat", make_fields(seed=9, splits=("test", "train"))))
    assert swapped.splits == ["test", "train"]
    assert not np.array_equal(ref.split_id, swapped.split_id)  # raw indices differ ...
    for name in ("train", "test"):  # ... the named splits do not
        np.testing.assert_array_equal(ref.split_mask(name), swapped.split_mask(name))
    np.testing.assert_array_equal(ref.split_mask("train"), ref.recording_id % 2 == 0)
    with pytest.raises(LookupError, match="unknown split"):
        ref.split_mask("val")


def test_select_and_fingerprint(tmp_path: Path) -> None:
    d = load_stag(write_v5(tmp_path / "w.mat", make_fields("weights", [10, 10], seed=1)))
    s = d.select(d.valid)
    assert s.n_frames == d.valid_frames and s.valid.all()
    np.testing.assert_array_equal(s.extra["graspIndex"], d.extra["graspIndex"][d.valid])
    np.testing.assert_array_equal(s.extra["weights"], d.extra["weights"])
    assert s.fingerprint() != d.fingerprint()
    assert d.select(np.arange(d.n_frames)).fingerprint() == d.fingerprint()
    changed = d.select(np.arange(d.n_frames))
    changed.object_id[3] += 1
    assert changed.fingerprint() != d.fingerprint()
    with pytest.raises(InvalidInputError):
        d.select(np.ones(3, bool))


# --------------------------------------------------------------------------- combine


def test_combine_keeps_recording_ids_unique(tmp_path: Path) -> None:
    a = load_stag(write_v5(tmp_path / "a.mat", make_fields("classification", [9, 8], seed=1)))
    b = load_stag(
        write_v73(
            tmp_path / "b.mat", make_fields("blindfolded", [7, 6, 5], splits=("test", "train"))
        )
    )
    w = load_stag(write_v5(tmp_path / "w.mat", make_fields("weights", [4, 3], seed=2)))
    c = combine([a, b, w])
    assert c.n_frames == a.n_frames + b.n_frames + w.n_frames
    assert c.n_recordings == a.n_recordings + b.n_recordings + w.n_recordings == 7
    names = [c.recordings[i] for i in c.recording_id]
    expected = [d.recordings[i] for d in (a, b, w) for i in d.recording_id]
    assert names == expected
    assert c.sources == a.sources + b.sources + w.sources
    np.testing.assert_array_equal(c.subset, np.repeat([0, 1, 2], [17, 18, 7]))
    # splits unified by name, no-split frames stay -1
    assert c.splits == ["train", "test"]
    np.testing.assert_array_equal(
        c.split_mask("test"),
        np.concatenate([a.split_mask("test"), b.split_mask("test"), w.split_mask("test")]),
    )
    assert (c.split_id[c.subset == 2] == -1).all()
    # per-frame extras carried, filled where a subset lacks them
    np.testing.assert_array_equal(c.extra["graspIndex"][c.subset == 2], w.extra["graspIndex"])
    assert (c.extra["graspIndex"][c.subset < 2] == -1).all()
    np.testing.assert_array_equal(c.pressure, np.concatenate([a.pressure, b.pressure, w.pressure]))
    np.testing.assert_array_equal(c.valid, np.concatenate([a.valid, b.valid, w.valid]))


def test_combine_rejects_different_class_lists(tmp_path: Path) -> None:
    a = load_stag(write_v5(tmp_path / "a.mat", make_fields("weights", [4])))
    fields = make_fields("weights", [4])
    fields["objects"] = ["G2"] + OBJECTS[1:]
    b = load_stag(write_v5(tmp_path / "b.mat", fields))
    with pytest.raises(DataFormatError, match="class lists"):
        combine([a, b])
    with pytest.raises(InvalidInputError):
        combine([])


# --------------------------------------------------------------------------- taxels and gate


def test_taxel_mask_from_spec() -> None:
    m = taxel_mask_from_spec()
    assert m.shape == (32, 32) and m.dtype == bool and m.sum() == 548
    np.testing.assert_array_equal(m, spec_mask())
    assert m[0].all() and m[17].all() and not m[18, :25].any() and m[31, 25:29].all()
    assert not m[3, :14].any() and m[3, 14:].all() and not m[31, 29:].any()


def test_taxel_mask_from_data_and_report(tmp_path: Path) -> None:
    d = load_stag(write_v5(tmp_path / "c.mat", make_fields(seed=1)))
    np.testing.assert_array_equal(taxel_mask_from_data(d.pressure), taxel_mask_from_spec())
    r = dynamic_range_report(d.pressure)
    assert r["taxel_mask_matches_spec"] is True and r["taxels_data"] == 548
    assert r["raw_min"] == 510 and r["raw_max"] == d.pressure.max()
    assert 0 < r["frac_saturated"] < 0.5 and r["frac_zero"] == 0
    assert r["levels_used"] >= 30
    # a dead taxel shows up as a spec/data disagreement
    p = d.pressure.copy()
    p[:, 0, 0] = 512
    r2 = dynamic_range_report(p)
    assert r2["taxel_mask_matches_spec"] is False and r2["taxels_spec_not_data"] == 1


def test_report_histograms_match_direct_numpy(tmp_path: Path, monkeypatch) -> None:
    import tactus_memory.touch.profile as data_mod

    d = load_stag(write_v5(tmp_path / "c.mat", make_fields(seed=2)))
    mask = taxel_mask_from_spec()
    taxels = d.pressure[:, mask].reshape(-1)
    q = np.rint(calibrate(d.pressure)[:, mask] * 255).astype(int).reshape(-1)
    expected = {
        "raw_p50": int(np.percentile(taxels, 50, method="nearest")),
        "raw_p99": int(np.percentile(taxels, 99, method="nearest")),
        "level_p1": int(np.percentile(q, 1, method="nearest")),
        "level_p999": int(np.percentile(q, 99.9, method="nearest")),
        "levels_distinct": int(np.unique(q).size),
        "frac_saturated": float(np.mean(q == 255)),
    }
    monkeypatch.setattr(data_mod, "_CHUNK_FRAMES", 7)  # many chunks: same answer
    r = dynamic_range_report(d.pressure)
    for key, value in expected.items():
        assert r[key] == pytest.approx(value, rel=1e-9), key
    assert r["levels_used"] == r["level_p999"] - r["level_p1"] + 1


def test_gate_rejects_max_scaled_data(tmp_path: Path) -> None:
    d = load_stag(write_v5(tmp_path / "w.mat", make_fields("weights", [40, 40], peak=654)))
    raw = d.pressure
    check_dynamic_range(raw)  # the raw readings pass
    check_dynamic_range(calibrate(raw), already_calibrated=True)  # and so does calibrated
    maxed = raw / raw.max()
    with pytest.raises(DynamicRangeError, match="already normalised"):
        check_dynamic_range(maxed)
    with pytest.raises(DynamicRangeError, match="pedestal"):
        check_dynamic_range(maxed, already_calibrated=True)
    as_bytes = np.round(maxed * 255).astype(np.uint8)  # an 8-bit cache of max-scaled frames
    with pytest.raises(DynamicRangeError, match="offset"):
        check_dynamic_range(as_bytes)


def test_gate_rejects_too_few_levels() -> None:
    rng = np.random.default_rng(0)
    flat = rng.integers(512, 516, size=(100, 32, 32))  # a sensor that never gets pressed
    with pytest.raises(DynamicRangeError, match="levels"):
        check_dynamic_range(flat)
    cal = calibrate(flat)
    with pytest.raises(DynamicRangeError, match="levels"):
        check_dynamic_range(cal, already_calibrated=True)
    with pytest.raises(DynamicRangeError, match=r"\[0, 1\]"):
        check_dynamic_range(cal + 1.0, already_calibrated=True)


# --------------------------------------------------------------------------- real files


@pytest.mark.slow
def test_real_weights_file(stag_dir: Path) -> None:
    d = load_stag(stag_dir / "weights_lite")
    assert (d.n_frames, d.n_recordings, d.valid_frames) == (11682, 27, 2301)
    assert d.objects == OBJECTS
    assert d.pressure.dtype == np.int16 and d.pressure.shape == (11682, 32, 32)
    assert (int(d.pressure.min()), int(d.pressure.max())) == (510, 654)
    assert d.splits == [] and (d.split_id == -1).all() and d.balanced.all()
    assert d.extra["weights"].shape == (27,) and d.extra["graspIndex"].max() == 6
    report = check_dynamic_range(d.pressure)  # the real weights file passes the gate
    assert report["levels_used"] >= 30 and report["taxel_mask_matches_spec"]
    with pytest.raises(DynamicRangeError):  # ... and its max-scaled version does not
        check_dynamic_range(d.pressure / d.pressure.max(), already_calibrated=True)


@pytest.mark.slow
def test_real_blindfolded_file(stag_dir: Path, stag_subset) -> None:
    d = load_stag(stag_subset("blindfolded_lite_train") / "metadata.mat")
    assert (d.n_frames, d.n_recordings, d.valid_frames) == (3034, 52, 260)
    assert len(d.recordings) == 105 and d.objects == OBJECTS
    assert d.splits == ["train", "test"] and d.split_mask("test").all() and d.balanced.all()
    assert (int(d.pressure.min()), int(d.pressure.max())) == (509, 991)
    assert d.extra["actionStartTS"].shape == (105,)
    check_dynamic_range(d.pressure)
    pool = combine([load_stag(stag_dir / "weights_lite"), d])
    assert pool.n_recordings == 79 and pool.valid_frames == 2561
    assert np.unique(pool.recording_id[pool.subset == 1]).min() >= 27


# --------------------------------------------------------------------------- CLI


def _cli():
    from tactus_memory.cli import app

    return app


@pytest.mark.slow
def test_cli_inspect_real_file(stag_dir: Path) -> None:
    runner = CliRunner()
    res = runner.invoke(_cli(), ["data", "inspect", str(stag_dir / "weights_lite"), "--json"])
    assert res.exit_code == 0, res.output
    out = json.loads(res.stdout)
    assert (out["frames"], out["recordings"], out["valid_frames"]) == (11682, 27, 2301)
    assert (out["raw_min"], out["raw_max"]) == (510, 654) and out["objects"] == OBJECTS
    assert out["gate"] == "pass" and out["dynamic_range"]["levels_used"] >= 30
    table = runner.invoke(_cli(), ["data", "inspect", str(stag_dir / "weights_lite")])
    assert table.exit_code == 0
    for word in ("frames", "valid_frames", "raw_max", "levels_used", "tea_box"):
        assert word in table.stdout


def test_cli_inspect_synthetic_v73(tmp_path: Path) -> None:
    fields = make_fields("classification", [12, 10, 8], seed=4)
    write_v73(tmp_path / "metadata.mat", fields)
    runner = CliRunner()
    res = runner.invoke(_cli(), ["data", "inspect", str(tmp_path), "--json"])
    assert res.exit_code == 0, res.output
    out = json.loads(res.stdout)
    assert out["frames"] == 30 and out["recordings"] == 3
    assert out["valid_frames"] == int(fields["hasValidLabel"].sum())
    assert out["raw_min"] == 510 and out["raw_max"] == int(fields["pressure"].max())
    assert out["splits"]["train"]["frames"] == 20  # recordings 0 and 2
    bad = runner.invoke(_cli(), ["data", "inspect", str(tmp_path / "missing")])
    assert bad.exit_code == 2 and "no STAG metadata" in bad.output


def test_v5_char_matrix_lists(tmp_path: Path) -> None:
    """Lists saved as MATLAB char matrices (padded rows) instead of cell arrays."""
    fields = make_fields(seed=1)
    fields["splits"] = np.array(["train", "test"])  # savemat writes a 2 x 5 char matrix
    d = load_stag(write_v5(tmp_path / "m.mat", fields))
    assert d.splits == ["train", "test"]
    np.testing.assert_array_equal(d.split_mask("train"), d.recording_id % 2 == 0)


def test_per_subset_gate_catches_a_mis_scaled_subset_in_a_pool(tmp_path: Path) -> None:
    good = load_stag(write_v5(tmp_path / "a.mat", make_fields("classification", seed=1)))
    fields = make_fields("weights", [40, 40], seed=2, peak=654)
    p = fields["pressure"].astype(np.float64)
    fields["pressure"] = np.round(p / p.max() * 255).astype(np.int16)  # an 8-bit max-scaled cache
    bad = load_stag(write_v5(tmp_path / "b.mat", fields))
    pool = combine([good, bad])
    check_dynamic_range(pool.pressure)  # the pooled gate is fooled by the good subset ...
    assert list(good.check_dynamic_range()) == good.sources
    with pytest.raises(DynamicRangeError, match="b.mat"):  # ... the per-subset gate is not
        pool.check_dynamic_range()
