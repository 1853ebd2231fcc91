"""Ingest capacity of ``tactus serve --workers N``, measured against what the machine's cores
can embed, not as one machine's raw figure.

For each ``--workers`` count (a fresh store and server each; the default ONNX Runtime
server, the shipped touch encoder):

1. **encoder alone**: N processes (one per worker, one intra-op thread each, as a worker
   runs it) embed raw 8-frame windows with the touch encoder for ``--encoder-seconds``:
   windows/s on those cores, nothing else (validation + calibration + ONNX Runtime);
2. **idle search**: one searcher, ``GET /search`` back to back, p50/p95;
3. **saturation** (closed loop): ``--closed-gloves`` WebSocket gloves, each keeping
   ``--depth`` windows in flight (one binary ``.npy`` message of 8 frames per window, the
   next sent as soon as an ack comes back): acknowledged windows/s, and its ratio to (1)
   (the *efficiency*);
4. **below saturation** (open loop): ``--open-gloves`` gloves at 30 Hz, one frame per
   message (``load.stream_gloves``), with the searcher beside them: ack latency p50/p99
   (last frame sent -> ``stored``), refused windows, search p95 and its ratio to idle.

The client (this process) runs on the same cores as the server. The 1-minute load average
is recorded before and after every phase: the machine may be shared. Writes
``benchmarks/results/capacity.json`` (``--out``).

    python benchmarks/capacity.py --workers 1 2 [--seconds 20]
"""

from __future__ import annotations

import argparse
import asyncio
import json
import multiprocessing as mp
import os
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from fleet import Searchers
from load import Barrier, GloveStats, npy, pct, run_header, stream_gloves
from serving import free_port, start_serve, stop_process, wait_ok

RESULTS = Path(__file__).resolve().parent / "results" / "capacity.json"
WINDOW = 8
STARTUP_S = 600


def load1() -> float:
    return round(os.getloadavg()[0], 2)


def windows(n: int, seed: int) -> np.ndarray:
    """(n, WINDOW, 32, 32) uint16 raw windows with a contact patch (never idle)."""
    rng = np.random.default_rng(seed)
    out = np.full((n, WINDOW, 32, 32), 512, np.uint16)
    out[:, :, 8:24, 6:20] += rng.integers(60, 260, (n, WINDOW, 16, 14)).astype(np.uint16)
    return out


def _encode_for(seconds: float, batch: int, onnx: str, start: Any, out: Any) -> None:
    """A child: embed batches of raw windows for ``seconds`` once ``start`` is set."""
    from tactus_memory.adapters.touch import TactusEncoder

    enc = TactusEncoder(onnx=onnx)
    wins = windows(batch, 0)
    enc.embed(wins)  # warm
    start.wait()
    n, t0 = 0, time.perf_counter()
    while time.perf_counter() - t0 < seconds:
        enc.embed(wins)
        n += batch
    out.put(n / (time.perf_counter() - t0))


def encoder_alone(procs: int, seconds: float, batch: int, onnx: str) -> dict[str, Any]:
    ctx = mp.get_context("spawn")
    start, out = ctx.Event(), ctx.Queue()
    job = (seconds, batch, onnx, start, out)
    kids = [ctx.Process(target=_encode_for, args=job) for _ in range(procs)]
    for k in kids:
        k.start()
    time.sleep(0.5)
    before = load1()
    start.set()
    rates = [out.get(timeout=seconds + 300) for _ in kids]
    for k in kids:
        k.join()
    return {
        "processes": procs,
        "batch": batch,
        "windows_per_s": round(sum(rates), 1),
        "per_process": [round(r, 1) for r in rates],
        "load1_before": before,
        "load1_after": load1(),
    }


