"""MAE pieces, the training loop on separable synthetic touch, resume, checkpoint round trip."""

from __future__ import annotations

import logging
from types import SimpleNamespace

import numpy as np
import pytest
import torch

from tactus_memory.hashing import file_sha256
from tactus_memory.touch.checkpoint import load_checkpoint, save_checkpoint
from tactus_memory.touch.model import create_model
from tactus_memory.training.augment import AugmentConfig, augment
from tactus_memory.training.pretrain import (
    MAE,
    MASK_RATIO,
    MIN_PATCH_STD,
    N_PATCHES,
    PretrainConfig,
    apply_mask,
    masked_loss,
    patch_targets,
    patchify,
    pretrain,
    pretrain_pool,
    random_mask,
    unpatchify,
)
from tactus_memory.training.train import TrainConfig, fit, holdout_recordings
from tests.helpers.training import DIM, N_CLS, orthogonal_targets, synthetic

# -- MAE -------------------------------------------------------------------------------------


def test_patchify_round_trip_and_layout() -> None:
    x = torch.arange(2 * 32 * 32, dtype=torch.float32).reshape(2, 32, 32)
    p = patchify(x)
    assert p.shape == (2, N_PATCHES, 16)
    assert torch.equal(p[0, 1], x[0, 0:4, 4:8].reshape(-1))  # second patch: row 0, col 1
    assert torch.equal(unpatchify(p), x)


def test_per_patch_normalisation_flat_and_active() -> None:
    x = torch.full((1, 32, 32), 0.07)
    x[0, 0:4, 0:4] = torch.rand(4, 4)  # an active patch
    x[0, 0:4, 4:8] += torch.tensor([0.0, 1 / 150] * 8).reshape(4, 4)  # one-count rest noise
    t = patch_targets(x)
    assert torch.isfinite(t).all()
    assert torch.allclose(t[0, 0].mean(), torch.tensor(0.0), atol=1e-5)
    assert torch.allclose(t[0, 0].std(unbiased=False), torch.tensor(1.0), atol=1e-4)
    assert torch.count_nonzero(t[0, 2:]) == 0  # flat patches: exactly zero, no NaN
    # near-flat noise is not blown up to unit variance: the std floor holds it down
    assert t[0, 1].abs().max() < (1 / 300) / MIN_PATCH_STD + 1e-4


def test_masked_loss_counts_masked_patches_only() -> None:
    gen = torch.Generator().manual_seed(0)
    mask = random_mask(3, gen)
    assert (mask.sum(1) == round(MASK_RATIO * N_PATCHES)).all()
    target = torch.randn(3, N_PATCHES, 16)
    pred = torch.zeros_like(target)
    base = masked_loss(pred, target, mask)
    pred_unmasked = pred.clone()
    pred_unmasked[~mask] = 5.0
    assert torch.allclose(masked_loss(pred_unmasked, target, mask), base)
    pred_masked = pred.clone()
    pred_masked[mask] = 5.0
    assert masked_loss(pred_masked, target, mask) > base + 1.0
    x = torch.rand(3, 32, 32) + 0.1
    zeroed = patchify(apply_mask(x, mask))
    assert (zeroed[mask] == 0).all() and (zeroed[~mask] > 0).all()


def test_mae_on_toy_with_flat_frame_is_finite() -> None:
    mae = MAE(create_model("tactus-tiny", 8).cfg)
    x = torch.full((4, 32, 32), 0.07)  # all flat: every target is zero
    x[1, 9:15, 9:15] = 0.5  # edges inside patches: some non-flat targets
    loss, base = mae(x, random_mask(4, torch.Generator().manual_seed(1)))
    assert torch.isfinite(loss) and torch.isfinite(base) and 0 < float(base) <= 1.0
    loss.backward()
    assert all(torch.isfinite(p.grad).all() for p in mae.parameters() if p.grad is not None)


def test_pretrain_excludes_recordings_and_saves_trunk(tmp_path) -> None:
    d = synthetic(rec_per_class=2, frames_per_rec=6)
    held = sorted(set(d.recording_id[d.heldout_valid].tolist()))
    pool = pretrain_pool(d.recording_id, held)
    assert not np.isin(d.recording_id[pool], held).any()
    assert len(pool) == (~d.heldout_valid).sum()
    cfg = PretrainConfig(model="tactus-tiny", steps=3, batch=8, warmup=1, save_every=2)
    s = pretrain(
        d.calibrated, d.recording_id, held, tmp_path / "mae.safetensors", cfg, progress=False
    )
    assert s["frames"] == len(pool) and s["excluded_recordings"] == held
    from tactus_memory.training.pretrain import load_pretrained_trunk

    m = create_model("tactus-tiny", 8)
    meta = load_pretrained_trunk(m.trunk, tmp_path / "mae.safetensors", m.cfg)
    assert meta["excluded_recordings"] == held
    with pytest.raises(ValueError, match="does not match"):
        other = create_model("tactus-lite", 8)
        load_pretrained_trunk(other.trunk, tmp_path / "mae.safetensors", other.cfg)


