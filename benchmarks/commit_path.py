"""The group committer alone, without a server (issue 28): how long a touch window waits
from ``GroupCommitter.submit`` to its acknowledgement when nothing but the fleet's windows
runs, and where each commit's time goes. The real parts: a fresh LanceDB store, the MiniLM
space, the shipped TactusEncoder; ``--gloves`` streams' windows (raw 8x32x32 frames, one
window per glove every ``window / hz`` s) are submitted from this process's main thread at
the fleet's rate for ``--seconds``; the committer runs on ``--torch-threads`` torch threads.

Reported: ack latency (submit -> future done) p50/p95/p99, and per commit the time of its
steps (embedding, Arrow rows, the LanceDB write, the version read) at p50/p95, with the
1-minute load average. Set beside ``fleet_ii.py``'s ack latency through a real server, the
difference is what the server adds (event loop, WebSocket, the interpreter lock).

    python benchmarks/commit_path.py --gloves 64      # ~30 s; results/commit_path.json
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
import time
from collections import defaultdict
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from load import run_header

ROOT = Path(__file__).resolve().parents[1]
WINDOW = 8  # frames per window (the shipped encoder's)
#: raw 16-bit-range pressure (the STAG glove's ADC range), never idle
PRESSURE_MAX = 3000.0


def timed(obj: Any, name: str, key: str, into: dict[str, list[float]]) -> None:
    """Wrap ``obj.name`` so each call's seconds land in ``into[key]``."""
    f: Callable[..., Any] = getattr(obj, name)

    def g(*a: Any, **k: Any) -> Any:
        t0 = time.perf_counter()
        try:
            return f(*a, **k)
        finally:
            into[key].append(time.perf_counter() - t0)

    setattr(obj, name, g)


def pct(xs: list[float], scale: float = 1000.0) -> dict[str, float]:
    a = np.asarray(xs) * scale
    return {
        "n": len(a),
        **{f"p{q}_ms": round(float(np.percentile(a, q)), 2) for q in (50, 95, 99)},
    }


def one_run(args: argparse.Namespace) -> dict[str, Any]:
    import tactus_memory.memory.writes as writes
    from tactus_memory.adapters.touch import TactusEncoder
    from tactus_memory.memory.group_commit import GroupCommitter
    from tactus_memory.memory.main import Memory

    memory = Memory.open(tempfile.mkdtemp(prefix="tactus-commit-path-"))
    memory.add_sense(TactusEncoder())
    rng = np.random.default_rng(0)
    # windows: (G, K, 32, 32) raw frames, one per glove
    windows = rng.uniform(0, PRESSURE_MAX, size=(args.gloves, WINDOW, 32, 32)).astype(np.float32)
    steps: dict[str, list[float]] = defaultdict(list)
    for name in ("embed_isolated", "writes_table"):
        timed(writes, name, name, steps)
    path = memory.write_path
    timed(path, "commit_writes", "commit_writes", steps)
    timed(path.store, "write", "store.write", steps)
    timed(path.store, "version", "store.version", steps)
    acks: list[float] = []
    period = WINDOW / args.hz  # a glove completes a window every period s
    per_tick = args.gloves * args.tick_s / period  # windows due per submit tick
    with GroupCommitter(memory, encode_threads=args.torch_threads) as gc:
        gc.submit("warm-up", "touch", [windows[0]], t=[0.0]).result()
        for v in steps.values():
            v.clear()
        start = time.monotonic()
        due, sent, i = 0.0, 0, 0
        while time.monotonic() < start + args.seconds:
            due += per_tick
            while sent < int(due):
                g = sent % args.gloves
                t0 = time.perf_counter()
                fut = gc.submit(f"glove-{g}", "touch", [windows[g]], t=[float(sent)])
                fut.add_done_callback(lambda _f, t0=t0: acks.append(time.perf_counter() - t0))
                sent += 1
            i += 1
            time.sleep(max(0.0, start + i * args.tick_s - time.monotonic()))
        stats = gc.stats
    return {
        "gloves": args.gloves,
        "windows_per_s_offered": args.gloves / period,
        "windows_submitted": sent,
        "ack_latency": pct(acks),
        "commits": stats.commits,
        "windows_per_commit": round(stats.items / max(stats.commits, 1), 1),
        "commit_steps": {k: pct(v) for k, v in steps.items()},
        "load_1min_after": os.getloadavg()[0],
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--gloves", type=int, nargs="+", default=[64])
    ap.add_argument("--hz", type=float, default=30.0)
    ap.add_argument("--seconds", type=float, default=20.0)
    ap.add_argument("--tick-s", type=float, default=1 / 30, help="how often windows are submitted")
    ap.add_argument("--torch-threads", type=int, default=1, help="as `tactus serve` on 2 cores")
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "commit_path.json"))
    args = ap.parse_args()
    result: dict[str, Any] = {**run_header("commit_path"), "runs": []}
    for gloves in args.gloves:
        run = one_run(argparse.Namespace(**{**vars(args), "gloves": gloves}))
        print(json.dumps({k: run[k] for k in ("gloves", "ack_latency", "windows_per_commit")}))
        result["runs"].append(run)
    Path(args.out).write_text(json.dumps(result, indent=2) + "\n")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