async def closed_loop(
    port: int, gloves: int, depth: int, seconds: float, first: int = 0
) -> dict[str, Any]:
    """Gloves ``first``.. that each keep ``depth`` windows in flight: acknowledged windows/s."""
    from websockets.asyncio.client import connect

    msgs = [npy(w) for w in windows(16, 1)]
    counts = {"stored": 0, "errors": 0, "overloaded": 0}
    clock = Barrier(gloves, seconds)
    workers: set[int] = set()

    async def glove(g: int) -> None:
        url = f"ws://127.0.0.1:{port}/sessions/cap{first + g}/touch/stream?window={WINDOW}&hz=30"
        async with connect(url, max_size=2**22, open_timeout=120) as ws:
            ready = json.loads(await ws.recv())
            workers.add(ready.get("worker", 0))
            await clock.ready()
            credit = asyncio.Semaphore(depth)

            async def sender() -> None:
                n = 0
                while time.monotonic() < clock.stop_at():
                    await credit.acquire()
                    await ws.send(msgs[(g + n) % len(msgs)])
                    n += 1

            task = asyncio.create_task(sender())
            try:
                while True:
                    wait = max(clock.stop_at() - time.monotonic(), 0.0) + 30.0
                    try:
                        raw = await asyncio.wait_for(ws.recv(), timeout=wait)
                    except TimeoutError:
                        break  # nothing in flight after the stop
                    msg = json.loads(raw)
                    if msg["type"] == "stored" and time.monotonic() <= clock.stop_at():
                        counts["stored"] += 1
                    elif msg["type"] == "error":
                        counts["errors"] += 1
                        counts["overloaded"] += msg.get("error", {}).get("status") == 503
                    credit.release()
                    if time.monotonic() > clock.stop_at():
                        break
            finally:
                task.cancel()

    before = load1()
    await asyncio.gather(*(glove(g) for g in range(gloves)))
    return {
        "stored_per_s": counts["stored"] / seconds,
        "gloves": gloves,
        "depth": depth,
        "seconds": seconds,
        "acked_windows_per_s": round(counts["stored"] / seconds, 1),
        **counts,
        "workers_holding_gloves": sorted(workers),
        "load1_before": before,
        "load1_after": load1(),
    }


async def open_loop(port: int, gloves: int, seconds: float) -> dict[str, Any]:
    """Gloves at 30 Hz (one frame a message) with a searcher beside them."""
    stats = GloveStats()
    clock = Barrier(gloves, seconds)
    searches: list[float] = []
    searcher = Searchers([f"http://127.0.0.1:{port}"], 1, 0.2, seed=2)
    sessions = [f"open{g}" for g in range(gloves)]
    before = load1()

    async def search_when_started() -> None:
        await clock.go.wait()
        await searcher.run(clock.stop_at(), searches)

    await asyncio.gather(
        stream_gloves([port], sessions, stats, hz=30.0, window=WINDOW, clock=clock),
        search_when_started(),
    )
    return {
        "gloves": gloves,
        "hz": 30,
        "seconds": seconds,
        "offered_windows_per_s": round(gloves * 30 / WINDOW, 1),
        "acked_windows_per_s": round(stats.stored_during / seconds, 1),
        "refused": stats.overloaded,
        "ack_p50_ms": round(1000 * pct(stats.lag, 50), 1),
        "ack_p99_ms": round(1000 * pct(stats.lag, 99), 1),
        "search_p95_ms": round(1000 * pct(searches, 95), 1),
        "searches": len(searches),
        "load1_before": before,
        "load1_after": load1(),
    }


async def idle_search(port: int, seconds: float) -> dict[str, Any]:
    out: list[float] = []
    await Searchers([f"http://127.0.0.1:{port}"], 1, 0.0, seed=1).run(
        time.monotonic() + seconds, out
    )
    return {"p50_ms": round(1000 * pct(out, 50), 1), "p95_ms": round(1000 * pct(out, 95), 1)}


def _closed_child(job: tuple[int, int, int, float, int]) -> dict[str, Any]:
    return asyncio.run(closed_loop(*job))


