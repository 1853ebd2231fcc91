"""Resident memory of a ``tactus serve`` (MiniLM + the shipped touch encoder), as `make run`
starts it: RSS of the server process (VmRSS and its peak, VmHWM, from /proc) once ready,
and again after some writes and searches. Linux only. Writes benchmarks/results/rss.json.

    python benchmarks/rss.py [--writes 200] [--searches 50]
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


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--writes", type=int, default=200, help="touch windows + notes written")
    ap.add_argument("--searches", type=int, default=50)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        port = free_port()
        base = f"http://127.0.0.1:{port}"
        log = Path(tmp) / "serve.log"
        t0 = time.perf_counter()
        proc = start_serve(port, Path(tmp) / "memory", log)
        try:
            if wait_ok(proc, base + "/ready", STARTUP_S, interval=0.2) is None:
                sys.exit(f"the server did not get ready:\n{log.read_text()[-2000:]}")
            ready_s = time.perf_counter() - t0
            ready = status_mb(proc.pid)
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
    result = {
        "what": "RSS of `tactus serve` (MiniLM-L6 + shipped tactus-lite touch encoder), MB",
        "ready": ready,
        "after": used,
        "writes": args.writes,
        "searches": args.searches,
        "seconds_to_ready": round(ready_s, 1),
        "torch_threads": os.environ.get("TACTUS_TORCH_THREADS", "default (half the cores)"),
        "machine": f"{platform.machine()}, {os.cpu_count()} cores, "
        f"Python {platform.python_version()}",
    }
    RESULTS.write_text(json.dumps(result, indent=2) + "\n")
    print(json.dumps(result, indent=2))


if __name__ == "__main__":
    main()
