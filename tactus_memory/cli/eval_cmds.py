"""``tactus eval``, ``tactus baseline train|eval`` and ``tactus ablate``: the paper's numbers."""

from __future__ import annotations

import json
import logging
from pathlib import Path
from typing import Annotated, Any

import typer

from tactus_memory.cli.app import app
from tactus_memory.cli.common import (
    CheckpointOut,
    LearningRate,
    ScoredHoldout,
    Seed,
    Split,
    StagFiles,
    Threads,
    output_folder,
    set_threads,
)
from tactus_memory.cli.sensor_opts import SensorData
from tactus_memory.cli.space_opts import SpaceDim, SpaceName, SpacePath, fail, space_choice
from tactus_memory.signatures import grouped

baseline_app = typer.Typer(
    help="The supervised STAG CNN (closed-set reference), trained and scored like Tactus.",
    no_args_is_help=True,
)
app.add_typer(baseline_app, name="baseline")


def _warn(message: str) -> None:
    typer.echo(message, err=True)


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
        from tactus_memory.training.report import write_report

        others = [json.loads(Path(p).read_text()) for p in compare]
        files = write_report(report, payload, first, es.calibrated, others)
        typer.echo(
            f"report: {', '.join(str(f) for f in files[:4])}" + (" …" if len(files) > 4 else "")
        )
    from tactus_memory.training.metrics import SCALAR_METRICS

    summary = {k: payload.get(k) for k in ("split", "n_tuples", "n_recordings", *SCALAR_METRICS)}
    if "aggregate" in payload:
        summary.update({f"{k}_std": payload.get(f"{k}_std") for k in SCALAR_METRICS})
    typer.echo(json.dumps(summary, indent=2))


