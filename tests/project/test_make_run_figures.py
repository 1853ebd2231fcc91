"""The first-hour figures the README and Getting started quote for ``make run`` are those of
the latest run ``benchmarks/make_run.py`` recorded (``benchmarks/results/make_run_warm.json``):
seconds to ``ready``, resident memory once ready (MB = 10^6 bytes), the ``.venv``'s size
(GB), and the load the run saw."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
RESULTS = ROOT / "benchmarks" / "results" / "make_run_warm.json"
PAGES = ("README.md", "docs/getting-started.md")


@pytest.mark.parametrize("page", PAGES)
def test_the_quoted_make_run_figures_are_the_latest_run(page: str) -> None:
    run = json.loads(RESULTS.read_text())["runs"][-1]
    text = " ".join((ROOT / page).read_text().split())  # lines joined as the page reads
    ready = f"{round(run['ready_s']):,} s"
    rss = f"{round(run['rss_mb'])} MB"
    venv = f"{run['install_mb'] / 1000:.2f} GB"
    load = sorted([*run["load_1_5min_at_start"], *run["load_1_5min_at_ready"]])
    span = f"load {round(load[0])} to {round(load[-1])}"
    for figure in (ready, rss, venv, span):
        assert figure in text, f"{page} does not quote {figure!r} (results: {RESULTS.name})"
