"""Bulk work on Ray: rows/s of ``ingest`` and ``reembed`` on the local path and as Ray Data
jobs with 1 and 2 workers (issue 28).

    nice python benchmarks/ray_bulk.py [--files 4] [--minutes 2]
                                       [--out benchmarks/results/ray_bulk.json]

Writes ``--files`` real MCAP recordings (benchmarks/recordings.py's glove + notes, a seed per
file), then, each into a fresh real store (MiniLM space, the shipped TactusEncoder):

* ``local``: ``ingest_recording`` in this process (models loaded before timing);
  each ingest is then run again (``rerun``: every id found, nothing embedded or added, its
  ``rows`` are the ids found): the fixed cost of starting workers, decoding, looking up;
* ``ray_1`` / ``ray_2``: ``ingest_on_ray`` on a local Ray instance of 2
  CPUs, with 1 and 2 one-CPU workers. The wall time includes starting the workers (each
  loads torch, MiniLM and the touch encoder) and Lance's commit: what a user waits for.

then re-embeds the touch rows of the local store (a copy each) with the shipped checkpoint
the same three ways. Every Ray run's rows are checked against the local run's (same ids).
The machine has 2 cores shared with other engineers' work: the load average is recorded
around each run, and the figures are only comparable within one run of this script.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import sys
import tempfile
import time
from functools import partial
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks.recordings import TOPICS, make_messages  # noqa: E402
from tactus_memory.recordings import samples as rf  # noqa: E402

#: Ray worker counts measured (the machine has 2 cores)
WORKERS = (1, 2)


def _load() -> list[float]:
    return [round(x, 2) for x in os.getloadavg()]


def _open(path: Path) -> Any:
    from tactus_memory.adapters.touch import TactusEncoder
    from tactus_memory.memory.main import Memory

    mem = Memory.open(str(path), background=False)
    mem.add_sense(TactusEncoder())
    return mem


def _ids(mem: Any) -> list[str]:
    return sorted(mem.store.scan(None, ["id"]).column("id").to_pylist())


def _new_rows(summary: Any) -> int:
    return sum(summary.rows.values())


def _timed(run: Any, rows_of: Any) -> dict[str, Any]:
    before = _load()
    t = time.perf_counter()
    out = run()
    wall = time.perf_counter() - t
    rows = rows_of(out)
    return {"wall_s": round(wall, 2), "rows": rows, "rows_per_s": round(rows / wall, 2),
            "loadavg_before": before, "loadavg_after": _load()}  # fmt: skip


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--files", type=int, default=4)
    ap.add_argument("--minutes", type=float, default=2.0, help="per file")
    ap.add_argument("--out", default=str(ROOT / "benchmarks/results/ray_bulk.json"))
    args = ap.parse_args()

    import ray

    from tactus_memory.adapters.touch import TactusEncoder
    from tactus_memory.recordings.ingest import ingest_recording
    from tactus_memory.recordings.ray_jobs import LOCAL, connect, ingest_on_ray, reembed_on_ray

    work = Path(tempfile.mkdtemp(prefix="tactus-bench-ray-"))
    try:
        paths = [rf.write_mcap(work / f"glove{i}.mcap", make_messages(args.minutes, 30.0, seed=i))
                 for i in range(args.files)]  # fmt: skip
        mem = _open(work / "local")
        mem.space.embed_texts(["warm up"])  # models loaded before timing
        ingest: dict[str, Any] = {}
        connect(LOCAL, workers=max(WORKERS))
        for name in ("local", *(f"ray_{n}" for n in WORKERS)):
            m = mem if name == "local" else _open(work / name)
            run = (
                partial(ingest_recording, m, paths)
                if name == "local"
                else partial(ingest_on_ray, m, paths, address=LOCAL, workers=int(name[4:]))
            )
            run = partial(run, session="bench", topics=TOPICS)
            ingest[name] = _timed(run, _new_rows)
            # again: every id found, nothing embedded (the fixed cost: start, decode, look up)
            ingest[name]["rerun"] = again = _timed(run, lambda s: s.existing)
            assert again["rows"] == ingest[name]["rows"], f"{name}: a re-run added rows"
            assert _ids(m) == _ids(mem), f"{name}: other ids than the local path"
        reembed: dict[str, Any] = {}
        for name in ("local", *(f"ray_{n}" for n in WORKERS)):
            shutil.copytree(work / "local", work / f"re_{name}")
            m = _open(work / f"re_{name}")
            enc = TactusEncoder()
            if name == "local":
                run = partial(m.reembed, "touch", enc)
            else:
                n = int(name.split("_")[1])
                run = partial(reembed_on_ray, m, "touch", enc, address=LOCAL, workers=n)
            reembed[name] = _timed(run, lambda r: r.rows)
        ray.shutdown()
    finally:
        shutil.rmtree(work, ignore_errors=True)
    result = {
        "command": "python benchmarks/ray_bulk.py " + " ".join(sys.argv[1:]),
        "recordings": {
            "files": args.files,
            "minutes_each": args.minutes,
            "hz": 30.0,
            "format": "mcap",
            "topics": TOPICS,
        },  # fmt: skip
        "ingest": ingest,
        "reembed": reembed,
        "machine": {
            "cpus": os.cpu_count(),
            "python": platform.python_version(),
            "ray": ray.__version__,
            "note": "2 cores shared with other engineers' builds and tests (see each run's "
            "load average); Ray wall times include starting the workers and loading the "
            "models in each; a local Ray instance on the same 2 cores cannot beat the "
            "local path, the figures show the overhead and the scaling from 1 to 2 workers",
        },
    }
    text = json.dumps(result, indent=2) + "\n"
    Path(args.out).write_text(text)
    print(text, end="")


if __name__ == "__main__":
    main()