@app.command("eval")
@grouped(source=SensorData)
def eval_cmd(
    checkpoint: Annotated[
        list[str],
        typer.Option(
            "--checkpoint", help="Tactus or baseline .safetensors, or 'default'; repeat for runs"
        ),
    ],
    split: Split = "test",
    holdout: ScoredHoldout = None,
    votes: int = typer.Option(4, "--votes", help="independent tuple draws pooled for *_vote"),
    seed: int | None = typer.Option(None, "--seed", help="tiling seed (default 1234, as train)"),
    json_out: Path = typer.Option(..., "--json", help="write the metrics JSON here"),
    report: Path | None = typer.Option(None, "--report", help="write report.md + PNGs here"),
    compare: list[Path] = typer.Option(
        [], "--compare", help="other eval JSONs (e.g. the baseline's) as rows of the table"
    ),
    analysis: bool = typer.Option(True, "--analysis/--no-analysis", help="confusion analyses"),
    threads: Threads = 1,
    space: SpaceName = None,
    space_path: SpacePath = None,
    space_dim: SpaceDim = None,
    stream: bool = typer.Option(
        False,
        "--stream",
        help="also score the memory as used: whole --holdout recordings as one session of "
        "consecutive windows, natural queries, match bar, last/count "
        "(touch/training/stream_eval.py)",
    ),
    stream_limit: int = typer.Option(0, "--stream-limit", help="stream only the first N (0: all)"),
    group: str | None = typer.Option(
        None,
        "--group",
        help="with --stream: 'grasp' also scores every mode grasp-grouped (<mode>_grasp: search, "
        "last and count rank grasps, a stream's contiguous windows pooled)",
    ),
    grasp_pool: list[str] = typer.Option(
        ["mean"],
        "--grasp-pool",
        help="with --group grasp: how a grasp is scored, repeat to compare: mean (every "
        "window pooled) | top (its 3 windows closest to the query) | max (its best window)",
    ),
    *,
    source: SensorData,
) -> None:
    """Score checkpoints on STAG or your own sensor's recordings (--data FILE.npz or --bag;
    calibrated with the first checkpoint's sensor profile unless --sensor/--shape say
    otherwise): top-1/3, voting, recording level, per class, confusion. The analyses embed
    phrasings in each checkpoint's space: a Qwen3-VL checkpoint needs --space-path (else they
    are skipped with a note)."""
    logging.basicConfig(level=logging.WARNING)
    if split not in ("test", "all"):
        raise typer.BadParameter("--split must be 'test' or 'all'")
    if stream and not holdout:
        raise typer.BadParameter("--stream needs --holdout (the recordings to stream)")
    if group not in (None, "grasp") or (group and not stream):
        raise typer.BadParameter(f"--group takes 'grasp', with --stream; got {group!r}")
    if bad := [p for p in grasp_pool if p not in ("mean", "top", "max")]:
        raise typer.BadParameter(f"--grasp-pool takes mean, top or max; got {bad}")
    set_threads(threads)
    from tactus_memory.errors import SpaceConfigError
    from tactus_memory.training.eval_runs import (
        checkpoint_profile,
        load_eval_data,
        run_eval,
    )
    from tactus_memory.training.evaluate import file_fingerprint

    given = space is not None or space_path is not None or space_dim is not None
    scope = {"split": split, "holdout": holdout, "votes": votes, "seed": seed}
    profile = source.profile(checkpoint_profile(checkpoint[0]))
    data = list(source.data or ())
    if source.bag:
        bag_data, profile = source.load(profile)
        loaded = (bag_data, [file_fingerprint(bag_data)])
    else:
        if not data:
            raise typer.BadParameter("give --data FILE... or --bag REC...")
        loaded = load_eval_data(data, profile)  # once: the stream evaluation reuses it
    try:
        payload, first, es = run_eval(
            checkpoint,
            data,
            analysis=analysis,
            warn=_warn,
            space=space_choice(space, space_path, space_dim) if given else None,
            loaded=loaded,
            profile=profile,
            **scope,
        )
    except SpaceConfigError as exc:
        fail(str(exc))
    if stream:
        from tactus_memory.training.stream_eval import run_stream_eval, stream_markdown

        sdata = loaded[0]
        groups = (None, group) if group else (None,)
        runs = [
            run_stream_eval(
                None if c == "default" else c,
                sdata,
                holdout or "",
                limit=stream_limit,
                groups=groups,
                pools=grasp_pool,
            )
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
            for pool in grasp_pool if group else []:
                g = r.get(f"served_{group}" + ("" if pool == "mean" else f"_{pool}"), {})
                typer.echo(
                    f"stream {r['checkpoint']} by {group} ({pool}): R@1 {g.get('r@1')} "
                    f"R@5 {g.get('r@5')} MRR {g.get('mrr')} last {g.get('last_correct')} "
                    f"count exact {g.get('count_exact')}"
                )
    _write_outputs(payload, first, es, json_out, report, compare)


@baseline_app.command("train")
def baseline_train_cmd(
    data: StagFiles,
    out: CheckpointOut,
    holdout: str = typer.Option("none", "--holdout", help="recordings kept out (train's grammar)"),
    epochs: int = typer.Option(30, "--epochs", help="passes over the training tuples"),
    max_steps: int | None = typer.Option(None, "--max-steps", help="cap on optimizer steps"),
    batch: int = typer.Option(32, "--batch"),
    lr: LearningRate = 1e-3,
    seed: Seed = 0,
    sampling: str = typer.Option("cluster", "--sampling", help="cluster | random"),
    k: int = typer.Option(8, "--k", help="frames per tuple (reference: 8)"),
    threads: Threads = 1,
) -> None:
    """Train the STAG reference CNN on the non-held-out frames; the last epoch is saved (no
    model selection). With --holdout, the held-out recordings are scored afterwards."""
    logging.basicConfig(level=logging.WARNING)
    set_threads(threads)
    output_folder(out)
    from tactus_memory.training.baseline import BaselineConfig
    from tactus_memory.training.eval_runs import train_baseline_run

    cfg = BaselineConfig(
        epochs=epochs, batch=batch, lr=lr, seed=seed, sampling=sampling, max_steps=max_steps, k=k
    )
    sha, meta = train_baseline_run(data, out, holdout, cfg)
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
    checkpoint: Annotated[list[str], typer.Option("--checkpoint", help="baseline .safetensors")],
    data: StagFiles,
    split: Split = "test",
    holdout: ScoredHoldout = None,
    votes: int = typer.Option(4, "--votes"),
    seed: int | None = typer.Option(None, "--seed"),
    json_out: Path = typer.Option(..., "--json"),
    report: Path | None = typer.Option(None, "--report"),
    threads: Threads = 1,
) -> None:
    """Score baseline checkpoints with the same tuples and JSON keys as ``tactus eval``
    (voting and recording level average class probabilities)."""
    logging.basicConfig(level=logging.WARNING)
    set_threads(threads)
    from tactus_memory.training.eval_runs import run_eval

    payload, first, es = run_eval(
        checkpoint, data, split=split, holdout=holdout, votes=votes, seed=seed, warn=_warn
    )
    _write_outputs(payload, first, es, json_out, report, [])


@app.command("ablate")
def ablate_cmd(
    data: StagFiles,
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
    rows: str = typer.Option(
        "recipe,max_scaling,random_tuples,no_mae", "--rows", help="comma-separated rows to run"
    ),
    workdir: Path | None = typer.Option(
        None, "--workdir", help="checkpoints (default: beside JSON)"
    ),
    threads: Threads = 1,
    space: SpaceName = None,
    space_path: SpacePath = None,
    space_dim: SpaceDim = None,
) -> None:
    """Recipe ablations: each row changes one thing of the recipe, seeds repeated, mean ± std."""
    logging.basicConfig(level=logging.WARNING)
    set_threads(threads)
    from tactus_memory.cli.space_opts import resolve_or_exit
    from tactus_memory.training.ablate import AblationConfig, format_table, run_ablation

    sp = resolve_or_exit(space, space_path, space_dim)

    cfg = AblationConfig(
        steps=steps,
        pretrain_steps=pretrain_steps if pretrain_steps is not None else steps,
        seeds=seeds,
        holdout=holdout,
        model=model,
        batch=batch,
        space=sp.name,
        rows=[r.strip() for r in rows.split(",") if r.strip()],
    )
    work = workdir or json_out.with_suffix("")
    json_out.parent.mkdir(parents=True, exist_ok=True)

    def write(partial: dict[str, Any]) -> None:
        json_out.write_text(json.dumps(dict(partial, complete=False), indent=1) + "\n")

    result = run_ablation(data, cfg, work, space=sp, on_run=write)
    json_out.write_text(json.dumps(dict(result, complete=True), indent=1) + "\n")
    typer.echo(format_table(result))
