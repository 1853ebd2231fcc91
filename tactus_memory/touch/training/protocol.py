"""The validation protocol: recipes compared on 2-fold cross-validation with paired seeds.

Why (checkpoints README, "Protocol"): a single split that leaves each object one training
recording of the held-out condition has a seed spread (0.06 tuple top-1) larger than the
effects it is asked to decide. The protocol instead trains in the shipped model's own data
regime and pairs every comparison:

* **folds** over the blindfolded recordings: fold ``A`` holds out the lower-id recording of each
  object (``one-per-object@blindfolded``), fold ``B`` the other (``last-per-object@blindfolded``);
  ``weights_lite`` is always in training, and MAE pretraining excludes the fold's held-out
  recordings too. ``all`` trains on every recording (what ships).
* **seeds**: every recipe runs the same seeds on the same folds, so the difference between two
  recipes is taken per (fold, seed) pair; decisions go by the 95 % interval of those paired
  differences (t distribution), not by two means side by side.
* **runs are files**: a run is done when its ``<run>.result.json`` exists; a killed plan resumes
  where it stopped (finished runs are skipped, a running one resumes from its resume state).

A **plan** (JSON, ``plans/*.json``) names the recipes, the baseline, folds, seeds and which
recipes are also trained on all data. A recipe may distil (``teacher``: the recipe whose runs of
the same fold teach it). The runner builds the jobs (MAE trunks shared by recipes that pretrain
alike, supervised runs, distillation after its teachers) and runs them as parallel processes
(``--jobs``), each ``python -m tactus_memory.touch.training.protocol job SPEC``.

``budget_s`` in a plan (GPU plans): the steps of the recipes listed in ``scaled`` are scaled
down so their estimated GPU time fits, from a measured training step of the largest model
(:func:`probe_step_s`); the steps each run really used are in its result.
"""

from __future__ import annotations

import json
import logging
import math
import os
import subprocess
import sys
import time
from collections.abc import Iterable, Sequence
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

log = logging.getLogger("tactus_memory.touch.training.protocol")

#: fold name -> holdout spec (train.holdout_recordings grammar)
FOLDS: dict[str, str] = {
    "A": "one-per-object@blindfolded",
    "B": "last-per-object@blindfolded",
    "all": "none",
}
PLANS_DIR = Path(__file__).parent / "plans"
#: the metrics a run reports (tuple and recording top-1 from fit's held-out evaluation; the
#: stream ones from ``stream`` on the run's checkpoint, grasp-grouped, served mode)
METRICS = ("top1", "top3", "recording_top1", "stream_r1", "stream_r5", "other_pass")
CONFIDENCE = 0.95
MODULE = "tactus_memory.touch.training.protocol"  # each job runs as `python -m MODULE job SPEC`
STEP_ROUND = 250  # scaled step counts are rounded down to a multiple of this


@dataclass(frozen=True)
class Recipe:
    """One way to train the encoder (the options of ``tactus pretrain`` + ``train``/``distill``)."""

    name: str
    model: str = "tactus-lite"
    mae_steps: int = 0  # MAE pretraining steps (0: no MAE, random trunk init)
    mae_batch: int = 128  # frames per MAE step
    steps: int = 600  # supervised (or distillation) optimizer steps
    batch: int = 64
    lr: float = 1e-3
    weight_decay: float = 0.05
    augment: str = "default"  # augment.AUGMENT_PRESETS name
    amp: bool = True  # bf16 autocast on CUDA (no effect on CPU)
    teacher: str | None = None  # recipe whose runs of the same fold teach this one
    teachers: int = 3  # how many of the teacher recipe's seeds teach (its first seeds)
    cosine_weight: float = 1.0  # distillation: weight of mean(1 - cos(student, teachers))
    half: bool = False  # float16 weights for fold runs (small files to carry back from a GPU)
    seeds: list[int] | None = None  # fold-run seeds of this recipe (default: the plan's)

    def mae_key(self) -> str | None:
        return f"mae-{self.model}-{self.mae_steps}x{self.mae_batch}" if self.mae_steps else None


