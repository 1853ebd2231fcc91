"""``tactus eval``, ``tactus baseline train|eval`` and ``tactus ablate``: the paper's numbers."""

from __future__ import annotations

import json
import logging
from pathlib import Path
from typing import Any

import typer

from tactus_memory.cli.app import app

HOLDOUT_HELP = (
    "score exactly the recordings a `tactus train --holdout SPEC` run held out (same grammar: "
    "none | one-per-object@SUBSTR | recordings@NAME,NAME); replaces --split. Pass the same "
    "--data files in the same order as the training run"
)
SPLIT_HELP = (
    "test: each file's 'test' frames (a file without splits, e.g. weights, is scored whole); "
    "all: every valid frame"
)

baseline_app = typer.Typer(
    help="The supervised STAG CNN (closed-set reference), trained and scored like Tactus.",
    no_args_is_help=True,
)
app.add_typer(baseline_app, name="baseline")


def _threads(n: int) -> None:
    import torch

    if n > 0:
        torch.set_num_threads(n)


def load_eval_data(paths: list[Path]) -> tuple[Any, list[dict[str, Any]]]:
    """Load each file (fingerprinted), combine, run the dynamic-range gate per subset."""
    from tactus_memory.touch.data import combine, load_stag
    from tactus_memory.touch.evaluate import file_fingerprint

    parts = [load_stag(p) for p in paths]
    fps = [file_fingerprint(d, p) for d, p in zip(parts, paths, strict=True)]
    data = parts[0] if len(parts) == 1 else combine(parts)
    data.check_dynamic_range()
    return data, fps


def run_eval(
    checkpoints: list[str],
    data_paths: list[Path],
    *,
    split: str = "test",
    holdout: str | None = None,
    votes: int = 4,
    seed: int | None = None,
    analysis: bool = True,
    progress: bool = True,
) -> tuple[dict[str, Any], Any, Any]:
    """Evaluate one or more checkpoints on one scope. Returns (payload, first result, scope).

    One checkpoint: the payload is that run's metrics. Several: ``runs`` (each run's metrics),
    ``aggregate`` (mean, sample std per metric), and the top-level metric keys hold the means.
    """
    from tactus_memory.touch.evaluate import (
        EVAL_SEED,
        SCALAR_METRICS,
        aggregate_runs,
        evaluate_checkpoint,
        resolve_checkpoint,
        select_eval_frames,
    )

    data, fps = load_eval_data(data_paths)
    es = select_eval_frames(data, split, holdout, fingerprints=fps)
    runs, first = [], None
    for spec in checkpoints:
        path = resolve_checkpoint(spec)
        m, res, _ = evaluate_checkpoint(
            path,
            es,
            votes=votes,
            seed=EVAL_SEED if seed is None else seed,
            analysis=analysis,
            progress=progress,
        )
        runs.append(m)
        first = first or res
        if m["leakage"]["status"] == "overlap":
            typer.echo(
                f"WARNING: {path}: {m['leakage']['trained_on']} of the "
                f"{m['leakage']['scored_recordings']} scored recordings were in its training "
                f"data (e.g. {m['leakage']['examples']}); these scores are not held-out",
                err=True,
            )
    if len(runs) == 1:
        return runs[0], first, es
    agg = aggregate_runs(runs)
    shared = (
        "split",
        "k",
        "seed",
        "votes",
        "n_tuples",
        "n_recordings",
        "n_frames",
        "chance",
        "chance_top3",
        "classes",
        "data",
        "model_kind",
    )
    payload: dict[str, Any] = {k: runs[0][k] for k in shared}
    payload.update({k: agg[k]["mean"] for k in SCALAR_METRICS})
    payload.update({f"{k}_std": agg[k]["std"] for k in SCALAR_METRICS})
    payload["n_runs"] = len(runs)
    payload["checkpoint"] = [r["checkpoint"] for r in runs]
    payload["aggregate"] = agg
    payload["runs"] = runs
    return payload, first, es


def _write_outputs(
    payload: dict[str, Any],
    first: Any,
    es: Any,
    json_out: Path | None,
    report: Path | None,
    compare: list[Path],
) -> None:
    if json_out is not None:
        json_out.parent.mkdir(parents=True, exist_ok=True)
        json_out.write_text(json.dumps(payload, indent=1) + "\n")
    if report is not None:
        from tactus_memory.touch.report import write_report

        others = [json.loads(Path(p).read_text()) for p in compare]
        files = write_report(report, payload, first, es.calibrated, others)
        typer.echo(
            f"report: {', '.join(str(f) for f in files[:4])}" + (" …" if len(files) > 4 else "")
        )
    from tactus_memory.touch.evaluate import SCALAR_METRICS

    summary = {k: payload.get(k) for k in ("split", "n_tuples", "n_recordings", *SCALAR_METRICS)}
    if "aggregate" in payload:
        summary.update({f"{k}_std": payload.get(f"{k}_std") for k in SCALAR_METRICS})
    typer.echo(json.dumps(summary, indent=2))


