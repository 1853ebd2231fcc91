"""What read-your-writes across ``tactus serve --workers N`` costs a search (issue 48,
defect 2).

Two processes on one real LanceDB store (``--rows`` text rows), as two workers: the other
one appends a note every ``--write-interval`` s (counted in the group's shared commit
counters, ``cli.workers.Workers``), this one searches. Each query is asked twice in a random
order, once plainly (the store's handles as LanceDB's read consistency interval leaves them)
and once after the worker's per-request step (:meth:`Workers.refresh`: the others' commit
counts compared, and the tables read at their latest version when they moved), so each pair
is one paired difference. Reported: search latency p50 of each, the mean paired difference
with a 95 % t interval, and how often the step found another worker's commit (then it reads
the latest versions; otherwise it costs a comparison of a few bytes). A 384-d stand-in space
(``memory.BenchSpace``) keeps the embedding cheap, so the step's share is larger than with
MiniLM.

    python benchmarks/read_your_writes.py --queries 300

Writes ``benchmarks/results/read_your_writes.json`` (``--out``).
"""

from __future__ import annotations

import argparse
import json
import multiprocessing as mp
import random
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np
from scipy import stats as st

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from load import queries, run_header  # noqa: E402
from memory import BenchSpace  # noqa: E402
from tactus_memory.cli.workers import COMMITS_FILE, COUNTER_BYTES, Workers  # noqa: E402
from tactus_memory.memory.main import Memory  # noqa: E402


def other_worker(path: str, folder: str, interval: float, stop: Any) -> None:
    group = Workers(1, 2, Path(folder))
    group.open_counters()
    memory = Memory.open(path, space=BenchSpace(), background=False)
    n = 0
    while not stop.is_set():
        memory.add("other", "text", f"note from the other worker {n}", t=float(n))
        n += 1
        time.sleep(interval)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--rows", type=int, default=5000)
    ap.add_argument("--queries", type=int, default=300)
    ap.add_argument("--write-interval", type=float, default=0.025)
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "read_your_writes.json"))
    args = ap.parse_args()
    with tempfile.TemporaryDirectory(prefix="tactus-ryw-") as tmp:
        path, folder = str(Path(tmp) / "mem"), Path(tmp) / "workers"
        folder.mkdir()
        (folder / COMMITS_FILE).write_bytes(bytes(COUNTER_BYTES * 2))
        memory = Memory.open(path, space=BenchSpace(), background=False)
        for b in range(0, args.rows, 2500):
            n = min(2500, args.rows - b)
            memory.add_many("bulk", "text", [f"note {b + i}" for i in range(n)], t=[0.0] * n)
        group = Workers(0, 2, folder)
        group.open_counters()
        ctx = mp.get_context("spawn")
        stop = ctx.Event()
        work = (path, str(folder), args.write_interval, stop)
        other = ctx.Process(target=other_worker, args=work)
        other.start()
        while group.others() == bytes(COUNTER_BYTES):  # the other worker writes
            time.sleep(0.05)
        rng = random.Random(48)
        plain, fresh, refreshed = [], [], 0
        for q in queries(args.queries, seed=48):
            order = ["plain", "fresh"]
            rng.shuffle(order)
            for kind in order:
                t0 = time.perf_counter()
                if kind == "fresh":
                    refreshed += group.refresh(memory)
                memory.search(q, k=5)
                (fresh if kind == "fresh" else plain).append(time.perf_counter() - t0)
        stop.set()
        other.join(30)
    diff = np.array(fresh) - np.array(plain)
    half = float(st.t.ppf(0.975, len(diff) - 1) * diff.std(ddof=1) / np.sqrt(len(diff)))
    ms = 1000.0
    out = {
        **run_header("read_your_writes"),
        "config": {k: v for k, v in vars(args).items() if k != "out"},
        "search_p50_ms_plain": round(float(np.median(plain)) * ms, 2),
        "search_p50_ms_read_your_writes": round(float(np.median(fresh)) * ms, 2),
        "paired_diff_mean_ms": round(float(diff.mean()) * ms, 2),
        "paired_diff_ci95_ms": [
            round((float(diff.mean()) - half) * ms, 2), round((float(diff.mean()) + half) * ms, 2)
        ],
        "requests_that_read_latest": refreshed,
        "requests": len(fresh),
    }  # fmt: skip
    Path(args.out).write_text(json.dumps(out, indent=2) + "\n")
    print(json.dumps({k: v for k, v in out.items() if k not in ("machine", "config")}))


if __name__ == "__main__":
    main()
