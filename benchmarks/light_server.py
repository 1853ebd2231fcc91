"""A light server: cold start to ``/ready`` and idle RSS of ``tactus serve`` (MiniLM + the
shipped touch encoder), and what the two model runtimes cost on their own: torch
(sentence-transformers + the Tactus checkpoint, what the server runs) against ONNX Runtime
(both encoders exported by :mod:`tactus_memory.export.onnx`, run by
:mod:`tactus_memory.spaces.onnx_runtime`).

Each measurement is a fresh process (cold start; the OS file cache is warm after the first
round, as on a robot that restarts its server). The variants run back to back in
``--rounds`` rounds (A/B/C, A/B/C, ...), so a change of the shared machine's load hits all
of them; the 1-minute load average is recorded with every figure. A model-only child
reports the seconds and RSS after its imports and after loading and running each model.

    python benchmarks/light_server.py [--rounds 3] [--onnx-dir runs/onnx]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from rss import status_mb
from serving import free_port, start_serve, stop_process, wait_ok

RESULTS = Path(__file__).resolve().parent / "results" / "light_server.json"
READY_S = 300


def load1() -> float:
    return round(os.getloadavg()[0], 2)


def child(runtime: str, onnx_dir: str) -> None:
    """Load and run both encoders on ``runtime`` ("parts": what a server on ONNX loads, step
    by step); print one JSON line of steps."""
    import numpy as np

    t0 = time.perf_counter()
    steps: list[dict[str, Any]] = []

    def mark(what: str) -> None:
        steps.append(
            {"step": what, "s": round(time.perf_counter() - t0, 2), **status_mb(os.getpid())}
        )

    window = np.full((1, 8, 32, 32), 0.2, np.float32)  # (B, K, 32, 32) calibrated
    if runtime == "parts":
        mark("python")
        import lancedb  # noqa: F401

        mark("import lancedb (pyarrow, pandas)")
        from tactus_memory.service.app import create_app, open_store
        from tactus_memory.settings import Settings

        mark("import the service")
        settings = Settings(data=tempfile.mkdtemp() + "/mem", onnx=onnx_dir)
        memory = open_store(settings)
        mark("open a new store")
        create_app(settings, memory=memory)
        mark("build the app")
        memory.space.embed_texts(["warm up"])
        mark("MiniLM on ONNX loaded and run")
        from tactus_memory.adapters.touch import TactusEncoder

        TactusEncoder(onnx=onnx_dir).embed(window, calibrated=True)
        mark("touch encoder on ONNX loaded and run")
    elif runtime == "torch":
        import torch  # noqa: F401

        mark("import torch")
        from tactus_memory.spaces.minilm import MiniLMSpace

        MiniLMSpace().embed_texts(["warm up"])
        mark("MiniLM loaded and run")
        from tactus_memory.adapters.touch import TactusEncoder

        TactusEncoder().embed(window, calibrated=True)
        mark("touch encoder loaded and run")
    else:
        from tactus_memory.spaces.onnx_runtime import OnnxMiniLM, OnnxTouch

        mark("imports")
        OnnxMiniLM(onnx_dir).embed_texts(["warm up"])
        mark("MiniLM loaded and run")
        OnnxTouch(onnx_dir).embed(window)
        mark("touch encoder loaded and run")
    print(json.dumps(steps))


def models(runtime: str, onnx_dir: Path) -> dict[str, Any]:
    cmd = [sys.executable, __file__, "--child", runtime, "--onnx-dir", str(onnx_dir)]
    load = load1()
    t0 = time.perf_counter()
    out = subprocess.run(cmd, capture_output=True, text=True, timeout=READY_S, check=True)
    steps = json.loads(out.stdout.strip().splitlines()[-1])
    return {"process_s": round(time.perf_counter() - t0, 2), "load_1min": load, "steps": steps}


def server(tmp: Path, *extra: str) -> dict[str, Any]:
    """Cold start of ``tactus serve *extra`` on a new store: seconds from the process start
    to /ready answering 200, RSS then, and after 10 s idle."""
    port = free_port()
    base = f"http://127.0.0.1:{port}"
    log = tmp / "serve.log"
    load = load1()
    t0 = time.perf_counter()
    proc = start_serve(port, tempfile.mkdtemp(dir=tmp), log, *extra)
    try:
        if wait_ok(proc, base + "/ready", READY_S, interval=0.05) is None:
            sys.exit(f"the server did not get ready:\n{log.read_text()[-2000:]}")
        ready_s = time.perf_counter() - t0
        ready = status_mb(proc.pid)
        time.sleep(10)
        idle = status_mb(proc.pid)
    finally:
        stop_process(proc)
    return {"ready_s": round(ready_s, 2), "at_ready": ready, "idle_10s": idle, "load_1min": load}


def summary(runs: list[dict[str, Any]], key: str) -> dict[str, float]:
    vals = [r[key] for r in runs]
    return {"median": statistics.median(vals), "min": min(vals), "max": max(vals)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--rounds", type=int, default=3)
    onnx_dir = Path(__file__).resolve().parents[1] / "runs" / "onnx"  # the ignored runs/
    ap.add_argument("--onnx-dir", type=Path, default=onnx_dir, help="`tactus export-onnx` output")
    ap.add_argument("--child", choices=("torch", "onnx", "parts"), help=argparse.SUPPRESS)
    ap.add_argument("--out", type=Path, default=RESULTS)
    args = ap.parse_args()
    if args.child:
        child(args.child, str(args.onnx_dir))
        return
    if not (args.onnx_dir / "touch.onnx").exists():
        from tactus_memory.export.onnx import export_minilm, export_touch

        export_minilm(args.onnx_dir)
        export_touch(args.onnx_dir)
    variants = {
        "server_torch": lambda tmp: server(tmp),
        "server_onnx": lambda tmp: server(tmp, "--onnx", str(args.onnx_dir)),
        "models_torch": lambda tmp: models("torch", args.onnx_dir),
        "models_onnx": lambda tmp: models("onnx", args.onnx_dir),
    }
    runs: dict[str, list[dict[str, Any]]] = {name: [] for name in variants}
    load_start = os.getloadavg()
    with tempfile.TemporaryDirectory() as tmp:
        for r in range(args.rounds):
            for name, fn in variants.items():
                runs[name].append(fn(Path(tmp)))
                print(f"round {r} {name}: {json.dumps(runs[name][-1])}", flush=True)
    parts = models("parts", args.onnx_dir)  # where the ONNX server's memory goes
    result: dict[str, Any] = {
        "what": "cold start to /ready and idle RSS (MB, 10^6 bytes) of `tactus serve` with "
        "MiniLM + the shipped touch encoder; both encoders alone on torch vs ONNX Runtime",
        "targets": {"ready_s": 3.0, "idle_rss_mb": 400},
        "machine": {
            "cpus": os.cpu_count(),
            "load_avg_start": load_start,
            "load_avg_end": os.getloadavg(),
        },
        "rounds": args.rounds,
        "order": "variants back to back in each round (A/B/C, A/B/C, ...)",
        "runs": runs,
        "onnx_server_parts": parts,
        "summary": {
            **{
                f"{name}_{what}": summary(
                    [
                        {"v": r["ready_s"] if what == "ready_s" else r["idle_10s"]["VmRSS"]}
                        for r in runs[name]
                    ],
                    "v",
                )
                for name in ("server_torch", "server_onnx")
                for what in ("ready_s", "idle_rss_mb")
            },
            **{
                f"{name}_{what}": summary([{"v": r["steps"][-1][key]} for r in runs[name]], "v")
                for name in ("models_torch", "models_onnx")
                for what, key in (("s", "s"), ("rss_mb", "VmRSS"))
            },
        },
    }
    args.out.write_text(json.dumps(result, indent=2) + "\n")
    print(json.dumps(result["summary"], indent=2))


if __name__ == "__main__":
    main()
