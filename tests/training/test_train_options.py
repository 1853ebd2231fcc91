"""The training ladder's options: recording/class-balanced batches, stream-like consecutive
windows, the strong augmentation preset (``tactus train --balance/--consecutive/--augment``)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from tactus_memory.errors import InvalidInputError
from tactus_memory.training.augment import (
    AUGMENT_PRESETS,
    AugmentConfig,
    augment,
    augment_preset,
)
from tactus_memory.training.train import TrainConfig, draw_weights, fit
from tactus_memory.training.tuples import consecutive_windows
from tests.helpers.training import DIM, orthogonal_targets, synthetic


def test_consecutive_windows_stay_in_the_anchor_recording() -> None:
    rec = np.repeat([0, 1, 2], [20, 5, 12])  # recording 1 is shorter than k
    anchors = np.arange(rec.size)
    w = consecutive_windows(anchors, rec, 8, np.random.default_rng(0))
    assert w.shape == (rec.size, 8)
    assert (rec[w] == rec[anchors][:, None]).all()  # never crosses a recording boundary
    assert (w == anchors[:, None]).any(axis=1).all()  # the anchor is in its window
    long = rec[anchors] != 1
    assert (np.diff(w[long], axis=1) == 1).all()  # consecutive frames in time order
    short = w[rec[anchors] == 1]
    assert set(short.ravel()) == set(range(20, 25))  # the whole short recording, last repeated
    assert (np.diff(short, axis=1) >= 0).all()


def test_consecutive_windows_refuse_unsorted_recordings() -> None:
    rec = np.array([0, 0, 1, 1, 0, 0])
    with pytest.raises(InvalidInputError, match="sorted by recording"):
        consecutive_windows(np.array([0]), rec, 2, np.random.default_rng(0))


def test_draw_weights_give_every_group_the_same_mass() -> None:
    key = np.array([3, 3, 3, 3, 7, 9, 9])
    w = draw_weights(key)
    for g in (3, 7, 9):
        assert w[key == g].sum() == pytest.approx(1.0)
    picks = torch.multinomial(torch.from_numpy(w), 30000, replacement=True)
    share = np.bincount(key[picks.numpy()], minlength=10)[[3, 7, 9]] / 30000
    assert np.allclose(share, 1 / 3, atol=0.02)  # uniform draws would give 4/7 to group 3


def test_strong_preset_drops_taxels_and_unknown_preset_is_named() -> None:
    x = torch.full((4, 8, 32, 32), 0.5)
    strong = augment_preset("strong")
    assert strong.taxel_drop > 0 and strong is not AUGMENT_PRESETS["strong"]
    y = augment(x, strong, torch.Generator().manual_seed(1))
    assert y.shape == x.shape and (y >= 0).all()
    assert ((y == 0).float().mean() > 0.05).item()  # ~10 % of pixels zeroed
    dflt = augment(x, AugmentConfig(), torch.Generator().manual_seed(1))
    assert ((dflt == 0).float().mean() < 0.01).item()
    with pytest.raises(ValueError, match="strong"):
        augment_preset("wild")


@pytest.mark.parametrize(
    "options",
    [
        {"balance": "recording"},
        {"balance": "class", "consecutive": 1.0},
        {"balance": "recording", "consecutive": 0.5, "augment": augment_preset("strong")},
    ],
)
def test_tiny_training_with_ladder_options_learns(tmp_path, options) -> None:
    d = synthetic()
    cfg = TrainConfig(
        model="tactus-tiny", steps=60, batch=16, lr=3e-3, warmup=4, save_every=1000, **options
    )
    out = tmp_path / "t.safetensors"
    s = fit(d, orthogonal_targets(), cfg, out, space_dim=DIM, device="cpu", progress=False)
    assert s["heldout"]["top1"] >= 0.75  # chance 0.25
    from tactus_memory.touch.checkpoint import load_checkpoint

    args = load_checkpoint(out).meta["train_args"]
    assert args["balance"] == options["balance"]
    assert args["consecutive"] == options.get("consecutive", 0.0)


@pytest.mark.parametrize(
    ("bad", "names"),
    [
        ({"balance": "objects"}, "balance"),
        ({"consecutive": 1.5}, "consecutive"),
        # compressed input with noise on empty taxels (0.015 ** 0.3 ~ 0.28): refused
        ({"model_overrides": {"input_gamma": 0.3}}, "pressed-noise"),
    ],
)
def test_bad_ladder_options_are_refused(tmp_path, bad, names) -> None:
    cfg = TrainConfig(model="tactus-tiny", steps=2, batch=4, warmup=1, **bad)
    with pytest.raises(ValueError, match=names):
        fit(
            synthetic(2, 8),
            orthogonal_targets(),
            cfg,
            tmp_path / "x.safetensors",
            space_dim=DIM,
            device="cpu",
            progress=False,
        )


def test_input_shaping_compresses_blurs_and_survives_a_checkpoint(tmp_path) -> None:
    from tactus_memory.touch.checkpoint import load_checkpoint, save_checkpoint
    from tactus_memory.touch.model import InputShaping, create_model, gaussian_kernel

    k = gaussian_kernel(1.0)
    assert k.shape == (1, 1, 5, 5) and float(k.sum()) == pytest.approx(1.0)
    dot = torch.zeros(1, 1, 32, 32)
    dot[0, 0, 16, 16] = 0.008  # ~1 raw step above the offset
    shaped = InputShaping(0.3, 1.0)(dot)
    assert float(shaped.sum()) == pytest.approx(0.008**0.3, rel=1e-4)  # blur keeps the mass
    assert float(shaped[0, 0, 16, 16]) < 0.008**0.3 and float(shaped[0, 0, 16, 17]) > 0
    assert torch.equal(InputShaping(1.0, 0.0)(dot), dot)

    torch.manual_seed(0)
    m = create_model("tactus-tiny", DIM, input_gamma=0.3, input_blur=1.0).eval()
    assert not any("kernel" in name for name in m.state_dict())  # derived, not a weight
    x = torch.rand(2, 8, 32, 32)
    with torch.inference_mode():
        ref = m(x)
        plain = create_model("tactus-tiny", DIM)
        plain.load_state_dict(m.state_dict())
        assert not torch.allclose(plain.eval()(x), ref, atol=1e-3)  # shaping changes outputs
    p = tmp_path / "shaped.safetensors"
    save_checkpoint(p, m, orthogonal_targets(), space_dim=DIM, seed=0, steps=1)
    ck = load_checkpoint(p)
    assert ck.meta["model"]["input_gamma"] == 0.3 and ck.meta["model"]["input_blur"] == 1.0
    with torch.inference_mode():
        assert torch.allclose(ck.model(x), ref, atol=1e-6)


@pytest.mark.parametrize("bad", [{"input_gamma": 0.0}, {"input_gamma": 2.0}, {"input_blur": -1}])
def test_bad_input_shaping_is_refused(bad) -> None:
    from tactus_memory.touch.model import create_model

    with pytest.raises(ValueError, match="input_gamma"):
        create_model("tactus-tiny", DIM, **bad)


def test_pressed_noise_leaves_empty_taxels_empty() -> None:
    x = torch.zeros(3, 8, 32, 32)
    x[:, :, 10:14, 10:14] = 0.5
    y = augment(x, augment_preset("pressed-noise"), torch.Generator().manual_seed(0))
    assert (y[:, :, :8, :8] == 0).all()  # unpressed corner: no noise
    everywhere = augment(x, augment_preset("default"), torch.Generator().manual_seed(0))
    assert (everywhere[:, :, :8, :8] > 0).any()


def test_arithmetic_on_a_validated_window_is_validated_again() -> None:
    from tactus_memory.adapters.touch import CalibratedWindow, TactusEncoder
    from tactus_memory.errors import InvalidInputError as Invalid

    enc = TactusEncoder()
    w = enc.validate(np.full((8, 32, 32), 0.5, np.float32))
    assert isinstance(w, CalibratedWindow) and isinstance(w[:4], CalibratedWindow)
    assert type(w * 3) is np.ndarray  # no longer "validated"
    with pytest.raises(Invalid, match=r"\[0, 1\]"):
        enc.embed([w * 3], calibrated=True)  # 1.5 > 1: refused, not trusted
    assert enc.embed([w]).shape == (1, enc.dim)