@dataclass
class Plan:
    recipes: list[Recipe]
    baseline: str  # the recipe every other is paired against (the shipped one)
    folds: list[str] = field(default_factory=lambda: ["A", "B"])
    seeds: list[int] = field(default_factory=lambda: [0, 1, 2])
    final: dict[str, list[int]] = field(default_factory=dict)  # recipe -> seeds on all data
    budget_s: float = 0.0  # GPU plans: estimated GPU seconds the scaled recipes may take
    scaled: list[str] = field(default_factory=list)  # recipes whose steps the budget scales
    min_scale: float = 0.375  # never scale steps below this share of the recipe's

    @classmethod
    def load(cls, path: str | os.PathLike[str]) -> Plan:
        p = Path(path)
        if not p.is_file() and (PLANS_DIR / f"{path}.json").is_file():
            p = PLANS_DIR / f"{path}.json"
        raw = json.loads(p.read_text())
        raw.pop("_comment", None)
        recipes = [
            Recipe(**{k: v for k, v in r.items() if k != "_comment"}) for r in raw.pop("recipes")
        ]
        plan = cls(recipes=recipes, **raw)
        plan.check()
        return plan

    def recipe(self, name: str) -> Recipe:
        for r in self.recipes:
            if r.name == name:
                return r
        raise KeyError(f"plan has no recipe {name!r}; recipes: {[r.name for r in self.recipes]}")

    def check(self) -> None:
        names = [r.name for r in self.recipes]
        if len(set(names)) != len(names):
            raise ValueError(f"recipe names repeat: {names}")
        self.recipe(self.baseline)
        for f in self.folds:
            if f not in FOLDS or f == "all":
                raise ValueError(f"fold {f!r}: folds are {[k for k in FOLDS if k != 'all']}")
        for r in self.recipes:
            if r.teacher:
                t = self.recipe(r.teacher)
                if t.teacher:
                    raise ValueError(f"{r.name}: teacher {t.name} is itself a student")
                if r.teachers > len(t.seeds or self.seeds):
                    raise ValueError(
                        f"{r.name}: {r.teachers} teachers but {t.name} has fewer seeds"
                    )
                if r.name in self.final and len(self.final.get(t.name, [])) < r.teachers:
                    raise ValueError(
                        f"{r.name} is trained on all data: plan.final must give {t.name} "
                        f"at least {r.teachers} seeds"
                    )
        for name in [*self.final, *self.scaled]:
            self.recipe(name)


@dataclass
class Job:
    key: str  # path of the run under the output folder, without suffix
    kind: str  # "mae" | "train"
    fold: str
    seed: int
    recipe: Recipe | None = None  # train jobs
    model: str = ""  # mae jobs
    steps: int = 0
    batch: int = 0
    pretrained: str | None = None  # key of the MAE job
    teachers: list[str] = field(default_factory=list)  # keys of teacher runs
    deps: list[str] = field(default_factory=list)

    def spec(self, out: Path, data: Sequence[str], targets_from: str | None, device: str) -> dict:
        d = asdict(self)
        d.update(
            out=str(out), data=[str(p) for p in data], targets_from=targets_from, device=device
        )
        return d


def run_key(recipe: str, fold: str, seed: int) -> str:
    return f"{recipe}/{fold}-s{seed}"