@app.command("eval")
def eval_cmd(
    checkpoint: list[str] = typer.Option(
        ..., "--checkpoint", help="Tactus or baseline .safetensors, or 'default'; repeat for runs"
    ),
    data: list[Path] = typer.Option(..., "--data", help="STAG metadata.mat or folder; repeat"),
    split: str = typer.Option("test", "--split", help=SPLIT_HELP),
    holdout: str | None = typer.Option(None, "--holdout", help=HOLDOUT_HELP),
    votes: int = typer.Option(4, "--votes", help="independent tuple draws pooled for *_vote"),
    seed: int | None = typer.Option(None, "--seed", help="tiling seed (default 1234, as train)"),
    json_out: Path = typer.Option(..., "--json", help="write the metrics JSON here"),
    report: Path | None = typer.Option(None, "--report", help="write report.md + PNGs here"),
    compare: list[Path] = typer.Option(
        [], "--compare", help="other eval JSONs (e.g. the baseline's) as rows of the table"
    ),
    analysis: bool = typer.Option(True, "--analysis/--no-analysis", help="confusion analyses"),
    threads: int = typer.Option(1, "--threads", help="torch CPU threads (0: torch default)"),
    stream: bool = typer.Option(
        False,
        "--stream",
        help="also score the memory as used: whole --holdout recordings as one session of "
        "consecutive windows, natural queries, match bar, last/count (touch/stream_eval.py)",
    ),
    stream_limit: int = typer.Option(0, "--stream-limit", help="stream only the first N (0: all)"),
) -> None:
    """Score checkpoints on STAG: top-1/3, voting, recording level, per class, confusion."""
    logging.basicConfig(level=logging.WARNING)
    if split not in ("test", "all"):
        raise typer.BadParameter("--split must be 'test' or 'all'")
    if stream and not holdout:
        raise typer.BadParameter("--stream needs --holdout (the recordings to stream)")
    _threads(threads)
    payload, first, es = run_eval(
        checkpoint, data, split=split, holdout=holdout, votes=votes, seed=seed, analysis=analysis
    )
    if stream:
        from tactus_memory.touch.stream_eval import run_stream_eval, stream_markdown

        sdata, _ = load_eval_data(data)
        runs = [
            run_stream_eval(None if c == "default" else c, sdata, holdout or "", limit=stream_limit)
            for c in checkpoint
        ]
        payload["stream"] = runs[0] if len(runs) == 1 else runs
        if report is not None:
            report.mkdir(parents=True, exist_ok=True)
            (report / "stream.md").write_text("\n".join(stream_markdown(r) for r in runs))
        for r in runs:
            s, a = r.get("served", {}), r.get("all_windows", {})
            typer.echo(
                f"stream {r['checkpoint']}: R@1 {s.get('r@1')} R@5 {s.get('r@5')} "
                f"MRR {s.get('mrr')} idle-pass(all windows) {a.get('match_idle_rate')} "
                f"leakage {r['leakage']['status']}"
            )
    _write_outputs(payload, first, es, json_out, report, compare)


@baseline_app.command("train")
def baseline_train_cmd(
    data: list[Path] = typer.Option(..., "--data", help="STAG metadata.mat or folder; repeat"),
    out: Path = typer.Option(..., "--out", help="checkpoint to write (.safetensors)"),
    holdout: str = typer.Option("none", "--holdout", help="recordings kept out (train's grammar)"),
    epochs: int = typer.Option(30, "--epochs", help="passes over the training tuples"),
    max_steps: int | None = typer.Option(None, "--max-steps", help="cap on optimizer steps"),
    batch: int = typer.Option(32, "--batch"),
    lr: float = typer.Option(1e-3, "--lr"),
    seed: int = typer.Option(0, "--seed"),
    sampling: str = typer.Option("cluster", "--sampling", help="cluster | random"),
    k: int = typer.Option(8, "--k", help="frames per tuple (reference: 8)"),
    threads: int = typer.Option(1, "--threads", help="torch CPU threads (0: torch default)"),
) -> None:
    """Train the STAG reference CNN on the non-held-out frames; the last epoch is saved (no
    model selection). With --holdout, the held-out recordings are scored afterwards."""
    logging.basicConfig(level=logging.WARNING)
    _threads(threads)
    from tactus_memory.touch.baseline import (
        BaselineConfig,
        BaselineScorer,
        baseline_meta,
        save_baseline,
        train_baseline,
    )
    from tactus_memory.touch.evaluate import evaluate_scorer, select_eval_frames
    from tactus_memory.touch.train import holdout_recordings, prepare_data

    d, fps = load_eval_data(data)
    td = prepare_data(d, holdout_recordings(d, holdout))
    cfg = BaselineConfig(
        epochs=epochs,
        batch=batch,
        lr=lr,
        seed=seed,
        sampling=sampling,
        max_steps=max_steps,
        k=k,
    )

    def snapshot(net: Any, summary: dict[str, Any]) -> None:  # latest epoch, never selected
        meta = baseline_meta(td, cfg, summary, holdout)
        save_baseline(out, net, dict(meta, data=fps, complete=False))

    net, summary = train_baseline(td, cfg, on_epoch=snapshot)
    meta = baseline_meta(td, cfg, summary, holdout)
    meta["data"] = fps
    meta["complete"] = True
    if holdout != "none":
        es = select_eval_frames(d, holdout=holdout, calibrated=td.calibrated, fingerprints=fps)
        res = evaluate_scorer(BaselineScorer(net, td.classes), es)
        meta["heldout"] = {
            k: res.metrics[k]
            for k in (
                "n_tuples",
                "n_recordings",
                "top1",
                "top3",
                "top1_vote",
                "top3_vote",
                "recording_top1",
            )
        }
    sha = save_baseline(out, net, meta)
    typer.echo(
        json.dumps(
            {
                "out": str(out),
                "sha256": sha,
                "train": meta["train"],
                "heldout": meta.get("heldout"),
            },
            indent=2,
        )
    )


