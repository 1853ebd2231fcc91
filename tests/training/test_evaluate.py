"""Evaluation metrics on hand-made cases whose answers are known, and the `tactus eval` CLI."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from tactus_memory.training.evaluate import (
    EmbeddingScorer,
    EvalSet,
    evaluate_scorer,
    scope_mask,
)
from tactus_memory.training.metrics import (
    aggregate_runs,
    confusion_counts,
    ksweep_windows,
    mean_std,
    mean_unit,
    pad_window,
    pair_spearman,
    recording_windows,
    row_normalise,
    text_confusion_correlation,
    topk_accuracy,
    unit_rows,
)

CLASSES = ["a", "b", "c", "d", "e"]


def _evalset(frames_per_rec: list[int], labels: list[int], seed: int = 0) -> EvalSet:
    """Recording r holds class labels[r]; pixel (0, 0) of every frame encodes its class."""
    rng = np.random.default_rng(seed)
    cal, lab, rec = [], [], []
    for r, (n, c) in enumerate(zip(frames_per_rec, labels, strict=True)):
        f = rng.uniform(0.0, 0.1, size=(n, 32, 32)).astype(np.float32)
        f[:, 0, 0] = (c + 1) / 100.0
        cal.append(f)
        lab += [c] * n
        rec += [r] * n
    n_all = len(lab)
    members = np.ones(n_all, bool)
    return EvalSet(
        calibrated=np.concatenate(cal),
        labels=np.array(lab, np.int64),
        recording_id=np.array(rec, np.int64),
        members=members,
        anchors=members.copy(),
        classes=list(CLASSES),
        recordings=[f"rec{r}" for r in range(len(labels))],
        split="test",
    )


def _targets(n: int = len(CLASSES), d: int = 16) -> np.ndarray:
    return unit_rows(np.random.default_rng(7).normal(size=(n, d)))


def _perfect(targets: np.ndarray):
    def fn(windows: np.ndarray) -> np.ndarray:
        cls = np.rint(windows[:, 0, 0, 0] * 100).astype(int) - 1  # the anchor's class
        return targets[cls]

    return fn


def _constant(targets: np.ndarray, c: int):
    return lambda windows: np.repeat(targets[c : c + 1], len(windows), axis=0)


# recordings of classes 0..4, one of class 2 with only two valid frames (< k)
FRAMES = [12, 10, 9, 11, 12, 2, 10]
LABELS = [0, 1, 2, 3, 4, 2, 0]


def test_perfect_model_scores_one():
    t = _targets()
    es = _evalset(FRAMES, LABELS)
    res = evaluate_scorer(EmbeddingScorer(_perfect(t), t, CLASSES, k=4), es, progress=False)
    m = res.metrics
    assert m["top1"] == 1.0 and m["top3"] == 1.0
    assert m["top1_vote"] == 1.0 and m["recording_top1"] == 1.0
    assert m["n_tuples"] == sum(FRAMES)
    assert m["n_recordings"] == len(FRAMES)  # the 2-frame recording still counts
    assert all(v == 1.0 for v in m["per_class"].values())
    assert m["ksweep"] == {"1": 1.0, "2": 1.0, "4": 1.0}
    conf = np.array(m["confusion"])
    assert np.allclose(conf, np.eye(len(CLASSES)))
    short = [p for p in m["per_recording"] if p["recording"] == "rec5"][0]
    assert short["frames"] == 2 and short["windows"] == 1 and short["pred"] == 2


def test_constant_model_scores_class_prior():
    t = _targets()
    es = _evalset(FRAMES, LABELS)
    res = evaluate_scorer(EmbeddingScorer(_constant(t, 2), t, CLASSES, k=4), es, progress=False)
    m = res.metrics
    prior = (np.array(LABELS).repeat(FRAMES) == 2).mean()
    assert m["top1"] == pytest.approx(prior)
    assert m["top1_vote"] == pytest.approx(prior)
    assert m["recording_top1"] == pytest.approx(np.mean(np.array(LABELS) == 2))
    assert m["per_class"]["c"] == 1.0 and m["per_class"]["a"] == 0.0
    conf = np.array(m["confusion"])
    assert np.allclose(conf[:, 2], 1.0) and np.allclose(conf.sum(axis=1), 1.0)


def test_topk_and_ties():
    s = np.array([[0.1, 0.9, 0.5], [0.3, 0.2, 0.1], [0.0, 0.0, 0.0]])
    y = np.array([1, 2, 0])
    assert topk_accuracy(s, y, 1) == pytest.approx(2 / 3)  # a tie predicts class 0
    assert topk_accuracy(s, y, 2) == pytest.approx(2 / 3)
    assert topk_accuracy(s, y, 3) == 1.0


def test_voting_over_identical_draws_changes_nothing():
    e = unit_rows(np.random.default_rng(0).normal(size=(5, 8)))
    assert np.allclose(mean_unit(np.stack([e, e, e, e])), e, atol=1e-6)
    t = _targets(3, 8)
    sc = EmbeddingScorer(lambda w: w, t, ["x", "y", "z"], k=1)
    assert np.allclose(sc.scores(sc.pool(np.stack([e, e]))), sc.scores(e), atol=1e-6)


def test_spearman_known_orderings():
    sim = np.array([[1.0, 0.1, 0.2], [0.3, 1.0, 0.4], [0.5, 0.6, 1.0]])
    up = np.array([[0.9, 0.01, 0.02], [0.03, 0.8, 0.04], [0.05, 0.06, 0.7]])
    assert pair_spearman(up, sim)["rho"] == pytest.approx(1.0)
    down = np.array([[0.9, 0.06, 0.05], [0.04, 0.8, 0.03], [0.02, 0.01, 0.7]])
    assert pair_spearman(down, sim)["rho"] == pytest.approx(-1.0)
    assert pair_spearman(up, sim)["n_pairs"] == 6
    assert pair_spearman(np.eye(3), sim)["rho"] is None  # no confusion at all: undefined
    t = _targets(27, 32)
    conf = row_normalise(np.random.default_rng(1).random((27, 27)))
    out = text_confusion_correlation(conf, t, t)
    assert out["uncentred"]["n_pairs"] == 702 and out["centred"]["n_pairs"] == 702


def test_confusion_rows_sum_to_one():
    y = np.array([0, 0, 1, 1, 1, 3])
    p = np.array([0, 1, 1, 2, 1, 0])
    counts = confusion_counts(y, p, 4)
    assert counts.sum() == 6 and counts[1, 1] == 2
    conf = row_normalise(counts)
    assert np.allclose(conf.sum(axis=1), [1, 1, 0, 1])  # class 2 has no samples: zero row
    assert conf[1, 2] == pytest.approx(1 / 3)


def test_ksweep_and_windows_repeat_the_last_frame():
    t = np.array([[10, 11, 12, 13], [20, 21, 22, 23]])
    assert ksweep_windows(t, 1).tolist() == [[10, 10, 10, 10], [20, 20, 20, 20]]
    assert ksweep_windows(t, 2).tolist() == [[10, 11, 11, 11], [20, 21, 21, 21]]
    assert ksweep_windows(t, 4).tolist() == t.tolist()
    assert pad_window(np.array([5, 6]), 4).tolist() == [5, 6, 6, 6]
    w = recording_windows(np.arange(10), 4)
    assert w.tolist() == [[0, 1, 2, 3], [4, 5, 6, 7], [8, 9, 9, 9]]
    assert recording_windows(np.array([7]), 8).tolist() == [[7] * 8]
    big = recording_windows(np.arange(100), 8)
    assert big.shape == (8, 8) and big[0, 0] == 0 and big[-1, -1] == 99


def test_padding_matches_the_model():
    """ksweep padding is what TactusModel.pad_frames does to a short window."""
    import torch

    from tactus_memory.touch.model import create_model

    model = create_model("tactus-tiny", out_dim=8, frames=4)
    x = torch.rand(1, 4, 32, 32)
    padded = model.pad_frames(x[:, :2])
    assert torch.equal(padded, x[:, ksweep_windows(np.array([[0, 1, 2, 3]]), 2)[0]])


def test_mean_and_sample_std():
    s = mean_std([0.7, 0.8, None])
    assert s["mean"] == pytest.approx(0.75) and s["std"] == pytest.approx(
        np.std([0.7, 0.8], ddof=1)
    )
    assert mean_std([0.5])["std"] is None
    agg = aggregate_runs([{"top1": 0.6, "ksweep": {"1": 0.2}}, {"top1": 0.8, "ksweep": {"1": 0.4}}])
    assert agg["top1"]["mean"] == pytest.approx(0.7) and agg["ksweep_1"]["mean"] == pytest.approx(
        0.3
    )


def test_scope_no_split_file_is_scored_whole(tmp_path: Path):
    from tactus_memory.training.data import combine, load_stag
    from tests.helpers.stag_synth import make_fields, write_subset

    cls = load_stag(write_subset(tmp_path, "cls", make_fields("classification", [20, 20, 20])))
    wts = load_stag(write_subset(tmp_path, "wts", make_fields("weights", [20, 20], seed=1)))
    d = combine([cls, wts])
    m = scope_mask(d, "test")
    assert m[cls.n_frames :].sum() == wts.valid.sum()  # weights: every valid frame
    test_rec = cls.valid & (cls.recording_id % 2 == 1)
    assert np.array_equal(m[: cls.n_frames], test_rec)
    assert scope_mask(d, "all").sum() == d.valid.sum()
    held = scope_mask(d, "test", holdout=[0])
    assert held.sum() == (cls.valid & (cls.recording_id == 0)).sum()  # a train recording


# --------------------------------------------------------------------------- CLI


def _tiny_checkpoint(path: Path, seed: int) -> Path:
    import torch

    from tactus_memory.touch.checkpoint import save_checkpoint
    from tactus_memory.touch.model import create_model
    from tactus_memory.touch.targets import build_targets
    from tests.helpers.fakes import HashingSpace
    from tests.helpers.stag_synth import OBJECTS

    torch.manual_seed(seed)
    model = create_model("tactus-tiny", out_dim=32, frames=4)
    targets = build_targets(HashingSpace(dim=32), OBJECTS)
    save_checkpoint(path, model, targets, space_dim=32, seed=seed)
    return path


def test_cli_eval_end_to_end(tmp_path: Path):
    from typer.testing import CliRunner

    from tactus_memory.cli import app
    from tests.helpers.metric_checks import check_metrics
    from tests.helpers.stag_synth import make_fields, write_subset

    folder = write_subset(tmp_path, "cls", make_fields("classification", [16, 14, 12, 3, 10, 9]))
    a = _tiny_checkpoint(tmp_path / "a.safetensors", 0)
    b = _tiny_checkpoint(tmp_path / "b.safetensors", 1)
    runner = CliRunner()
    out = tmp_path / "one.json"
    r = runner.invoke(
        app,
        [
            "eval",
            "--checkpoint",
            str(a),
            "--data",
            str(folder),
            "--json",
            str(out),
            "--report",
            str(tmp_path / "rep"),
            "--votes",
            "2",
        ],
    )
    assert r.exit_code == 0, r.output
    m = json.loads(out.read_text())
    for key in (
        "top1",
        "top3",
        "top1_vote",
        "top3_vote",
        "recording_top1",
        "n_tuples",
        "n_recordings",
        "per_class",
        "confusion",
        "chance",
        "classes",
        "split",
        "data",
    ):
        assert key in m, key
    check_metrics(m)  # values consistent, not only present
    assert m["checkpoint"]["sha256"] and m["data"][0]["fingerprint"]
    assert m["n_recordings"] == 3 and m["split"] == "test"  # odd recordings are 'test'
    assert len(m["confusion"]) == 27 and m["chance"] == pytest.approx(1 / 27)
    for f in ("report.md", "confusion.png", "ksweep.png", "results.json"):
        assert (tmp_path / "rep" / f).is_file(), f
    assert list((tmp_path / "rep" / "examples").glob("*.png"))
    assert "Spearman" in (tmp_path / "rep" / "report.md").read_text()

    # several runs -> mean and sample std; a holdout spec replaces the split
    out2 = tmp_path / "two.json"
    r = runner.invoke(
        app,
        [
            "eval",
            "--checkpoint",
            str(a),
            "--checkpoint",
            str(b),
            "--data",
            str(folder),
            "--json",
            str(out2),
            "--holdout",
            "recordings@0,3",
            "--votes",
            "1",
            "--no-analysis",
        ],
    )
    assert r.exit_code == 0, r.output
    m2 = json.loads(out2.read_text())
    assert m2["n_runs"] == 2 and len(m2["runs"]) == 2 and m2["n_recordings"] == 2
    vals = [run["top1"] for run in m2["runs"]]
    assert m2["top1"] == pytest.approx(np.mean(vals))
    assert m2["aggregate"]["top1"]["std"] == pytest.approx(np.std(vals, ddof=1))
    assert m2["split"] == "holdout:recordings@0,3"


def test_ablation_rows_change_one_thing():
    from tactus_memory.training.ablate import ROWS

    base = ROWS["recipe"]
    assert base == {"norm": "affine", "sampling": "cluster", "mae": True}
    for name, row in ROWS.items():
        assert sum(row[k] != base[k] for k in base) == (0 if name == "recipe" else 1), name


def test_per_file_max_scaling_is_the_defect():
    from tactus_memory.training.ablate import per_file_max_scaled

    p = np.full((4, 32, 32), 510, np.int16)
    p[0, 0, 0], p[2, 0, 0] = 1000, 654  # file 0 saturates, file 1 (weights-like) does not
    out = per_file_max_scaled(p, np.array([0, 0, 1, 1]))
    assert out[0, 0, 0] == 1.0 and out[2, 0, 0] == 1.0  # each file's max maps to 1
    assert out[1, 5, 5] == pytest.approx(0.51) and out[3, 5, 5] == pytest.approx(510 / 654)


def test_ablation_runs_seeds_and_aggregates(tmp_path: Path):
    from tactus_memory.training.ablate import AblationConfig, format_table, run_ablation
    from tests.helpers.fakes import HashingSpace
    from tests.helpers.stag_synth import make_fields, write_subset

    folder = write_subset(tmp_path, "cls", make_fields("classification", [12, 10, 8, 10]))
    cfg = AblationConfig(
        steps=2,
        pretrain_steps=2,
        seeds=2,
        holdout="recordings@1",
        model="tactus-tiny",
        batch=4,
        pretrain_batch=8,
        rows=["recipe", "no_mae"],
    )
    res = run_ablation([folder], cfg, tmp_path / "abl", space=HashingSpace(dim=384), progress=False)
    assert len(res["runs"]) == 4 and res["heldout_recordings"] == ["001-allen_key_set"]
    for row in res["rows"].values():
        assert row["top1"]["n"] == 2 and row["top1"]["mean"] is not None
    assert "| no_mae |" in format_table(res)
    assert len(list((tmp_path / "abl").glob("mae_*.safetensors"))) == 2  # one per seed


def test_leakage_check_flags_trained_on_recordings():
    from tactus_memory.training.eval_runs import leakage_check

    es = _evalset([4, 4, 4], [0, 1, 2])
    es.fingerprint = "fp"
    held = {"train_data_fingerprint": "fp", "train_heldout_recordings": ["rec0", "rec1", "rec2"]}
    assert leakage_check(held, es)["status"] == "clean"
    partly = dict(held, train_heldout_recordings=["rec0"])
    out = leakage_check(partly, es)
    assert out["status"] == "overlap" and out["trained_on"] == 2
    assert leakage_check(dict(held, train_data_fingerprint="other"), es)["status"] == "unknown"
