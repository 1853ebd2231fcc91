"""``tactus eval-recipe run|report|stream``: the validation protocol (2 folds x seeds, paired
differences against the shipped recipe; ``touch/training/protocol.py``)."""

from __future__ import annotations

from pathlib import Path

import typer

from tactus_memory.cli.app import app
from tactus_memory.cli.common import StagFiles

recipe_app = typer.Typer(
    help="Compare touch recipes on the validation protocol (2 folds x seeds, paired "
    "differences against the shipped recipe); every run is resumable.",
    no_args_is_help=True,
)
app.add_typer(recipe_app, name="eval-recipe")

Out = typer.Option(..., "--out", help="folder of the runs (resumable: finished runs are kept)")


@recipe_app.command("run")
def run_cmd(
    data: StagFiles,
    out: Path = Out,
    plan: str = typer.Option("cpu", "--plan", help="plan JSON, or a name in plans/ (cpu, gpu)"),
    jobs: int = typer.Option(2, "--jobs", min=1, help="training processes at a time"),
    threads: int = typer.Option(1, "--threads", min=1, help="torch threads per process"),
    device: str = typer.Option("auto", "--device"),
    only: list[str] = typer.Option([], "--only", help="only this recipe (and what it needs)"),
    targets_from: Path | None = typer.Option(
        None, "--targets-from", help="checkpoint whose class targets to train against"
    ),
    deadline_s: float = typer.Option(0.0, "--deadline-s", help="stop after this many seconds"),
) -> None:
    """Run every job of the plan not done yet, then write report.json / report.md."""
    from tactus_memory.training.protocol import Plan
    from tactus_memory.training.protocol_report import report_markdown
    from tactus_memory.training.protocol_run import RunnerConfig, run_command

    try:
        p = Plan.load(plan)
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise typer.BadParameter(f"--plan {plan}: {exc}") from exc
    rc = RunnerConfig(
        out=out, data=[str(d) for d in data], jobs=jobs, threads=threads, device=device,
        targets_from=str(targets_from) if targets_from else None, deadline_s=deadline_s,
        only=only,
    )  # fmt: skip
    res = run_command(p, rc)
    typer.echo(report_markdown(res["report"]))
    if res["status"]["failed"]:
        typer.echo(f"failed: {sorted(res['status']['failed'])} (see their .log)", err=True)
        raise typer.Exit(1)


@recipe_app.command("report")
def report_cmd(
    out: Path = Out,
    baseline: str = typer.Option("shipped", "--baseline", help="the recipe paired against"),
) -> None:
    """Mean, 95 % interval and paired difference per recipe, from the finished runs."""
    from tactus_memory.training.protocol_report import report_markdown, write_report

    if not out.is_dir():
        raise typer.BadParameter(f"--out {out}: no such folder")
    typer.echo(report_markdown(write_report(out, baseline)))


@recipe_app.command("stream")
def stream_cmd(
    data: StagFiles,
    out: Path = Out,
    recipe: list[str] = typer.Option([], "--recipe", help="only this recipe's runs"),
) -> None:
    """Stream metrics (grasp-grouped R@1/R@5 in a real memory) of finished fold runs."""
    from tactus_memory.training.protocol_report import add_stream_metrics

    n = add_stream_metrics(out, [str(d) for d in data], recipe)
    typer.echo(f"stream metrics written for {n} runs")
