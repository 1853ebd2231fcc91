"""The protocol's runner (``python -m tactus_memory.training.protocol_run run ...``;
``tactus eval-recipe`` and ``scripts/gpu_recipe.sh`` call it): each job of a plan
(:mod:`tactus_memory.training.protocol`) runs in its own process, at most ``jobs`` at a
time, in dependency order; a run is done when its ``<run>.result.json`` exists, so a killed
plan resumes where it stopped."""

from __future__ import annotations

import json
import logging
import os
import subprocess
import sys
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from tactus_memory.training.protocol import (
    FOLDS,
    Plan,
    Recipe,
    budget_scale,
    build_jobs,
    probe_step_s,
    shrink,
    without,
)
from tactus_memory.training.protocol_report import (
    add_stream_metrics,
    report_markdown,
    write_report,
)

log = logging.getLogger("tactus_memory.training.protocol_run")

MODULE = "tactus_memory.training.protocol_run"  # each job runs as `python -m MODULE job`

# -- one job (in its own process) -------------------------------------------------------------


def _targets(targets_from: str | None, classes: list[str]) -> tuple[Any, int]:
    """The class targets: read from a checkpoint (no text model needed, e.g. on a GPU machine
    without MiniLM) or embedded by the default space. Returns (Targets, dim)."""
    if targets_from:
        from tactus_memory.touch.checkpoint import load_checkpoint

        ck = load_checkpoint(targets_from, weights=False)
        if ck.targets.classes != classes:
            raise ValueError(f"{targets_from} has classes {ck.targets.classes}, the data {classes}")
        return ck.targets, ck.dim
    from tactus_memory.spaces.resolve import resolve_space
    from tactus_memory.touch.targets import build_targets

    space = resolve_space(None)
    return build_targets(space, classes), space.dim


def run_job(spec: dict[str, Any]) -> dict[str, Any]:
    """Run one job from its spec (``Job.spec``) and write ``<out>/<key>.result.json``."""
    import torch

    from tactus_memory.touch.profile import STAG_GLOVE
    from tactus_memory.training.augment import augment_preset
    from tactus_memory.training.pretrain import PretrainConfig, pretrain, recipe_warmup
    from tactus_memory.training.train import (
        TrainConfig,
        _resolve_device,
        holdout_recordings,
        load_data,
        prepare_data,
    )

    out = Path(spec["out"])
    key = spec["key"]
    ckpt = out / f"{key}.safetensors"
    done = out / f"{key}.result.json"
    device = _resolve_device(spec["device"])
    if device.startswith("cuda"):
        torch.backends.cudnn.benchmark = True  # fixed shapes: let cuDNN pick its kernels
        torch.backends.cuda.matmul.allow_tf32 = True
    t0 = time.perf_counter()
    d = load_data(spec["data"])
    excl = holdout_recordings(d, FOLDS[spec["fold"]])
    result: dict[str, Any] = {"key": key, "kind": spec["kind"], "fold": spec["fold"]}
    result["seed"] = spec["seed"]
    if spec["kind"] == "mae":
        cfg = PretrainConfig(
            model=spec["model"], steps=spec["steps"], batch=spec["batch"], seed=spec["seed"],
            warmup=recipe_warmup(spec["steps"]),
        )  # fmt: skip
        s = pretrain(
            d.calibrated(STAG_GLOVE), d.recording_id, excl, ckpt, cfg,
            fingerprint=d.fingerprint(), device=device, resume=True, progress=False,
        )  # fmt: skip
        result.update(final_ratio=s["final_ratio"], frames=s["frames"], steps=spec["steps"])
    else:
        r = Recipe(**spec["recipe"])
        td = prepare_data(d, excl)
        targets, dim = _targets(spec.get("targets_from"), td.classes)
        cfg = TrainConfig(
            model=r.model, steps=spec["steps"], batch=r.batch, lr=r.lr, seed=spec["seed"],
            weight_decay=r.weight_decay, half=r.half and spec["fold"] != "all", amp=r.amp,
        )  # fmt: skip
        cfg.warmup = recipe_warmup(cfg.steps)
        cfg.augment = augment_preset(r.augment)
        pre = str(out / f"{spec['pretrained']}.safetensors") if spec["pretrained"] else None
        common = dict(space_dim=dim, pretrained=pre, device=device, resume=True, progress=False)
        if r.teacher:
            from tactus_memory.training.distill import DistillConfig, distill

            teachers = [out / f"{t}.safetensors" for t in spec["teachers"]]
            dcfg = DistillConfig(cosine_weight=r.cosine_weight)
            s = distill(td, targets, cfg, ckpt, teachers, dcfg=dcfg, **common)
        else:
            from tactus_memory.training.train import fit

            s = fit(td, targets, cfg, ckpt, **common)
        held = s.get("heldout") or {}
        result.update(
            recipe=r.name, model=r.model, steps=spec["steps"],
            top1=held.get("top1"), top3=held.get("top3"),
            recording_top1=held.get("recording_top1"), tuples=held.get("tuples"),
            recordings=held.get("recordings"), train_acc=s.get("train_acc_ema"),
        )  # fmt: skip
    result.update(device=device, wall_s=round(time.perf_counter() - t0, 1))
    done.parent.mkdir(parents=True, exist_ok=True)
    done.write_text(json.dumps(result, indent=1) + "\n")
    return result


