"""Your sensor is a profile: frame shape, calibration (affine or per taxel), taxel mask, rest and
saturation, a layout of named pads assembled into one frame; read from TOML or flags, carried
by the checkpoint. And the touch model's stem adapts to small frames."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from tactus_memory.errors import DataFormatError, InvalidInputError
from tactus_memory.touch.checkpoint import load_checkpoint, save_checkpoint
from tactus_memory.touch.model import create_model
from tactus_memory.touch.pads import Pad
from tactus_memory.touch.profile import STAG_GLOVE, SensorProfile, dynamic_range_report
from tactus_memory.touch.sensor_file import load_profile_toml, parse_shape, resolve_profile
from tactus_memory.touch.targets import build_targets
from tactus_memory.training.bag_io import label_frames, parse_label
from tactus_memory.training.npz_io import from_arrays, load_npz
from tests.helpers.hand_synth import HAND_SHAPE, grasp, write_toml


@pytest.fixture
def hand(tmp_path: Path) -> SensorProfile:
    return load_profile_toml(write_toml(tmp_path))


def test_a_toml_pad_layout_assembles_pads_into_one_frame_and_back(hand) -> None:
    assert hand.shape == HAND_SHAPE and [p.name for p in hand.pads][-1] == "palm"
    pads = grasp("mug", 5, np.random.default_rng(0), hand)
    frames = hand.assemble(pads)
    assert frames.shape == (5, *HAND_SHAPE)
    np.testing.assert_array_equal(frames[:, 4:12, 4:12], pads["palm"])  # palm at [4, 4]
    np.testing.assert_array_equal(frames[:, 0:4, 12:16], pads["ring"])
    assert (frames[:, 4:, :4] == 200).all()  # no pad there: the rest reading
    back = hand.split(frames)
    assert set(back) == set(pads)
    for name, arr in pads.items():
        np.testing.assert_array_equal(back[name], arr)
    cal = hand.calibrate(frames)
    assert cal.dtype == np.float32 and (cal[:, 4:, :4] == 0).all()  # outside the mask: 0
    with pytest.raises(InvalidInputError, match=r"pad 'thumb' is 4x4, got readings of shape"):
        hand.assemble({**pads, "thumb": np.zeros((5, 3, 3))})
    with pytest.raises(InvalidInputError, match=r"missing \['palm'\]"):
        hand.assemble({k: v for k, v in pads.items() if k != "palm"})


def test_bad_layouts_and_shapes_are_named() -> None:
    with pytest.raises(InvalidInputError, match="pads overlap at taxel"):
        SensorProfile("x", 0, 10, (8, 8), pads=(Pad("a", 4, 4, 0, 0), Pad("b", 4, 4, 2, 2)))
    with pytest.raises(InvalidInputError, match="leaves the 8x8 frame"):
        SensorProfile("x", 0, 10, (8, 8), pads=(Pad("a", 4, 4, 6, 0),))
    with pytest.raises(InvalidInputError, match=r"H, W >= 4, got \(3, 8\)"):
        SensorProfile("x", 0, 10, (3, 8))
    with pytest.raises(InvalidInputError, match="HxW"):
        parse_shape("16 by 16")
    assert parse_shape("64x32") == (64, 32)


def test_per_taxel_calibration_round_trips_through_a_checkpoint(tmp_path, minilm_space) -> None:
    rng = np.random.default_rng(3)
    offs = rng.uniform(90, 110, (6, 5))
    gain = rng.uniform(0.004, 0.006, (6, 5))
    mask = np.ones((6, 5), bool)
    mask[0, 0] = False
    np.save(tmp_path / "off.npy", offs)
    np.save(tmp_path / "gain.npy", gain)
    np.save(tmp_path / "mask.npy", mask)
    (tmp_path / "s.toml").write_text(
        'name = "skin"\nshape = [6, 5]\nspan = 200\nrest = 100\nsaturation = 4000\n'
        'taxel_offset = "off.npy"\ntaxel_gain = "gain.npy"\nmask = "mask.npy"\n'
    )
    prof = load_profile_toml(tmp_path / "s.toml")
    assert prof.offset == pytest.approx(offs.min()) and prof.per_taxel
    raw = rng.uniform(50, 400, (3, 6, 5))
    want = np.clip((raw - offs) * gain, 0, 1) * mask
    np.testing.assert_allclose(prof.calibrate(raw), want, atol=1e-5)
    assert dynamic_range_report(raw, prof)["taxels_used"] == 29  # the profile's mask
    path = tmp_path / "ck.safetensors"
    targets = build_targets(minilm_space, ["mug", "pen"])
    model = create_model("tactus-tiny", out_dim=minilm_space.dim, frame_shape=(6, 5))
    save_checkpoint(path, model, targets, space_dim=minilm_space.dim, calibration=prof.to_dict())
    ck = load_checkpoint(path)
    assert SensorProfile.from_dict(ck.meta["calibration"]) == prof
    assert ck.model.cfg.frame_shape == (6, 5)
    assert SensorProfile.from_dict(STAG_GLOVE.to_dict()) == STAG_GLOVE


def test_flags_or_a_file_name_the_profile(tmp_path, hand) -> None:
    p = resolve_profile(shape="16x16", offset=2000, span=600)
    assert (p.shape, p.offset, p.span) == ((16, 16), 2000.0, 600.0)
    assert resolve_profile("stag-glove") is STAG_GLOVE
    assert resolve_profile(str(write_toml(tmp_path))) == hand
    assert resolve_profile(default=STAG_GLOVE) is STAG_GLOVE
    with pytest.raises(InvalidInputError, match="not both"):
        resolve_profile("stag-glove", shape="16x16", span=3)
    with pytest.raises(InvalidInputError, match="needs --span"):
        resolve_profile(shape="16x16")
    with pytest.raises(InvalidInputError, match="unknown sensor profile key"):
        (tmp_path / "bad.toml").write_text('name = "x"\nspan = 3\nshape = [4, 4]\nspam = 1\n')
        load_profile_toml(tmp_path / "bad.toml")


@pytest.mark.parametrize(
    ("model", "shape", "out"),
    [
        ("tactus-lite", (32, 32), (2, 2)),  # the glove: the configs' own layout, unchanged
        ("tactus-r18", (32, 32), (4, 4)),
        ("tactus-lite", (4, 4), (2, 2)),  # a fingertip pad keeps 2x2
        ("tactus-lite", (16, 16), (2, 2)),  # no stride-2 stem under 32 a side
        ("tactus-tiny", (64, 32), (4, 2)),  # an insole
        ("tactus-tiny", (12, 16), (3, 4)),  # the five-pad hand: 12 -> 6 -> 3, then kept
    ],
)
def test_the_stem_adapts_to_the_frame(model, shape, out) -> None:
    m = create_model(model, out_dim=384, frame_shape=shape).eval()
    assert m.cfg.out_shape() == out
    x = torch.rand(2, 8, *shape)  # (B, K, H, W)
    with torch.inference_mode():
        f = m.trunk(x.reshape(16, 1, *shape))
        z = m(x)
    assert tuple(f.shape[-2:]) == out and z.shape == (2, 384)
    assert torch.allclose(z.norm(dim=-1), torch.ones(2), atol=1e-5)


def test_the_npz_format_and_its_errors(tmp_path) -> None:
    rng = np.random.default_rng(0)
    p = rng.integers(0, 4000, (10, 8, 8)).astype(np.int16)
    lab = np.array(["mug"] * 4 + ["none"] * 2 + ["pen"] * 4)
    rec = np.array(["a"] * 6 + ["b"] * 4)
    d = from_arrays(p, lab, rec)
    assert d.objects == ["mug", "pen"] and d.valid.tolist() == [True] * 4 + [False] * 2 + [True] * 4
    assert d.recordings == ["a", "b"] and d.pressure.dtype == np.int16
    d2 = from_arrays(p, np.array(["mug"] * 5 + ["pen"] * 5), np.array(["a"] * 10))
    assert d2.recordings == ["a/mug", "a/pen"]  # one object per recording
    np.savez(tmp_path / "x.npz", pressure=p, label=lab)
    with pytest.raises(DataFormatError, match=r"missing array\(s\) \['recording'\]"):
        load_npz(tmp_path / "x.npz")
    np.savez(tmp_path / "y.npz", pressure=p, label=lab, recording=rec)
    with pytest.raises(DataFormatError, match="8x8 but the sensor profile 'sensor-16x16' reads"):
        load_npz(tmp_path / "y.npz", resolve_profile(shape="16x16", span=10))
    with pytest.raises(DataFormatError, match=r"label must be \(10,\)"):
        from_arrays(p, lab[:3], rec)


def test_label_messages_mark_what_was_held() -> None:
    ns = 1_000_000_000
    spans = [
        parse_label("mug", 1 * ns, 0),
        parse_label("none", 3 * ns, 0),
        parse_label("red pen 5.0 6.0", 4 * ns, 0),
    ]
    assert spans[2].label == "red pen" and spans[2].end_ns == 6 * ns
    t = np.arange(0, 8) * ns
    assert label_frames(t, spans).tolist() == ["", "mug", "mug", "", "", "red pen", "", ""]
    with pytest.raises(DataFormatError, match="ends"):
        parse_label("mug 3 2", 0, 0)


def test_the_docs_python_snippet_runs_as_written(tmp_path, monkeypatch) -> None:
    """docs/guides/own-sensor-training.md: its Python block, run from a copy of examples/."""
    root = Path(__file__).resolve().parents[2]
    page = (root / "docs" / "guides" / "own-sensor-training.md").read_text()
    code = page.split("```python\n", 1)[1].split("```", 1)[0]
    (tmp_path / "examples" / "sensors").mkdir(parents=True)
    for f in (root / "examples" / "sensors").glob("*.toml"):
        (tmp_path / "examples" / "sensors" / f.name).write_text(f.read_text())
    monkeypatch.chdir(tmp_path)
    exec(compile(code, "own-sensor-training.md", "exec"), {})
    d = load_npz(tmp_path / "hand.npz", load_profile_toml("examples/sensors/five-pad-hand.toml"))
    assert d.objects == ["mug"] and d.pressure.shape == (10, 12, 16) and d.valid.all()


def test_training_flags_that_do_not_fit_are_named(tmp_path) -> None:
    from typer.testing import CliRunner

    from tactus_memory.cli import app

    p = np.full((4, 8, 8), 300, np.int16)
    np.savez(tmp_path / "x.npz", pressure=p, label=np.array(["mug"] * 4), recording=np.zeros(4))
    out = ["--out", str(tmp_path / "o.safetensors")]
    r = CliRunner().invoke(app, ["train", "--data", str(tmp_path / "x.npz"), "--shape", "16x16",
                                 "--span", "100", *out])  # fmt: skip
    assert r.exit_code == 2 and "8x8 but the sensor profile 'sensor-16x16' reads 16x16" in r.output
    r = CliRunner().invoke(app, ["train", "--bag", str(tmp_path), "--shape", "8x8", "--span", "9",
                                 *out])  # fmt: skip
    assert r.exit_code == 2 and "--bag needs --topic TACTILE and --labels LABELS" in r.output
    r = CliRunner().invoke(app, ["train", "--data", str(tmp_path / "x.npz"), "--sensor",
                                 "stag-glove", "--shape", "8x8", *out])  # fmt: skip
    assert r.exit_code == 2 and "not both" in r.output


def test_an_mcap_recording_with_a_label_topic_becomes_training_arrays(tmp_path, hand) -> None:
    """mono16 Images of the 12x16 hand and String labels, written with mcap-ros2-support's
    writer, read back as the .npz arrays: frames, labels, one recording per stretch."""
    from tactus_memory.recordings.samples import mono16, note, vector3, write_mcap
    from tactus_memory.training.bag_io import read_bag_arrays

    rng = np.random.default_rng(0)
    frames = rng.integers(200, 4000, (9, *HAND_SHAPE)).astype(np.int16)
    ns = 100_000_000  # 10 Hz
    msgs = [note("/labels", 0, "mug"), note("/labels", 3 * ns, "none")]
    msgs += [note("/labels", 4 * ns, "pen"), note("/labels", 7 * ns, "")]
    msgs += [mono16("/hand/tactile", i * ns + 1, f) for i, f in enumerate(frames)]
    msgs.append(vector3("/other", 5 * ns))
    path = write_mcap(tmp_path / "hand.mcap", msgs)
    a = read_bag_arrays(path, "/hand/tactile", "/labels", hand)
    np.testing.assert_array_equal(a["pressure"], frames)
    assert a["label"].tolist() == ["mug"] * 3 + [""] + ["pen"] * 3 + [""] * 2
    assert (
        a["recording"].tolist()
        == ["hand.mcap#0"] * 3 + ["hand.mcap#none"] + ["hand.mcap#2"] * 3 + ["hand.mcap#none"] * 2
    )
    np.testing.assert_allclose(a["t"], np.arange(9) * 0.1 + 1e-9)
    with pytest.raises(DataFormatError, match=r"no label topic '/names'"):
        read_bag_arrays(path, "/hand/tactile", "/names", hand)
    with pytest.raises(DataFormatError, match=r"label topic '/other' is geometry_msgs"):
        read_bag_arrays(path, "/hand/tactile", "/other", hand)
