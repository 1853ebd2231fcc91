"""Start time and resident memory of a ``tactus serve`` (MiniLM + the shipped touch
encoder), as `make run` starts it (ONNX Runtime; ``--torch``: the torch server): seconds
from the command to ``/ready`` and RSS of the server process (VmRSS and its peak, VmHWM,
from /proc) once ready, and again after some writes and searches. ``--rounds`` fresh starts
(the OS file cache warm after the first, as on a robot that restarts its server; MiniLM's
ONNX export, a first start's one-off, is made before the first round); the 1-minute load
average and the cores are recorded with every figure. Linux only. Writes
benchmarks/results/rss.json (``--out``).

``--cold`` empties the kernel's file cache before every start (root: /proc/sys/vm/drop_caches),
as after a boot. ``--ab`` starts the server twice a round, with the start's read-ahead off
(``TACTUS_PREFETCH=0``, :mod:`tactus_memory.cli.prefetch`) and on, the order alternating
round by round, after one unmeasured start that records the read-ahead list; it reports each
variant's mean, the paired differences (on - off) and their mean with a 95 % t-interval.

    python benchmarks/rss.py [--rounds 3] [--torch] [--writes 200] [--searches 50]
    python benchmarks/rss.py --cold --ab --rounds 5 --writes 0 --searches 0 \
        --out benchmarks/results/rss_cold.json
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
from typing import Any

import httpx
import numpy as np

from serving import free_port, start_serve, stop_process, wait_ok

RESULTS = Path(__file__).resolve().parent / "results" / "rss.json"
STARTUP_S = 300
#: writing 3 here drops the page cache, dentries and inodes (Linux; root only)
DROP_CACHES = Path("/proc/sys/vm/drop_caches")
#: the A/B's two variants: the environment each start gets (tactus_memory/cli/prefetch.py)
VARIANTS: dict[str, dict[str, str]] = {"off": {"TACTUS_PREFETCH": "0"}, "on": {}}


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


def drop_caches() -> None:
    """Write out dirty pages, then empty the kernel's file cache: the next start reads every
    file from the disk, as the first start after a boot does."""
    os.sync()
    DROP_CACHES.write_text("3\n")


def one_start(
    args: argparse.Namespace, tmp: Path, env: dict[str, str] | None = None
) -> dict[str, object]:
    """A fresh server on a new store: seconds to /ready, RSS then and after the load."""
    port = free_port()
    base = f"http://127.0.0.1:{port}"
    log = tmp / "serve.log"
    extra = ["--torch"] if args.torch else []
    if args.cold:
        drop_caches()
    load_before = load1()
    t0 = time.perf_counter()
    proc = start_serve(port, tmp / "memory", log, *extra, env=env)
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
        "cold": args.cold,
        "ready": ready,
        "after": used,
        "torch_loaded": torch_loaded,
        "load1_before": load_before,
        "load1_after": load1(),
    }


def paired(off: list[float], on: list[float]) -> dict[str, object]:
    """The paired differences on - off, their mean and its 95 % t-interval (Student's t
    with n - 1 degrees of freedom; needs two pairs at least); their median and how many
    pairs were faster with the read-ahead, which one start slowed by a neighbour's burst
    moves less than the mean."""
    from scipy import stats

    diffs = [b - a for a, b in zip(off, on, strict=True)]
    n = len(diffs)
    mean = float(np.mean(diffs))
    half = float(stats.t.ppf(0.975, n - 1) * np.std(diffs, ddof=1) / np.sqrt(n))
    return {
        "differences_on_minus_off": [round(d, 2) for d in diffs],
        "mean_difference": round(mean, 3),
        "t95": [round(mean - half, 3), round(mean + half, 3)],
        "inside_the_noise": mean - half <= 0 <= mean + half,
        "median_difference": round(float(np.median(diffs)), 3),
        "pairs_faster_on": f"{sum(d < 0 for d in diffs)} of {n}",
    }


def ab_rounds(args: argparse.Namespace) -> dict[str, Any]:
    """``--ab``: one unmeasured start (it records the read-ahead list), then per round a
    start with the read-ahead off and one with it on, the order alternating."""
    with tempfile.TemporaryDirectory() as tmp:
        one_start(args, Path(tmp))
    rounds: list[dict[str, Any]] = []
    for i in range(args.rounds):
        order = list(VARIANTS) if i % 2 == 0 else list(reversed(VARIANTS))
        pair: dict[str, Any] = {"order": order}
        for name in order:
            with tempfile.TemporaryDirectory() as tmp:
                pair[name] = one_start(args, Path(tmp), env=VARIANTS[name])
        rounds.append(pair)
        seconds = {name: pair[name]["seconds_to_ready"] for name in order}
        print(f"round {i + 1}: {json.dumps(seconds)} load {load1()}", flush=True)
    seconds_of = {name: [r[name]["seconds_to_ready"] for r in rounds] for name in VARIANTS}
    return {
        "rounds": rounds,
        "seconds_to_ready": seconds_of,
        "mean_seconds": {k: round(float(np.mean(v)), 3) for k, v in seconds_of.items()},
        "paired": paired(seconds_of["off"], seconds_of["on"]) if args.rounds > 1 else None,
        "load1_before_each_start": [r[n]["load1_before"] for r in rounds for n in r["order"]],
    }


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--rounds", type=int, default=3, help="fresh starts")
    ap.add_argument("--torch", action="store_true", help="the torch server (tactus serve --torch)")
    ap.add_argument("--writes", type=int, default=200, help="touch windows + notes written")
    ap.add_argument("--searches", type=int, default=50)
    ap.add_argument("--out", type=Path, default=RESULTS)
    ap.add_argument("--cold", action="store_true", help="empty the file cache before each start")
    ap.add_argument("--ab", action="store_true", help="read-ahead off/on pairs (TACTUS_PREFETCH)")
    args = ap.parse_args()
    if args.cold and not os.access(DROP_CACHES, os.W_OK):
        sys.exit(f"--cold writes {DROP_CACHES}: run as root")
    if not args.torch:  # a first start's one-off: not what a (re)start costs
        from tactus_memory.export.cache import default_folder, prepare

        prepare(default_folder(), None, print)
    machine = {
        "machine": f"{platform.machine()}, {os.cpu_count()} cores, "
        f"Python {platform.python_version()}",
        "cores": os.cpu_count(),
    }
    if args.ab:
        ab = {
            "what": "seconds from `tactus serve` (as `make run` starts it) to /ready, the "
            "start's read-ahead off (TACTUS_PREFETCH=0) and on, in pairs, the order "
            "alternating; " + ("file cache emptied before every start" if args.cold else "warm"),
            "runtime": "torch (--torch)" if args.torch else "ONNX Runtime (the default)",
            "cold": args.cold,
            **ab_rounds(args),
            **machine,
        }
        args.out.write_text(json.dumps(ab, indent=2) + "\n")
        print(json.dumps({k: ab[k] for k in ("mean_seconds", "paired", "load1_before_each_start")}))
        return
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
        "cold": args.cold,
        **machine,
    }
    args.out.write_text(json.dumps(result, indent=2) + "\n")
    print(json.dumps({k: result[k] for k in ("runtime", "seconds_to_ready", "ready_rss_mb")}))


if __name__ == "__main__":
    main()