# -- the runner -------------------------------------------------------------------------------


@dataclass
class RunnerConfig:
    out: Path
    data: list[str]
    jobs: int = 2  # processes at a time
    threads: int = 1  # torch threads per process
    device: str = "auto"
    targets_from: str | None = None
    deadline_s: float = 0.0  # stop starting jobs and end running ones after this (0: none)
    only: list[str] = field(default_factory=list)  # run only these recipes (and their deps)


def is_done(out: Path, key: str) -> bool:
    return (out / f"{key}.result.json").is_file()


def run_plan(plan: Plan, rc: RunnerConfig, scale: dict[str, float] | None = None) -> dict:
    """Run every job not done yet, ``rc.jobs`` processes at a time, in dependency order.
    Returns {"done": [...], "failed": {key: rc}, "unfinished": [...], "wall_s": ...}."""
    jobs = build_jobs(plan, scale)
    if rc.only:
        want = {j.key for j in jobs if j.recipe and j.recipe.name in rc.only}
        grow = True
        while grow:
            deps = {d for j in jobs if j.key in want for d in j.deps}
            grow = not deps <= want
            want |= deps
        jobs = [j for j in jobs if j.key in want]
    rc.out.mkdir(parents=True, exist_ok=True)
    (rc.out / "jobs.json").write_text(json.dumps([asdict(j) for j in jobs], indent=1) + "\n")
    pending = [j for j in jobs if not is_done(rc.out, j.key)]
    running: dict[str, tuple[subprocess.Popen, Any]] = {}
    failed: dict[str, int] = {}
    t0 = time.monotonic()
    env = {**os.environ, "OMP_NUM_THREADS": str(rc.threads), "MKL_NUM_THREADS": str(rc.threads)}
    env.setdefault("OMP_WAIT_POLICY", "PASSIVE")
    while pending or running:
        late = rc.deadline_s and time.monotonic() - t0 > rc.deadline_s
        if late:
            for key, (p, fh) in running.items():
                p.kill()
                p.wait()
                fh.close()
                log.warning("deadline: killed %s (its resume state is kept)", key)
            break
        for key, (p, fh) in list(running.items()):
            if p.poll() is not None:
                fh.close()
                del running[key]
                if p.returncode != 0 or not is_done(rc.out, key):
                    failed[key] = p.returncode
                    log.error("%s failed (exit %s): see %s.log", key, p.returncode, key)
                else:
                    log.info("%s done (%.0f s)", key, time.monotonic() - t0)
        blocked = {j.key for j in pending if any(d in failed for d in j.deps)}
        for j in [j for j in pending if j.key in blocked]:
            failed[j.key] = -1
        pending = [j for j in pending if j.key not in blocked]
        for j in list(pending):
            if len(running) >= rc.jobs:
                break
            if all(is_done(rc.out, d) for d in j.deps):
                spec = rc.out / f"{j.key}.spec.json"
                spec.parent.mkdir(parents=True, exist_ok=True)
                spec.write_text(json.dumps(j.spec(rc.out, rc.data, rc.targets_from, rc.device)))
                fh = open(rc.out / f"{j.key}.log", "w")  # noqa: SIM115 - closed when it ends
                cmd = [
                    sys.executable,
                    "-m",
                    MODULE,
                    "job",
                    str(spec),
                    "--threads",
                    str(rc.threads),
                ]
                running[j.key] = (
                    subprocess.Popen(cmd, stdout=fh, stderr=subprocess.STDOUT, env=env),
                    fh,
                )
                pending.remove(j)
                log.info("started %s", j.key)
        time.sleep(0.5)
    return {
        "done": [j.key for j in jobs if is_done(rc.out, j.key)],
        "failed": failed,
        "unfinished": [j.key for j in jobs if not is_done(rc.out, j.key) and j.key not in failed],
        "wall_s": round(time.monotonic() - t0, 1),
    }