def build_jobs(plan: Plan, scale: dict[str, float] | None = None) -> list[Job]:
    """Every job of the plan in dependency order (MAE before train, teachers before students).
    ``scale``: recipe name -> factor on its steps (budgeted GPU plans)."""
    scale = scale or {}
    jobs: dict[str, Job] = {}

    def steps_of(r: Recipe) -> int:
        f = scale.get(r.name, 1.0)
        return r.steps if f >= 1.0 else max(STEP_ROUND, int(r.steps * f) // STEP_ROUND * STEP_ROUND)

    # plan order is priority order (the runner starts ready jobs in this order); within a
    # recipe the runs on all data (what ships) come first
    for r in plan.recipes:
        folds = [("all", s) for s in plan.final.get(r.name, [])]
        folds += [(f, s) for f in plan.folds for s in (r.seeds or plan.seeds)]
        for fold, seed in folds:
            mae = None
            if r.mae_key():
                mae = f"mae/{r.mae_key()}-{fold}"
                if mae not in jobs:
                    jobs[mae] = Job(
                        key=mae, kind="mae", fold=fold, seed=0, model=r.model,
                        steps=r.mae_steps, batch=r.mae_batch,
                    )  # fmt: skip
            teachers = []
            if r.teacher:
                t = plan.recipe(r.teacher)
                tseeds = plan.final[r.teacher] if fold == "all" else (t.seeds or plan.seeds)
                teachers = [run_key(r.teacher, fold, s) for s in tseeds[: r.teachers]]
            key = run_key(r.name, fold, seed)
            rr = replace(r, steps=steps_of(r))
            jobs[key] = Job(
                key=key, kind="train", fold=fold, seed=seed, recipe=rr, steps=rr.steps,
                batch=r.batch, pretrained=mae, teachers=teachers,
                deps=[d for d in [mae, *teachers] if d],
            )  # fmt: skip
    return list(jobs.values())


def gpu_cost(plan: Plan, jobs: Iterable[Job]) -> tuple[float, float]:
    """(fixed, scalable) estimated GPU cost of the jobs that involve the scaled recipes, in
    units of one training step of the scaled model at batch 64: an MAE step of B frames costs
    B / 512 of it (a window is 8 frames), a training step 1 (x batch / 64), a student's step
    the forwards of its teachers (a third of a step each). Students of scaled teachers are
    the fixed part (their own steps are not scaled); the scaled recipes' runs the scalable."""
    fixed = scalable = 0.0
    scaled = {r.name: r for r in plan.recipes if r.name in plan.scaled}
    mae_keys = {r.mae_key() for r in scaled.values() if r.mae_key()}
    for j in jobs:
        if j.kind == "mae" and any(j.key == f"mae/{k}-{j.fold}" for k in mae_keys):
            fixed += j.steps * j.batch / 512
        elif j.kind == "train" and j.recipe is not None:
            if j.recipe.name in scaled:
                scalable += j.steps * j.batch / 64
            elif j.recipe.teacher in scaled:
                fixed += j.steps * len(j.teachers) / 3 * j.batch / 64
    return fixed, scalable


def budget_scale(plan: Plan, step_s: float) -> dict[str, float] | None:
    """recipe -> step factor so the estimated GPU time of the scaled recipes fits
    ``plan.budget_s`` given ``step_s`` (:func:`probe_step_s`); None when even
    ``plan.min_scale`` would not fit (the caller drops those recipes and their students)."""
    if not plan.budget_s or not plan.scaled:
        return {}
    fixed, scalable = gpu_cost(plan, build_jobs(plan))
    room = plan.budget_s / step_s - fixed
    f = min(1.0, room / max(scalable, 1e-9))
    if f < plan.min_scale:
        return None
    return {name: f for name in plan.scaled}


def without(plan: Plan, names: Iterable[str]) -> Plan:
    """The plan minus the named recipes and every student they teach."""
    drop = set(names)
    drop |= {r.name for r in plan.recipes if r.teacher in drop}
    keep = [r for r in plan.recipes if r.name not in drop]
    if plan.baseline in drop:
        raise ValueError(f"cannot drop the baseline {plan.baseline}")
    final = {k: v for k, v in plan.final.items() if k not in drop}
    return replace(plan, recipes=keep, final=final, scaled=[], budget_s=0.0)


def probe_step_s(model: str, device: str, batch: int = 64, steps: int = 12) -> float:
    """Seconds of one bf16 training step of ``model`` at ``batch`` on ``device`` (random
    windows, no data loading: the GPU side of a step)."""
    import torch

    from tactus_memory.touch.model import create_model

    net = create_model(model, out_dim=384).to(device)
    opt = torch.optim.AdamW(net.parameters(), lr=1e-4)
    x = torch.rand(batch, net.cfg.frames, 32, 32, device=device)
    amp = torch.autocast("cuda", dtype=torch.bfloat16) if device.startswith("cuda") else None
    times = []
    for i in range(steps):
        t0 = time.perf_counter()
        if amp is not None:
            with amp:
                z = net(x)
        else:
            z = net(x)
        loss = z.float().pow(2).sum()
        opt.zero_grad()
        loss.backward()
        opt.step()
        if device.startswith("cuda"):
            torch.cuda.synchronize()
        if i >= 2:
            times.append(time.perf_counter() - t0)
    return float(np.median(times))


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
    from tactus_memory.touch.training.augment import augment_preset
    from tactus_memory.touch.training.pretrain import PretrainConfig, pretrain, recipe_warmup
    from tactus_memory.touch.training.train import (
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
            from tactus_memory.touch.training.distill import DistillConfig, distill

            teachers = [out / f"{t}.safetensors" for t in spec["teachers"]]
            dcfg = DistillConfig(cosine_weight=r.cosine_weight)
            s = distill(td, targets, cfg, ckpt, teachers, dcfg=dcfg, **common)
        else:
            from tactus_memory.touch.training.train import fit

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


# -- the report -------------------------------------------------------------------------------


def interval(x: Sequence[float], confidence: float = CONFIDENCE) -> dict[str, Any]:
    """Mean and t-interval of ``x`` (n, mean, sd, lo, hi; no interval for n < 2)."""
    from scipy import stats

    a = np.asarray([v for v in x if v is not None and not math.isnan(v)], dtype=np.float64)
    n = len(a)
    if n == 0:
        return {"n": 0}
    m = float(a.mean())
    if n < 2:
        return {"n": 1, "mean": m}
    sd = float(a.std(ddof=1))
    h = float(stats.t.ppf(0.5 + confidence / 2, n - 1) * sd / math.sqrt(n))
    return {"n": n, "mean": m, "sd": sd, "lo": m - h, "hi": m + h}


def load_results(out: Path) -> list[dict[str, Any]]:
    """Every train run's result, with its stream metrics merged in where measured."""
    rows = []
    for p in sorted(out.rglob("*.result.json")):
        r = json.loads(p.read_text())
        if r.get("kind") != "train":
            continue
        sp = p.with_name(p.name.replace(".result.json", ".stream.json"))
        if sp.is_file():
            r.update(json.loads(sp.read_text()))
        rows.append(r)
    return rows


def report(rows: list[dict[str, Any]], baseline: str) -> dict[str, Any]:
    """Per recipe: mean and 95 % interval of each metric over its fold runs; the paired
    difference against ``baseline`` over the (fold, seed) pairs both have."""
    cv = [r for r in rows if r["fold"] != "all"]
    by: dict[str, dict[tuple[str, int], dict]] = {}
    for r in cv:
        by.setdefault(r["recipe"], {})[(r["fold"], r["seed"])] = r
    base = by.get(baseline, {})
    out: dict[str, Any] = {"baseline": baseline, "confidence": CONFIDENCE, "recipes": {}}
    for name, runs in sorted(by.items()):
        entry: dict[str, Any] = {
            "runs": len(runs),
            "steps": sorted({r["steps"] for r in runs.values()}),
            "device": sorted({r.get("device", "?") for r in runs.values()}),
        }
        for m in METRICS:
            vals = [r.get(m) for r in runs.values()]
            if any(v is not None for v in vals):
                entry[m] = interval(vals)
            if name != baseline:
                pairs = [
                    runs[k][m] - base[k][m]
                    for k in runs
                    if k in base and runs[k].get(m) is not None and base[k].get(m) is not None
                ]
                if pairs:
                    entry[f"{m}_paired_diff"] = interval(pairs)
        out["recipes"][name] = entry
    return out


def report_markdown(rep: dict[str, Any]) -> str:
    def f(iv: dict[str, Any] | None, signed: bool = False) -> str:
        if not iv or not iv.get("n"):
            return "-"
        fmt = "{:+.3f}" if signed else "{:.3f}"
        s = fmt.format(iv["mean"])
        if "lo" in iv:
            s += f" [{fmt.format(iv['lo'])}, {fmt.format(iv['hi'])}]"
        return s

    lines = [
        f"| recipe | runs | steps | tuple top-1 | recording top-1 | stream R@1 | stream R@5 | "
        f"paired diff vs {rep['baseline']}: tuple top-1 | recording top-1 | R@1 | R@5 |",
        "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    for name, e in rep["recipes"].items():
        lines.append(
            f"| {name} | {e['runs']} | {','.join(map(str, e['steps']))} | {f(e.get('top1'))} | "
            f"{f(e.get('recording_top1'))} | {f(e.get('stream_r1'))} | {f(e.get('stream_r5'))} | "
            f"{f(e.get('top1_paired_diff'), True)} | "
            f"{f(e.get('recording_top1_paired_diff'), True)} | "
            f"{f(e.get('stream_r1_paired_diff'), True)} | "
            f"{f(e.get('stream_r5_paired_diff'), True)} |"
        )
    return "\n".join(lines) + "\n"


# -- stream metrics of finished runs (CPU; real memory, real MiniLM) ---------------------------


def stream_metrics(ckpt: Path, data: Any, fold: str) -> dict[str, Any]:
    """Grasp-grouped stream R@1 / R@5 and the other-object pass rate of one fold run."""
    from tactus_memory.touch.training.stream_eval import build_stream, evaluate_stream, load_queries
    from tactus_memory.touch.training.train import holdout_recordings

    recs = holdout_recordings(data, FOLDS[fold])
    res = evaluate_stream(
        ckpt, build_stream(data, recs), load_queries(), modes=("served",), groups=("grasp",),
        data_fingerprint=data.fingerprint(),
    )  # fmt: skip
    g = res["served_grasp"]
    return {
        "stream_r1": g["r@1"],
        "stream_r5": g["r@5"],
        "other_pass": g.get("match_other_object_rate"),
    }


def add_stream_metrics(out: Path, data_paths: Sequence[str], recipes: Sequence[str] = ()) -> int:
    """Write ``<run>.stream.json`` for every finished fold run that has none yet."""
    from tactus_memory.touch.training.train import load_data

    data = load_data(data_paths)
    n = 0
    for p in sorted(out.rglob("*.result.json")):
        r = json.loads(p.read_text())
        if (
            r.get("kind") != "train"
            or r["fold"] == "all"
            or (recipes and r["recipe"] not in recipes)
        ):
            continue
        sp = p.with_name(p.name.replace(".result.json", ".stream.json"))
        ck = p.with_name(p.name.replace(".result.json", ".safetensors"))
        if sp.is_file() or not ck.is_file():
            continue
        sp.write_text(json.dumps(stream_metrics(ck, data, r["fold"]), indent=1) + "\n")
        n += 1
    return n


def shrink(
    plan: Plan,
    max_steps: int,
    seeds: list[int] | None,
    swap: dict[str, str],
    folds: list[str] | None = None,
) -> Plan:
    """A smoke-test copy of a plan: steps capped, other seeds, models swapped (e.g. the r18
    teacher for tactus-tiny, so a GPU plan runs on CPU in seconds)."""
    recipes = []
    for r in plan.recipes:
        kw: dict[str, Any] = {"model": swap.get(r.model, r.model)}
        if seeds is not None and r.seeds:
            kw["seeds"] = [x for x in r.seeds if x in seeds] or list(seeds[:1])
        if max_steps:
            kw["steps"] = min(r.steps, max_steps)
            kw["mae_steps"] = min(r.mae_steps, max_steps)
        recipes.append(replace(r, **kw))
    out = replace(plan, recipes=recipes, folds=list(folds or plan.folds))
    if seeds is not None:
        out.seeds = list(seeds)
        out.final = {
            k: list(seeds[: max(1, min(len(v), len(seeds)))]) for k, v in plan.final.items()
        }
        for r in out.recipes:
            if r.teacher and r.teachers > len(seeds):
                out.recipes[out.recipes.index(r)] = replace(r, teachers=len(seeds))
    out.check()
    return out


def write_report(out: Path, baseline: str) -> dict[str, Any]:
    """report.json and report.md from every finished run under ``out``."""
    rows = load_results(out)
    rep = report(rows, baseline)
    rep["runs"] = rows
    (out / "report.json").write_text(json.dumps(rep, indent=1) + "\n")
    (out / "report.md").write_text(report_markdown(rep))
    return rep


def run_command(
    plan: Plan,
    rc: RunnerConfig,
    *,
    probe: bool = True,
) -> dict[str, Any]:
    """Budget (GPU plans), run, report: what ``tactus eval-recipe run`` and the GPU script do."""
    from tactus_memory.touch.training.train import _resolve_device

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

    ap = argparse.ArgumentParser(prog="python -m tactus_memory.touch.training.protocol")
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
