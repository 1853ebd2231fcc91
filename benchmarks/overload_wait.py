"""Acks under overload (issue 48, defect 12): WebSocket gloves at 30 Hz against one
``tactus serve --workers 1`` (a fresh store, the default ONNX Runtime server and the
shipped touch encoder), more windows than the machine can embed, with and without the group
commit's wait bound (``TACTUS_COMMIT_MAX_WAIT_MS``).

Per run: windows sent, acknowledged (``stored``), refused (503 error messages with
``retry_after``), never answered (no message within ``--drain`` s after the stream stopped),
and the ack latency p50/p99 (last frame of a window sent -> its ``stored`` ack). The
configurations alternate (``--rounds`` interleaved rounds: bounded, unbounded, ...) on one
server start each, so a shared machine's load falls on both alike; the load average is
recorded. "Unbounded" is the bound raised to 10 minutes: the queue's item bound alone.

    python benchmarks/overload_wait.py --gloves 48 --seconds 20 --rounds 2

Writes ``benchmarks/results/overload_wait.json`` (``--out``). The client runs on the same
cores as the server.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import tempfile
import time
from pathlib import Path
from typing import Any

from load import Barrier, GloveStats, pct, run_header, stream_gloves
from serving import free_port, start_serve, stop_process, wait_ok

ROOT = Path(__file__).resolve().parents[1]
#: "unbounded": the wait bound raised to 10 minutes (longer than any run)
UNBOUNDED_MS = 600_000
WINDOW = 8


def one_run(args: argparse.Namespace, bound_ms: float, work: Path, tag: str) -> dict[str, Any]:
    port = free_port()
    data = work / f"mem-{tag}"
    log = work / f"serve-{tag}.log"
    env = {"TACTUS_COMMIT_MAX_WAIT_MS": str(bound_ms)}
    proc = start_serve(port, data, log, env=env)
    try:
        if wait_ok(proc, f"http://127.0.0.1:{port}/ready", 600) is None:
            raise SystemExit(f"the server did not start:\n{log.read_text()[-2000:]}")
        stats = GloveStats()
        clock = Barrier(args.gloves, args.seconds)
        load_before = os.getloadavg()[0]
        sessions = [f"{tag}-g{g}" for g in range(args.gloves)]
        asyncio.run(
            stream_gloves(
                [port], sessions, stats, hz=args.hz, window=WINDOW, clock=clock,
                drain_s=args.drain,
            )
        )  # fmt: skip
    finally:
        stop_process(proc)
    answered = stats.stored + stats.errors
    return {
        "bound_ms": bound_ms,
        "windows_sent": stats.expected,
        "acked": stats.stored,
        "refused_503": stats.overloaded,
        "other_errors": stats.errors - stats.overloaded,
        "never_answered": stats.late_windows,
        "refused_share": round(stats.overloaded / max(1, stats.expected), 4),
        "answered_share": round(answered / max(1, stats.expected), 4),
        "ack_p50_s": round(pct(stats.lag, 50), 3),
        "ack_p99_s": round(pct(stats.lag, 99), 3),
        "ack_max_s": round(max(stats.lag, default=float("nan")), 3),
        "acks_later_than_bound_plus_1s": sum(x > bound_ms / 1000 + 1.0 for x in stats.lag),
        "load_1m": [round(load_before, 2), round(os.getloadavg()[0], 2)],
        "error_samples": stats.error_samples[:2],
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--gloves", type=int, default=48)
    ap.add_argument("--hz", type=float, default=30.0)
    ap.add_argument("--seconds", type=float, default=20.0)
    ap.add_argument("--drain", type=float, default=60.0)
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--bound-ms", type=float, default=1000.0)
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "overload_wait.json"))
    args = ap.parse_args()
    runs: list[dict[str, Any]] = []
    t0 = time.monotonic()
    with tempfile.TemporaryDirectory(prefix="tactus-overload-") as tmp:
        for r in range(args.rounds):
            for name, bound in (("bounded", args.bound_ms), ("unbounded", UNBOUNDED_MS)):
                run = one_run(args, bound, Path(tmp), f"{name}{r}")
                runs.append({"config": name, "round": r, **run})
                print(json.dumps(runs[-1]), flush=True)
    out = {
        **run_header("overload_wait"),
        "config": {k: v for k, v in vars(args).items() if k != "out"},
        "runs": runs,
        "wall_s": round(time.monotonic() - t0, 1),
    }
    Path(args.out).write_text(json.dumps(out, indent=2) + "\n")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
