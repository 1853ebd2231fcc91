"""The supervised STAG CNN: shapes, training above chance on separable data, save/load, CLI."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch

from tactus_memory.training.baseline import (
    BaselineConfig,
    BaselineScorer,
    StagCNN,
    load_baseline,
    predict_proba,
    save_baseline,
    train_baseline,
)
from tactus_memory.training.evaluate import EvalSet, evaluate_scorer
from tactus_memory.training.train import TrainData

torch.set_num_threads(1)


def test_shapes_follow_the_reference():
    net = StagCNN(n_classes=27, frames=8)
    out = net(torch.rand(2, 8, 32, 32))
    assert out.shape == (2, 27)
    feats = net.trunk(torch.rand(3, 1, 32, 32))
    assert feats.shape == (3, 128, 8, 8)  # stag-format.md: 128 x 8 x 8 per frame
    assert net.fuse[0].in_channels == 8 * 128 and net.fuse[0].out_channels == 128
    with pytest.raises(ValueError):
        net(torch.rand(2, 4, 32, 32))


def _separable(n_classes: int = 3, per_rec: int = 12, recs: int = 2, seed: int = 0) -> TrainData:
    """Class c presses a bright 8x8 block at a class-specific place; noise elsewhere."""
    rng = np.random.default_rng(seed)
    cal, lab, rec = [], [], []
    r = 0
    for c in range(n_classes):
        for _ in range(recs):
            f = rng.uniform(0.05, 0.1, size=(per_rec, 32, 32)).astype(np.float32)
            f[:, 4:12, 8 * c : 8 * c + 8] = rng.uniform(0.5, 0.9, size=(per_rec, 1, 1))
            cal.append(f)
            lab += [c] * per_rec
            rec += [r] * per_rec
            r += 1
    n = len(lab)
    return TrainData(
        calibrated=np.concatenate(cal),
        labels=np.array(lab, np.int64),
        recording_id=np.array(rec, np.int64),
        train_valid=np.ones(n, bool),
        heldout_valid=np.zeros(n, bool),
        classes=[f"c{i}" for i in range(n_classes)],
    )


def test_trains_above_chance_on_separable_data(tmp_path: Path):
    td = _separable()
    cfg = BaselineConfig(epochs=100, batch=12, k=1, max_steps=60, noise=0.015, seed=0)
    net, summary = train_baseline(td, cfg, progress=False)
    assert summary["steps"] == 60  # BN running statistics need a few dozen steps
    es = EvalSet(
        calibrated=td.calibrated, labels=td.labels, recording_id=td.recording_id,
        members=td.train_valid, anchors=td.train_valid, classes=td.classes,
        recordings=[str(i) for i in range(6)], split="all",
    )  # fmt: skip
    m = evaluate_scorer(BaselineScorer(net, td.classes), es, votes=2, progress=False).metrics
    assert m["top1"] > 0.8 > 1 / 3  # chance is 1/3
    assert m["recording_top1"] >= 2 / 3

    path = tmp_path / "b.safetensors"
    save_baseline(path, net, {"classes": td.classes, "epochs": 20, "seed": 0})
    net2, meta = load_baseline(path)
    assert meta["format"] == "tactus-stag-baseline/1" and meta["classes"] == td.classes
    assert "CC-BY-NC" in meta["license"]
    w = td.calibrated[:5, None]
    assert np.allclose(predict_proba(net, w), predict_proba(net2, w), atol=1e-6)
    assert json.loads(path.with_suffix(".json").read_text())["sha256"]


def test_probability_pooling_of_identical_draws_changes_nothing():
    sc = BaselineScorer(StagCNN(3, 1), ["a", "b", "c"])
    p = np.array([[0.2, 0.5, 0.3], [0.6, 0.3, 0.1]], np.float32)
    assert np.allclose(sc.pool(np.stack([p, p, p])), p)


def test_cli_baseline_train_and_eval(tmp_path: Path):
    from typer.testing import CliRunner

    from tactus_memory.cli import app
    from tests.helpers.stag_synth import make_fields, write_subset

    folder = write_subset(tmp_path, "cls", make_fields("classification", [12, 10, 8, 9]))
    ck = tmp_path / "base.safetensors"
    runner = CliRunner()
    r = runner.invoke(
        app,
        [
            "baseline",
            "train",
            "--data",
            str(folder),
            "--out",
            str(ck),
            "--epochs",
            "1",
            "--max-steps",
            "2",
            "--batch",
            "4",
            "--k",
            "2",
            "--holdout",
            "recordings@1",
        ],
    )
    assert r.exit_code == 0, r.output
    _, meta = load_baseline(ck)
    assert meta["holdout"] == "recordings@1" and meta["heldout"]["n_recordings"] == 1
    assert meta["train"]["steps"] == 2
    out = tmp_path / "b.json"
    r = runner.invoke(
        app,
        [
            "baseline",
            "eval",
            "--checkpoint",
            str(ck),
            "--data",
            str(folder),
            "--json",
            str(out),
            "--votes",
            "2",
        ],
    )
    assert r.exit_code == 0, r.output
    m = json.loads(out.read_text())
    assert m["model_kind"] == "baseline" and m["checkpoint"]["kind"] == "baseline"
    for key in ("top1", "top3", "top1_vote", "top3_vote", "recording_top1", "confusion"):
        assert key in m
    assert m["n_recordings"] == 2
    from tests.helpers.metric_checks import check_metrics

    check_metrics(m)  # values consistent, not only present