def closed_clients(
    port: int, gloves: int, depth: int, seconds: float, clients: int
) -> dict[str, Any]:
    """The closed loop from ``clients`` processes (one Python client tops out near a few
    thousand messages/s, below what 8 workers acknowledge): their gloves and rates summed.
    Each process starts its clock once its own gloves are connected."""
    if clients <= 1:
        return asyncio.run(closed_loop(port, gloves, depth, seconds))
    share = [gloves // clients + (i < gloves % clients) for i in range(clients)]
    jobs = [(port, n, depth, seconds, sum(share[:i])) for i, n in enumerate(share)]
    before = load1()
    with mp.get_context("spawn").Pool(clients) as pool:
        parts = pool.map(_closed_child, jobs)
    keys = ("stored", "errors", "overloaded")
    return {
        "gloves": gloves,
        "depth": depth,
        "seconds": seconds,
        "clients": clients,
        "acked_windows_per_s": round(sum(p["stored_per_s"] for p in parts), 1),
        **{k: sum(p[k] for p in parts) for k in keys},
        "workers_holding_gloves": sorted({w for p in parts for w in p["workers_holding_gloves"]}),
        "load1_before": before,
        "load1_after": load1(),
    }


def little(closed: dict[str, Any]) -> dict[str, Any]:
    """The closed loop's windows in flight and the mean ack time they imply (Little's law:
    in flight / acknowledged per second): a closed loop of fixed depth is bounded by it, so
    when the cores are not busy (load average well under the cores) the acknowledged rate is
    a floor on capacity, not the capacity."""
    in_flight = closed["gloves"] * closed["depth"]
    rate = closed["acked_windows_per_s"]
    return {"in_flight": in_flight, "implied_ack_s": round(in_flight / rate, 3) if rate else None}


def one_count(args: argparse.Namespace, workers: int, tmp: Path) -> dict[str, Any]:
    encoder = encoder_alone(workers, args.encoder_seconds, args.batch, str(args.onnx))
    print(f"  encoder alone, {workers} processes: {encoder}", flush=True)
    port = free_port()
    log = tmp / f"serve-{workers}.log"
    proc = start_serve(
        port, tmp / f"memory-{workers}", log, "--workers", str(workers), "--onnx", str(args.onnx)
    )
    try:
        if wait_ok(proc, f"http://127.0.0.1:{port}/ready", STARTUP_S, interval=0.2) is None:
            raise SystemExit(f"the server did not get ready:\n{log.read_text()[-3000:]}")
        idle = asyncio.run(idle_search(port, args.idle_seconds))
        closed = closed_clients(port, args.closed_gloves, args.depth, args.seconds, args.clients)
        closed.update(little(closed))
        print(f"  saturation: {closed}", flush=True)
        opened = asyncio.run(open_loop(port, args.open_gloves, args.seconds))
        print(f"  30 Hz fleet: {opened}", flush=True)
    finally:
        stop_process(proc)
    opened["search_p95_vs_idle"] = round(opened["search_p95_ms"] / idle["p95_ms"], 2)
    return {
        "workers": workers,
        "encoder_alone": encoder,
        "idle_search": idle,
        "saturation": closed,
        "efficiency": round(closed["acked_windows_per_s"] / encoder["windows_per_s"], 3),
        "below_saturation": opened,
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--seconds", type=float, default=20.0)
    ap.add_argument("--encoder-seconds", type=float, default=10.0)
    ap.add_argument("--idle-seconds", type=float, default=8.0)
    ap.add_argument("--batch", type=int, default=32, help="windows per encoder call (alone)")
    ap.add_argument("--closed-gloves", type=int, default=32)
    ap.add_argument("--depth", type=int, default=4, help="windows in flight per closed glove")
    ap.add_argument("--open-gloves", type=int, default=32)
    ap.add_argument(
        "--clients", type=int, default=1, help="processes driving the closed-loop gloves"
    )
    ap.add_argument("--out", type=Path, default=RESULTS)
    ap.add_argument(
        "--onnx",
        type=Path,
        default=None,
        help="an exported model folder to serve from (default: the user's cache, as serve does)",
    )
    args = ap.parse_args()
    if args.onnx is None:
        from tactus_memory.export.cache import default_folder, prepare

        # a first start's one-off export, not measured
        args.onnx = prepare(default_folder(), None, print)
    result: dict[str, Any] = {**run_header("capacity"), "onnx": args.onnx.name, "runs": []}
    with tempfile.TemporaryDirectory() as tmp:
        for w in args.workers:
            print(f"== --workers {w}", flush=True)
            result["runs"].append(one_count(args, w, Path(tmp)))
    runs = {r["workers"]: r for r in result["runs"]}
    if 1 in runs:
        one = runs[1]["saturation"]["acked_windows_per_s"]
        result["speedup_vs_one_worker"] = {
            w: round(r["saturation"]["acked_windows_per_s"] / one, 2) for w, r in runs.items()
        }
    result["load_average_at_end"] = os.getloadavg()
    args.out.write_text(json.dumps(result, indent=2) + "\n")
    print(json.dumps({k: result.get(k) for k in ("speedup_vs_one_worker",)}))
    for r in result["runs"]:
        print(r["workers"], r["efficiency"], r["saturation"]["acked_windows_per_s"])


if __name__ == "__main__":
    main()