@baseline_app.command("eval")
def baseline_eval_cmd(
    checkpoint: list[str] = typer.Option(..., "--checkpoint", help="baseline .safetensors"),
    data: list[Path] = typer.Option(..., "--data", help="STAG metadata.mat or folder; repeat"),
    split: str = typer.Option("test", "--split", help=SPLIT_HELP),
    holdout: str | None = typer.Option(None, "--holdout", help=HOLDOUT_HELP),
    votes: int = typer.Option(4, "--votes"),
    seed: int | None = typer.Option(None, "--seed"),
    json_out: Path = typer.Option(..., "--json"),
    report: Path | None = typer.Option(None, "--report"),
    threads: int = typer.Option(1, "--threads"),
) -> None:
    """Score baseline checkpoints with the same tuples and JSON keys as ``tactus eval``
    (voting and recording level average class probabilities)."""
    logging.basicConfig(level=logging.WARNING)
    _threads(threads)
    payload, first, es = run_eval(
        checkpoint, data, split=split, holdout=holdout, votes=votes, seed=seed
    )
    _write_outputs(payload, first, es, json_out, report, [])


@app.command("ablate")
def ablate_cmd(
    data: list[Path] = typer.Option(..., "--data", help="STAG metadata.mat or folder; repeat"),
    json_out: Path = typer.Option(..., "--json", help="write the ablation table JSON here"),
    steps: int = typer.Option(300, "--steps", help="training steps per run"),
    pretrain_steps: int | None = typer.Option(
        None, "--pretrain-steps", help="MAE steps per seed (default: --steps)"
    ),
    seeds: int = typer.Option(2, "--seeds", help="repeats per row (seeds 0..N-1)"),
    holdout: str = typer.Option(
        "one-per-object@blindfolded", "--holdout", help="held-out recordings that are scored"
    ),
    model: str = typer.Option("tactus-lite", "--model"),
    batch: int = typer.Option(64, "--batch"),
    space: str = typer.Option("minilm", "--space"),
    rows: str = typer.Option(
        "recipe,max_scaling,random_tuples,no_mae", "--rows", help="comma-separated rows to run"
    ),
    workdir: Path | None = typer.Option(
        None, "--workdir", help="checkpoints (default: beside JSON)"
    ),
    threads: int = typer.Option(1, "--threads"),
) -> None:
    """Recipe ablations: each row changes one thing of the recipe, seeds repeated, mean ± std."""
    logging.basicConfig(level=logging.WARNING)
    _threads(threads)
    from tactus_memory.touch.ablate import AblationConfig, format_table, run_ablation

    cfg = AblationConfig(
        steps=steps,
        pretrain_steps=pretrain_steps if pretrain_steps is not None else steps,
        seeds=seeds,
        holdout=holdout,
        model=model,
        batch=batch,
        space=space,
        rows=[r.strip() for r in rows.split(",") if r.strip()],
    )
    work = workdir or json_out.with_suffix("")
    json_out.parent.mkdir(parents=True, exist_ok=True)

    def write(partial: dict[str, Any]) -> None:
        json_out.write_text(json.dumps(dict(partial, complete=False), indent=1) + "\n")

    result = run_ablation(data, cfg, work, on_run=write)
    json_out.write_text(json.dumps(dict(result, complete=True), indent=1) + "\n")
    typer.echo(format_table(result))
