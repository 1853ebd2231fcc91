"""``tactus data ...``: inspect STAG files (counts, class list, dynamic range, the gate)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import typer

from tactus_memory.cli.app import app

data_app = typer.Typer(name="data", help="Inspect STAG tactile data files.", no_args_is_help=True)
app.add_typer(data_app, name="data")


def inspect_summary(path: Path, profile_name: str = "stag-glove") -> dict[str, Any]:
    """Counts, lists, raw range and the dynamic-range report of one STAG subset."""
    import numpy as np

    from tactus_memory.errors import DynamicRangeError
    from tactus_memory.touch.data import (
        check_dynamic_range,
        dynamic_range_report,
        get_profile,
        load_stag,
    )

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