def test_pretrain_warns_when_loss_sits_at_mean_prediction(tmp_path, caplog) -> None:
    d = synthetic(rec_per_class=1, frames_per_rec=4)
    cfg = PretrainConfig(model="tactus-tiny", steps=101, batch=2, lr=0.0, warmup=1, save_every=1000)
    torch.manual_seed(0)
    with caplog.at_level(logging.WARNING, logger="tactus_memory.training.pretrain"):
        s = pretrain(
            d.calibrated, d.recording_id, [], tmp_path / "m.safetensors", cfg, progress=False
        )
    # lr = 0: the decoder's output stays ~0 (its init), i.e. the mean prediction
    if s["final_ratio"] > 0.95:
        assert s["collapse_warning"] and "mean-prediction" in caplog.text
    else:  # an init far from zero output: then the warning must not fire
        assert not s["collapse_warning"]


# -- supervised ------------------------------------------------------------------------------


def test_augment_keeps_shape_and_is_not_identity() -> None:
    x = torch.rand(6, 8, 32, 32) * 0.3
    y = augment(x, AugmentConfig(), torch.Generator().manual_seed(0))
    assert y.shape == x.shape and (y >= 0).all()
    assert not torch.allclose(x, y)
    no = AugmentConfig(max_shift=0, gain=0, noise_std=0, shuffle=False, p_drop=0)
    assert torch.equal(augment(x, no, torch.Generator()), x)


def test_tiny_training_learns_separable_classes(tmp_path) -> None:
    d = synthetic()
    cfg = TrainConfig(
        model="tactus-tiny",
        steps=60,
        batch=16,
        lr=3e-3,
        warmup=4,
        sampling="random",
        save_every=1000,
    )
    s = fit(
        d,
        orthogonal_targets(),
        cfg,
        tmp_path / "t.safetensors",
        space_dim=DIM,
        device="cpu",
        progress=False,
    )
    print(s["heldout"])
    assert s["steps"] == 60
    assert s["heldout"]["top1"] >= 0.75  # chance 0.25
    assert s["heldout"]["recordings"] == N_CLS


def test_resume_continues_the_step_count(tmp_path) -> None:
    d = synthetic(rec_per_class=2, frames_per_rec=8)
    out = tmp_path / "r.safetensors"
    cfg = TrainConfig(
        model="tactus-tiny", steps=6, batch=4, warmup=1, sampling="random", save_every=3
    )
    s1 = fit(d, orthogonal_targets(), cfg, out, space_dim=DIM, device="cpu", progress=False)
    assert s1["steps"] == 6
    cfg.steps = 10
    s2 = fit(
        d, orthogonal_targets(), cfg, out, space_dim=DIM, device="cpu", progress=False, resume=True
    )
    assert s2["steps"] == 10 and s2["steps_this_run"] == 4
    assert load_checkpoint(out).meta["steps"] == 10


def test_checkpoint_round_trip_preserves_outputs(tmp_path) -> None:
    torch.manual_seed(0)
    m = create_model("tactus-tiny", DIM).eval()
    with torch.no_grad():  # non-trivial BN statistics
        for mod in m.modules():
            if isinstance(mod, torch.nn.BatchNorm2d):
                mod.running_mean.uniform_(-0.1, 0.1)
                mod.running_var.uniform_(0.5, 1.5)
    x = torch.rand(3, 8, 32, 32)
    with torch.inference_mode():
        ref = m(x)
    for half, tol in ((False, 1e-6), (True, 2e-2)):
        p = tmp_path / f"c{half}.safetensors"
        sha = save_checkpoint(
            p,
            m,
            orthogonal_targets(),
            space_dim=DIM,
            seed=3,
            steps=7,
            calibration={"name": "stag-glove"},
            half=half,
        )
        assert sha == file_sha256(p) and p.with_suffix(".json").exists()
        ck = load_checkpoint(p)
        with torch.inference_mode():
            assert torch.allclose(ck.model(x), ref, atol=tol)
        assert ck.meta["seed"] == 3 and ck.meta["steps"] == 7 and ck.sha256 == sha
        assert ck.meta["model"]["name"] == "tactus-tiny"


def test_holdout_specs() -> None:
    data = SimpleNamespace(
        sources=["/x/weights_lite/metadata.mat", "/x/blindfolded_lite_train/metadata.mat"],
        subset=np.array([0, 0, 1, 1, 1, 1, 1]),
        valid=np.array([1, 1, 1, 1, 0, 1, 1], bool),
        object_id=np.array([0, 1, 0, 0, 1, 1, 1]),
        recording_id=np.array([0, 1, 5, 4, 6, 7, 7]),
        recordings=["a", "b", "c", "d", "e", "f", "g", "h"],
    )
    assert holdout_recordings(data, "none") == []
    # object 0: recordings 4 and 5 -> 4; object 1: recording 6 has no valid frame -> 7
    assert holdout_recordings(data, "one-per-object@blindfolded") == [4, 7]
    assert holdout_recordings(data, "recordings@c,3") == [2, 3]
    with pytest.raises(ValueError):
        holdout_recordings(data, "one-per-object@nothing")
    with pytest.raises(ValueError):
        holdout_recordings(data, "bogus")
