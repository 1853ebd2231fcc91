"""``tactus data ...``: inspect STAG files (counts, class list, dynamic range, the gate), show
the data folder (``data path``) and get the STAG lite files into it (``data fetch stag``)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import typer

from tactus_memory.cli.app import app

data_app = typer.Typer(
    name="data", help="STAG tactile data: where it is, get it, inspect it.", no_args_is_help=True
)
app.add_typer(data_app, name="data")


def inspect_summary(path: Path, profile_name: str = "stag-glove") -> dict[str, Any]:
    """Counts, lists, raw range and the dynamic-range report of one STAG subset."""
    import numpy as np

    from tactus_memory.errors import DynamicRangeError
    from tactus_memory.touch.profile import check_dynamic_range, dynamic_range_report, get_profile
    from tactus_memory.training.data import load_stag

    profile = get_profile(profile_name)
    data = load_stag(path)
    report = dynamic_range_report(data.pressure, profile)
    try:
        check_dynamic_range(data.pressure, profile)
        gate = "pass"
    except DynamicRangeError as exc:
        gate = f"FAIL: {exc}"
    split_counts = {
        name: {
            "frames": int(data.split_mask(name).sum()),
            "valid_frames": int(data.valid_mask(name).sum()),
            "anchors": int(data.anchor_mask(name).sum()),
        }
        for name in data.splits
    }
    return {
        "path": data.sources[0],
        "frames": data.n_frames,
        "recordings": data.n_recordings,
        "recordings_listed": len(data.recordings),
        "valid_frames": data.valid_frames,
        "anchors": int(data.anchor_mask().sum()),
        "objects": data.objects,
        "objects_present": int(np.unique(data.object_id).size),
        "splits": split_counts,
        "raw_min": report["raw_min"],
        "raw_max": report["raw_max"],
        "extra_fields": sorted(data.extra),
        "fingerprint": data.fingerprint(),
        "dynamic_range": report,
        "gate": gate,
    }


def _fmt(value: Any) -> str:
    if isinstance(value, float):
        return f"{value:.6g}"
    return str(value)


@data_app.command("inspect")
def inspect(
    path: Path = typer.Argument(..., help="metadata.mat, or the subset folder holding it"),
    as_json: bool = typer.Option(False, "--json", help="Print one JSON object."),
    profile: str = typer.Option("stag-glove", help="Sensor calibration profile."),
) -> None:
    """Counts, class list, raw range and calibrated dynamic range of a STAG subset."""
    from tactus_memory.errors import TactusError

    try:
        summary = inspect_summary(path, profile)
    except TactusError as exc:
        typer.echo(f"error: {exc}", err=True)
        raise typer.Exit(code=2) from exc
    if as_json:
        typer.echo(json.dumps(summary, indent=2))
        return
    rows = [(k, v) for k, v in summary.items() if k not in ("dynamic_range", "objects", "splits")]
    width = max(len(k) for k, _ in rows)
    for key, value in rows:
        typer.echo(f"{key:<{width}}  {_fmt(value)}")
    typer.echo(f"{'objects':<{width}}  " + ", ".join(summary["objects"]))
    for name, counts in summary["splits"].items():
        typer.echo(
            f"{'split ' + name:<{width}}  " + ", ".join(f"{k}={v}" for k, v in counts.items())
        )
    typer.echo("")
    typer.echo("dynamic range (calibrated levels on the 1/255 grid, over the taxels)")
    dr = summary["dynamic_range"]
    dwidth = max(len(k) for k in dr)
    for key, value in dr.items():
        typer.echo(f"  {key:<{dwidth}}  {_fmt(value)}")


@data_app.command("path")
def path_cmd(
    as_json: bool = typer.Option(False, "--json", help="Print one JSON object."),
    stag: bool = typer.Option(False, "--stag", help="Print only the STAG folder (for scripts)."),
) -> None:
    """Where the data folder is (TACTUS_DATA_HOME, the user data folder, or ../shared beside a
    checkout) and which STAG subsets it holds."""
    from tactus_memory.datasets.home import data_home, how_to_get_stag

    home = data_home()
    subsets = home.stag_subsets()
    if stag:
        typer.echo(str(home.stag))
        return
    if as_json:
        out = {"path": str(home.path), "source": home.source, "stag": str(home.stag)}
        typer.echo(json.dumps({**out, "stag_subsets": subsets}, indent=2))
        return
    typer.echo(f"data folder  {home.path}  ({home.source})")
    typer.echo(f"STAG subsets {', '.join(subsets) if subsets else 'none'}  (under {home.stag})")
    if not subsets:
        typer.echo(how_to_get_stag(), err=True)


#: ``tactus data fetch --base-url``
MIRROR_HELP = (
    "Download from this mirror: <base-url>/<subset>/metadata.mat "
    "(default: TACTUS_STAG_BASE_URL, else the public ini_estim mirror on GitHub)."
)


@data_app.command("fetch")
def fetch_cmd(
    dataset: str = typer.Argument(..., help="The data set to get: `stag`."),
    from_dir: Path | None = typer.Option(
        None,
        "--from",
        help="Import files you already have instead of downloading: a folder holding "
        "<subset>/metadata.mat (or stag/<subset>/metadata.mat, or one subset folder).",
    ),
    base_url: str | None = typer.Option(None, "--base-url", help=MIRROR_HELP),
    subset: list[str] = typer.Option(
        [], "--subset", help="Only these subsets (repeatable; default: all pinned ones)."
    ),
    progress: bool = typer.Option(True, "--progress/--no-progress", help="Progress bars."),
) -> None:
    """Get the STAG lite subsets (weights_lite, blindfolded_lite) into the data folder,
    sha256-checked against pinned sums; an interrupted download resumes on the next run."""
    from tactus_memory.datasets.stag import (
        FetchError,
        StagSource,
        fetch_stag,
        fetch_target,
        import_stag,
    )

    if dataset != "stag":
        typer.echo(f"error: unknown data set {dataset!r}; known: stag", err=True)
        raise typer.Exit(code=2)
    source = StagSource.from_env(base_url)

    def say(line: str) -> None:
        typer.echo(line, err=True)

    try:
        if from_dir is not None:
            placed = import_stag(from_dir, source=source, subsets=subset or None, say=say)
        else:
            placed = fetch_stag(source=source, subsets=subset or None, progress=progress, say=say)
    except FetchError as exc:
        typer.echo(f"error: {exc}", err=True)
        raise typer.Exit(code=1) from exc
    for p in placed:
        typer.echo(f"{p.subset}\t{p.status}\t{p.sha256}\t{p.path}")
    typer.echo(f"data folder: {fetch_target()}", err=True)