def run_command(
    plan: Plan,
    rc: RunnerConfig,
    *,
    probe: bool = True,
) -> dict[str, Any]:
    """Budget (GPU plans), run, report: what ``tactus eval-recipe run`` and the GPU script do."""
    from tactus_memory.training.train import _resolve_device

    rc.out.mkdir(parents=True, exist_ok=True)
    budget: dict[str, Any] = {"budget_s": plan.budget_s, "scaled": plan.scaled}
    scale: dict[str, float] | None = {}
    device = _resolve_device(rc.device)
    if plan.budget_s and plan.scaled and probe and device.startswith("cuda"):
        model = plan.recipe(plan.scaled[0]).model
        step_s = probe_step_s(model, device)
        scale = budget_scale(plan, step_s)
        budget.update(probe_model=model, step_s=step_s, scale=scale)
        if scale is None:
            budget["dropped"] = sorted(
                {*plan.scaled, *(r.name for r in plan.recipes if r.teacher in plan.scaled)}
            )
            plan, scale = without(plan, plan.scaled), {}
    (rc.out / "budget.json").write_text(json.dumps(budget, indent=1) + "\n")
    log.info("budget: %s", budget)
    status = run_plan(plan, rc, scale)
    status["budget"] = budget
    (rc.out / "status.json").write_text(json.dumps(status, indent=1) + "\n")
    rep = write_report(rc.out, plan.baseline)
    return {"status": status, "report": {k: v for k, v in rep.items() if k != "runs"}}


def _parser() -> Any:
    import argparse

    ap = argparse.ArgumentParser(prog="python -m tactus_memory.training.protocol_run")
    sub = ap.add_subparsers(dest="cmd", required=True)
    j = sub.add_parser("job", help="one job from its spec (the runner's subprocess)")
    j.add_argument("spec")
    j.add_argument("--threads", type=int, default=1)
    r = sub.add_parser("run", help="run a plan's jobs not done yet, then write the report")
    r.add_argument("--plan", required=True, help="plan JSON, or a name in plans/ (cpu, gpu)")
    r.add_argument("--out", required=True, type=Path)
    r.add_argument("--data", action="append", required=True, help="STAG file or folder")
    r.add_argument("--jobs", type=int, default=2, help="processes at a time")
    r.add_argument("--threads", type=int, default=1, help="torch threads per process")
    r.add_argument("--device", default="auto")
    r.add_argument("--targets-from", default=None, help="checkpoint whose class targets to use")
    r.add_argument("--deadline-s", type=float, default=0.0)
    r.add_argument("--only", action="append", default=[], help="only this recipe (+ its deps)")
    r.add_argument("--max-steps", type=int, default=0, help="smoke test: cap every step count")
    r.add_argument("--seeds", default=None, help="smoke test: comma-separated seeds")
    r.add_argument("--swap-model", action="append", default=[], help="smoke test: FROM=TO")
    r.add_argument("--folds", default=None, help="smoke test: comma-separated folds (A,B)")
    rep = sub.add_parser("report", help="report.json/.md from the finished runs")
    rep.add_argument("--out", required=True, type=Path)
    rep.add_argument("--baseline", default="shipped")
    st = sub.add_parser("stream", help="stream metrics (real memory, MiniLM) of finished runs")
    st.add_argument("--out", required=True, type=Path)
    st.add_argument("--data", action="append", required=True)
    st.add_argument("--recipe", action="append", default=[])
    return ap


def _main(argv: list[str]) -> int:
    args = _parser().parse_args(argv)
    logging.basicConfig(
        level=logging.INFO, format="%(asctime)s %(levelname)s %(name)s: %(message)s"
    )
    if args.cmd == "job":
        import torch

        torch.set_num_threads(max(1, args.threads))
        print(json.dumps(run_job(json.loads(Path(args.spec).read_text()))))
        return 0
    if args.cmd == "run":
        plan = Plan.load(args.plan)
        if args.max_steps or args.seeds or args.swap_model or args.folds:
            seeds = [int(x) for x in args.seeds.split(",")] if args.seeds else None
            swap = dict(s.split("=", 1) for s in args.swap_model)
            folds = args.folds.split(",") if args.folds else None
            plan = shrink(plan, args.max_steps, seeds, swap, folds)
        rc = RunnerConfig(
            out=args.out, data=args.data, jobs=args.jobs, threads=args.threads,
            device=args.device, targets_from=args.targets_from, deadline_s=args.deadline_s,
            only=args.only,
        )  # fmt: skip
        res = run_command(plan, rc)
        print(report_markdown(res["report"]))
        print(json.dumps(res["status"], indent=1))
        return 0 if not res["status"]["failed"] else 1
    if args.cmd == "report":
        print(report_markdown(write_report(args.out, args.baseline)))
        return 0
    if args.cmd == "stream":
        n = add_stream_metrics(args.out, args.data, args.recipe)
        print(f"stream metrics written for {n} runs")
        return 0
    return 2


if __name__ == "__main__":
    sys.exit(_main(sys.argv[1:]))
