"""Start time and resident memory of a ``tactus serve`` (MiniLM + the shipped touch
encoder), as `make run` starts it (ONNX Runtime; ``--torch``: the torch server): seconds
from the command to ``/ready`` and RSS of the server process (VmRSS and its peak, VmHWM,
from /proc) once ready, and again after some writes and searches. ``--rounds`` fresh starts
(the OS file cache warm after the first, as on a robot that restarts its server; MiniLM's
ONNX export, a first start's one-off, is made before the first round); the 1-minute load
average and the cores are recorded with every figure. Linux only. Writes
benchmarks/results/rss.json (``--out``).

    python benchmarks/rss.py [--rounds 3] [--torch] [--writes 200] [--searches 50]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import tempfile
import time
from pathlib import Path

import httpx
import numpy as np

from serving import free_port, start_serve, stop_process, wait_ok

RESULTS = Path(__file__).resolve().parent / "results" / "rss.json"
STARTUP_S = 300


def status_mb(pid: int) -> dict[str, float]:
    """VmRSS and VmHWM of ``pid`` in MB (10^6 bytes), from /proc/PID/status."""
    out = {}
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        key, _, value = line.partition(":")
        if key in ("VmRSS", "VmHWM"):
            out[key] = round(int(value.split()[0]) * 1024 / 1e6, 1)
    return out


def load1() -> float:
    return round(os.getloadavg()[0], 2)


def one_start(args: argparse.Namespace, tmp: Path) -> dict[str, object]:
    """A fresh server on a new store: seconds to /ready, RSS then and after the load."""
    port = free_port()
    base = f"http://127.0.0.1:{port}"
    log = tmp / "serve.log"
    extra = ["--torch"] if args.torch else []
    load_before = load1()
    t0 = time.perf_counter()
    proc = start_serve(port, tmp / "memory", log, *extra)
    try:
        if wait_ok(proc, base + "/ready", STARTUP_S, interval=0.05) is None:
            sys.exit(f"the server did not get ready:\n{log.read_text()[-2000:]}")
        ready_s = time.perf_counter() - t0
        time.sleep(1.0)  # idle: the loader's heap handed back (service/app.py)
        ready = status_mb(proc.pid)
        torch_loaded = "libtorch" in Path(f"/proc/{proc.pid}/maps").read_text()
        rng = np.random.default_rng(0)
        with httpx.Client(base_url=base, timeout=60) as c:
            for i in range(args.writes):
                w = np.full((8, 32, 32), 512, np.int16)
                w[:, 10:22, 8:20] = 600 + rng.integers(0, 80, (8, 12, 12))
                body = {"frames": w.tolist(), "t": float(i)}
                c.post("/sessions/rss/touch", json=body).raise_for_status()
                note = {"text": f"note {i} about the mug", "t": float(i)}
                c.post("/sessions/rss/text", json=note).raise_for_status()
            for i in range(args.searches):
                c.get("/search", params={"q": f"holding a mug {i}", "k": 10}).raise_for_status()
        used = status_mb(proc.pid)
    finally:
        stop_process(proc)
    return {
        "seconds_to_ready": round(ready_s, 2),
        "ready": ready,
        "after": used,
        "torch_loaded": torch_loaded,
        "load1_before": load_before,
        "load1_after": load1(),
    }


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--rounds", type=int, default=3, help="fresh starts")
    ap.add_argument("--torch", action="store_true", help="the torch server (tactus serve --torch)")
    ap.add_argument("--writes", type=int, default=200, help="touch windows + notes written")
    ap.add_argument("--searches", type=int, default=50)
    ap.add_argument("--out", type=Path, default=RESULTS)
    args = ap.parse_args()
    if not args.torch:  # a first start's one-off: not what a (re)start costs
        from tactus_memory.export.cache import default_folder, prepare

        prepare(default_folder(), None, print)
    rounds = []
    for i in range(args.rounds):
        with tempfile.TemporaryDirectory() as tmp:
            rounds.append(one_start(args, Path(tmp)))
        print(f"round {i + 1}: {json.dumps(rounds[-1])}", flush=True)
    result = {
        "what": "`tactus serve` (MiniLM-L6 + shipped tactus-lite touch encoder) as `make run` "
        "starts it: seconds to /ready, RSS in MB (10^6 bytes) once ready and idle, and after "
        "the writes and searches",
        "runtime": "torch (--torch)" if args.torch else "ONNX Runtime (the default)",
        "rounds": rounds,
        "seconds_to_ready": sorted(r["seconds_to_ready"] for r in rounds),
        "ready_rss_mb": sorted(r["ready"]["VmRSS"] for r in rounds),
        "writes": args.writes,
        "searches": args.searches,
        "torch_threads": os.environ.get("TACTUS_TORCH_THREADS", "default (half the cores)"),
        "machine": f"{platform.machine()}, {os.cpu_count()} cores, "
        f"Python {platform.python_version()}",
        "cores": os.cpu_count(),
    }
    args.out.write_text(json.dumps(result, indent=2) + "\n")
    print(json.dumps({k: result[k] for k in ("runtime", "seconds_to_ready", "ready_rss_mb")}))


if __name__ == "__main__":
    main()
