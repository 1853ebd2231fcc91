"""Distillation (issue 22): the student learns the teachers' embeddings plus the labels.

Library level on separable synthetic touch (tests/training/test_train.py's toy data and space): a
distilled student ends closer to its teacher than the same student trained without one.
Real path through ``tactus distill``: synthetic STAG files (tests/helpers/stag_synth.py), real
MiniLM
targets, a real tactus-tiny teacher trained by ``tactus train``; the student checkpoint
loads, records its teacher's sha256, resumes, and a teacher of another space is refused.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import torch
from typer.testing import CliRunner

from tactus_memory.cli import app
from tactus_memory.hashing import file_sha256
from tactus_memory.touch.checkpoint import load_checkpoint, save_checkpoint
from tactus_memory.training.distill import (
    DistillConfig,
    TeacherLoss,
    TeacherMismatchError,
    distill,
)
from tactus_memory.training.train import TrainConfig, embed_windows, fit
from tests.helpers.training import DIM, HOLDOUT, _last_json, _run, orthogonal_targets, synthetic


def _cfg(steps: int) -> TrainConfig:
    return TrainConfig(model="tactus-tiny", steps=steps, batch=8, warmup=2, sampling="random")


def _heldout_windows(d) -> np.ndarray:
    """(W, 8, 32, 32): consecutive 8-frame windows of the held-out recordings."""
    out = []
    for r in np.unique(d.recording_id[d.heldout_valid]):
        fr = np.flatnonzero(d.heldout_valid & (d.recording_id == r))
        out += [d.calibrated[fr[i : i + 8]] for i in range(0, len(fr) - 7, 8)]
    return np.stack(out)


def test_teacher_loss_is_zero_when_the_student_is_the_teacher() -> None:
    torch.manual_seed(0)
    d = synthetic(rec_per_class=2, frames_per_rec=8)
    from tactus_memory.touch.model import create_model

    teacher = create_model("tactus-tiny", DIM).eval()
    ck = type("Ck", (), {"model": teacher})()
    x = torch.from_numpy(d.calibrated[:16].reshape(2, 8, 32, 32))
    loss = TeacherLoss([ck], DistillConfig(cosine_weight=1.0, relational_weight=1.0))
    with torch.no_grad():
        z = teacher(x)
        assert float(loss(x, z)) == pytest.approx(0.0, abs=1e-5)
        assert float(loss(x, torch.roll(z, 1, dims=-1))) > 0.01  # another embedding costs


def test_distilled_student_ends_closer_to_its_teacher(tmp_path) -> None:
    d = synthetic(rec_per_class=3, frames_per_rec=16)
    tgt = orthogonal_targets()
    teacher = tmp_path / "teacher.safetensors"
    fit(d, tgt, _cfg(30), teacher, space_dim=DIM, device="cpu", progress=False)
    plain, taught = tmp_path / "plain.safetensors", tmp_path / "taught.safetensors"
    cfg = replace(_cfg(20), seed=1)
    fit(d, tgt, cfg, plain, space_dim=DIM, device="cpu", progress=False)
    s = distill(
        d, tgt, cfg, taught, [teacher], space_dim=DIM, dcfg=DistillConfig(cosine_weight=5.0),
        device="cpu", progress=False,
    )  # fmt: skip
    assert s["steps"] == 20 and "heldout" in s
    wins = _heldout_windows(d)
    t = embed_windows(load_checkpoint(teacher).model, wins)
    cos_plain = float((embed_windows(load_checkpoint(plain).model, wins) * t).sum(1).mean())
    cos_taught = float((embed_windows(load_checkpoint(taught).model, wins) * t).sum(1).mean())
    assert cos_taught > cos_plain + 0.05, (cos_taught, cos_plain)
    rec = load_checkpoint(taught).meta["train_args"]["distill"]
    assert rec["teachers"][0]["sha256"] == file_sha256(teacher)
    assert rec["cosine_weight"] == 5.0


def test_a_teacher_of_another_space_is_refused(tmp_path) -> None:
    d = synthetic(rec_per_class=2, frames_per_rec=8)
    tgt = orthogonal_targets()
    teacher = tmp_path / "t.safetensors"
    fit(d, tgt, _cfg(2), teacher, space_dim=DIM, device="cpu", progress=False)
    other = tmp_path / "other.safetensors"
    ck = load_checkpoint(teacher)
    save_checkpoint(other, ck.model, replace(tgt, space_name="elsewhere"), space_dim=DIM)
    out = tmp_path / "s.safetensors"
    with pytest.raises(TeacherMismatchError, match="elsewhere"):
        distill(d, tgt, _cfg(2), out, [teacher, other], space_dim=DIM, device="cpu")
    assert not out.exists()
    with pytest.raises(ValueError, match="both 0"):
        DistillConfig(cosine_weight=0.0, relational_weight=0.0)


# -- the real path: tactus train -> tactus distill ------------------------------------------

COMMON = ["--model", "tactus-tiny", "--threads", "1", "--holdout", HOLDOUT, "--batch", "8"]


@pytest.fixture(scope="module")
def teacher(data, tmp_path_factory) -> Path:  # noqa: F811
    ck = tmp_path_factory.mktemp("teacher") / "teacher.safetensors"
    _run(["train", *data, "--out", str(ck), "--steps", "3", *COMMON])
    return ck


def test_tactus_distill_records_its_teachers_and_resumes(data, teacher, tmp_path) -> None:  # noqa: F811
    out = tmp_path / "student.safetensors"
    args = ["distill", *data, "--out", str(out), "--teacher", str(teacher), *COMMON]
    args += ["--teacher", str(teacher), "--relational-weight", "0.5", "--augment", "strong"]
    s = _last_json(_run([*args, "--steps", "2"]))
    assert s["steps"] == 2 and s["heldout"]["recordings"] == 27
    s = _last_json(_run([*args, "--steps", "4", "--resume"]))
    assert s["steps"] == 4 and s["steps_this_run"] == 2
    ck = load_checkpoint(out)
    assert ck.space_name == "minilm-l6" and ck.dim == 384 and ck.meta["steps"] == 4
    rec = ck.meta["train_args"]["distill"]
    assert [t["sha256"] for t in rec["teachers"]] == [file_sha256(teacher)] * 2
    assert rec["relational_weight"] == 0.5 and ck.meta["train_args"]["augment"]["p_drop"] == 0.5


def test_tactus_distill_refuses_a_teacher_of_another_space(data, teacher, tmp_path) -> None:  # noqa: F811
    ck = load_checkpoint(teacher)
    other = tmp_path / "other.safetensors"
    save_checkpoint(other, ck.model, replace(ck.targets, space_name="qwen3-vl"), space_dim=384)
    out = tmp_path / "never.safetensors"
    args = ["distill", *data, "--out", str(out), "--teacher", str(other), "--steps", "2"]
    r = CliRunner().invoke(app, [*args, *COMMON])
    assert r.exit_code == 2
    assert "qwen3-vl" in r.output and "minilm-l6" in r.output
    assert not out.exists()
