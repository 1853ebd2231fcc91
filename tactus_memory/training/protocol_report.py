"""The protocol's report: per recipe the mean and 95 % interval of each metric over its fold
runs, and the paired difference against the baseline over the (fold, seed) pairs both have;
the stream metrics (grasp-grouped, real memory and MiniLM) of finished fold runs."""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from tactus_memory.training.protocol import FOLDS

#: the metrics a run reports (tuple and recording top-1 from fit's held-out evaluation; the
#: stream ones from ``stream`` on the run's checkpoint, grasp-grouped, served mode)
METRICS = ("top1", "top3", "recording_top1", "stream_r1", "stream_r5", "other_pass")
CONFIDENCE = 0.95

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
    from tactus_memory.training.stream_eval import build_stream, evaluate_stream, load_queries
    from tactus_memory.training.train import holdout_recordings

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
    from tactus_memory.training.train import load_data

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


def write_report(out: Path, baseline: str) -> dict[str, Any]:
    """report.json and report.md from every finished run under ``out``."""
    rows = load_results(out)
    rep = report(rows, baseline)
    rep["runs"] = rows
    (out / "report.json").write_text(json.dumps(rep, indent=1) + "\n")
    (out / "report.md").write_text(report_markdown(rep))
    return rep
