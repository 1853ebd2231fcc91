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
(``--jobs``; :mod:`tactus_memory.training.protocol_run`), and
:mod:`tactus_memory.training.protocol_report` writes the report.

``budget_s`` in a plan (GPU plans): the steps of the recipes listed in ``scaled`` are scaled
down so their estimated GPU time fits, from a measured training step of the largest model
(:func:`probe_step_s`); the steps each run really used are in its result.
"""

from __future__ import annotations

import json
import os
import time
from collections.abc import Iterable, Sequence
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

FOLDS: dict[str, str] = {
    "A": "one-per-object@blindfolded",
    "B": "last-per-object@blindfolded",
    "all": "none",
}
PLANS_DIR = Path(__file__).parent / "plans"
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

    def mae_job(self, fold: str) -> str | None:
        """The key of the MAE job this recipe's runs of ``fold`` start from (None: no MAE);
        recipes that pretrain alike share it."""
        if not self.mae_steps:
            return None
        return f"mae/mae-{self.model}-{self.mae_steps}x{self.mae_batch}-{fold}"


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
            mae = r.mae_job(fold)
            if mae is not None and mae not in jobs:
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
    for j in jobs:
        if j.kind == "mae" and any(j.key == r.mae_job(j.fold) for r in scaled.values()):
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
    from tactus_memory.training.precision import autocast

    net = create_model(model, out_dim=384).to(device)
    opt = torch.optim.AdamW(net.parameters(), lr=1e-4)
    x = torch.rand(batch, net.cfg.frames, 32, 32, device=device)
    times = []
    for i in range(steps):
        t0 = time.perf_counter()
        with autocast(device):
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
