"""The validation protocol (touch/training/protocol.py): folds, jobs, budget, pairing, resume,
and the GPU script run on CPU with tiny step counts (scripts/gpu_recipe.sh)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tarfile
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from tactus_memory.training.protocol import (
    FOLDS,
    Plan,
    Recipe,
    budget_scale,
    build_jobs,
    shrink,
    without,
)
from tactus_memory.training.protocol_report import interval, report
from tactus_memory.training.protocol_run import RunnerConfig, run_plan

ROOT = Path(__file__).resolve().parents[2]


def _plan(**kw) -> Plan:
    recipes = [
        Recipe(name="base", mae_steps=4, steps=4),
        Recipe(name="teacher", model="tactus-tiny", mae_steps=4, steps=8, seeds=[0, 1]),
        Recipe(name="student", mae_steps=4, steps=4, teacher="teacher", teachers=2),
    ]
    p = Plan(recipes=recipes, baseline="base", final={"teacher": [0, 1], "student": [0]}, **kw)
    p.check()
    return p


def test_shipped_plans_load_and_check() -> None:
    for name in ("cpu", "gpu", "gpu-distill"):
        plan = Plan.load(name)
        assert plan.baseline in {r.name for r in plan.recipes}
        assert build_jobs(plan)


def test_jobs_share_mae_trunks_and_students_wait_for_their_fold_teachers() -> None:
    jobs = {j.key: j for j in build_jobs(_plan())}
    # base and student pretrain alike (lite, 4 x 128): one MAE job per fold, shared
    assert (
        jobs["base/A-s0"].pretrained
        == jobs["student/A-s2"].pretrained
        == "mae/mae-tactus-lite-4x128-A"
    )
    # the teacher runs 2 seeds a fold; a fold's students learn from that fold's teachers only
    assert "teacher/A-s2" not in jobs
    assert jobs["student/B-s1"].teachers == ["teacher/B-s0", "teacher/B-s1"]
    assert jobs["student/all-s0"].teachers == ["teacher/all-s0", "teacher/all-s1"]
    assert set(jobs["student/A-s0"].deps) == {
        "mae/mae-tactus-lite-4x128-A",
        "teacher/A-s0",
        "teacher/A-s1",
    }
    # every dependency is a job of the plan, listed before the job that needs it
    order = list(jobs)
    for j in jobs.values():
        assert all(order.index(d) < order.index(j.key) for d in j.deps)


def test_plan_refuses_what_cannot_run() -> None:
    with pytest.raises(KeyError, match="nope"):
        replace(_plan(), baseline="nope").check()
    bad = _plan()
    bad.recipes[2] = replace(bad.recipes[2], teachers=3)
    with pytest.raises(ValueError, match="teachers"):
        bad.check()
    with pytest.raises(ValueError, match="fold"):
        replace(_plan(), folds=["A", "C"]).check()


def test_budget_scales_the_teacher_or_drops_it_with_its_students() -> None:
    plan = _plan(budget_s=10.0, scaled=["teacher"], min_scale=0.5)
    jobs = build_jobs(plan)
    fixed = sum(j.steps * j.batch / 512 for j in jobs if j.key.startswith("mae/mae-tactus-tiny"))
    fixed += sum(j.steps * len(j.teachers) / 3 for j in jobs if j.key.startswith("student/"))
    scalable = sum(j.steps for j in jobs if j.key.startswith("teacher/"))
    # a step so fast that everything fits: no scaling
    assert budget_scale(plan, 1e-6) == {"teacher": 1.0}
    # a step where 60 % of the teacher's steps fit
    step = 10.0 / (fixed + 0.6 * scalable)
    assert budget_scale(plan, step)["teacher"] == pytest.approx(0.6)
    # too slow for min_scale: None, and the plan without the teacher has no student either
    assert budget_scale(plan, 10.0) is None
    rest = without(plan, ["teacher"])
    assert [r.name for r in rest.recipes] == ["base"] and rest.final == {}


def test_interval_and_paired_difference() -> None:
    iv = interval([0.2, 0.3, 0.4])
    assert iv["n"] == 3 and iv["mean"] == pytest.approx(0.3)
    # t(0.975, 2) = 4.303; sd = 0.1 -> half width 0.2484
    assert iv["hi"] - iv["mean"] == pytest.approx(4.303 * 0.1 / np.sqrt(3), rel=1e-3)
    assert interval([0.5]) == {"n": 1, "mean": 0.5}
    rows = []
    for fold in ("A", "B"):
        for seed in (0, 1, 2):
            b = 0.2 + 0.1 * seed + (0.05 if fold == "B" else 0.0)
            rows.append({"recipe": "base", "fold": fold, "seed": seed, "steps": 4, "top1": b})
            # the other recipe is exactly 0.03 better on every pair: the paired interval is a
            # point although both recipes' own intervals are wide and overlap
            rows.append({"recipe": "new", "fold": fold, "seed": seed, "steps": 4, "top1": b + 0.03})
    rows.append({"recipe": "new", "fold": "all", "seed": 0, "steps": 4, "top1": None})
    rep = report(rows, "base")
    new = rep["recipes"]["new"]
    assert new["runs"] == 6  # the run on all data is not a fold run
    assert new["top1_paired_diff"]["mean"] == pytest.approx(0.03)
    assert new["top1_paired_diff"]["hi"] - new["top1_paired_diff"]["lo"] == pytest.approx(
        0, abs=1e-9
    )
    assert new["top1"]["lo"] < rep["recipes"]["base"]["top1"]["hi"]  # unpaired: overlap


def test_folds_hold_out_each_objects_other_recording(stag_subset) -> None:
    from tactus_memory.training.train import holdout_recordings, load_data

    d = load_data([stag_subset("weights_lite"), stag_subset("blindfolded_lite_train")])
    a = holdout_recordings(d, FOLDS["A"])
    b = holdout_recordings(d, FOLDS["B"])
    assert not set(a) & set(b)
    obj = {r: int(d.object_id[d.recording_id == r][0]) for r in a + b}
    # one recording of every blindfolded object in each fold, the same objects in both
    assert len({obj[r] for r in a}) == len(a) == len(b) == len({obj[r] for r in b})
    assert {obj[r] for r in a} == {obj[r] for r in b}
    assert all(
        min(ra, rb) == ra
        for ra, rb in zip(sorted(a, key=obj.get), sorted(b, key=obj.get), strict=True)
    )
    assert holdout_recordings(d, FOLDS["all"]) == []


def test_runner_resumes_and_skips_finished_runs(stag_subset, tmp_path: Path) -> None:
    data = [str(stag_subset("weights_lite")), str(stag_subset("blindfolded_lite_train"))]
    plan = shrink(
        Plan(recipes=[Recipe(name="base", model="tactus-tiny", steps=2)], baseline="base"),
        max_steps=2, seeds=[0], swap={}, folds=["A"],
    )  # fmt: skip
    rc = RunnerConfig(out=tmp_path, data=data, jobs=1, device="cpu")
    first = run_plan(plan, rc)
    assert first["done"] == ["base/A-s0"] and not first["failed"]
    res = json.loads((tmp_path / "base/A-s0.result.json").read_text())
    assert res["tuples"] > 0 and 0.0 <= res["top1"] <= 1.0 and res["fold"] == "A"
    log = tmp_path / "base/A-s0.log"
    stamp = log.stat().st_mtime_ns
    again = run_plan(plan, rc)
    assert again["done"] == ["base/A-s0"]
    assert log.stat().st_mtime_ns == stamp  # not started again


def test_gpu_script_runs_on_cpu_with_tiny_steps(stag_dir: Path, tmp_path: Path) -> None:
    """The whole GPU recipe (MAE, teachers, distillation, protocol, packing) on CPU: r18
    swapped for tactus-tiny, 2 steps, seed 0, fold A."""
    out = tmp_path / "out"
    env = {
        **os.environ,
        "STAG": str(stag_dir),
        "WORK": str(tmp_path / "work"),
        "DEVICE": "cpu",
        "MAX_STEPS": "2",
        "SEEDS": "0",
        "FOLDS": "A",
        "SWAP": "tactus-r18=tactus-tiny",
        "JOBS": "2",
        "PYTHON": sys.executable,
    }
    r = subprocess.run(
        ["bash", str(ROOT / "scripts/gpu_recipe.sh"), str(out)],
        env=env, capture_output=True, text=True, timeout=900,
    )  # fmt: skip
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    names = sorted(p.name for p in out.iterdir())
    assert names == [
        "final.tar",
        "results.tar.gz",
        "shipped-folds.tar",
        "strong-folds.tar",
        "student-folds.tar",
    ]
    assert all(p.stat().st_size <= 16 * 2**20 for p in out.iterdir())
    with tarfile.open(out / "results.tar.gz") as t:
        rep = json.load(t.extractfile("./report.json"))
    assert set(rep["recipes"]) == {"r18", "student", "shipped", "strong", "strong-fp32"}
    assert rep["recipes"]["student"]["top1_paired_diff"]["n"] == 1
    with tarfile.open(out / "final.tar") as t:
        t.extractall(tmp_path / "final", filter="data")
    from tactus_memory.touch.checkpoint import load_checkpoint

    student = load_checkpoint(tmp_path / "final/student/all-s0.safetensors")
    teachers = student.meta["train_args"]["distill"]["teachers"]
    assert [t["model"] for t in teachers] == ["tactus-tiny"]  # the swapped r18
    assert student.meta["weights_dtype"] == "float32"  # what ships is not halved
