"""Service benchmark: /search latency end to end vs the library, and live touch ingest.

1. Search. A store of ``--rows`` synthetic 384-d "text" rows (a mixture around MiniLM
   embeddings of everyday phrases, plus noise) is bulk-loaded through the store's write path
   and indexed (``Memory.optimize``). Then the same unique natural-language queries (so the
   MiniLM query cache never hits: the text embedding is in every measurement) are run
   (a) directly on the library, ``Memory.search(q, k=10)``, in this process, and
   (b) over real HTTP, ``GET /search?q=...&k=10``, against the service (uvicorn) in a
   subprocess, in alternating blocks. The overhead ratio is HTTP end to end over the time
   the same request spent in ``Memory.search`` inside the server (``Server-Timing``): on a
   shared, overloaded box two processes never see the same load, so (a) is reported too
   but not used for the ratio.
2. Ingest. For each ``--ingest TOUCH:CLIENTS`` run, CLIENTS WebSocket clients stream binary
   ``.npy`` frames (uint16, raw units) at ``--hz`` for ``--seconds`` into their own sessions
   (window 8, stride 8) while one client searches; reports stored windows/s while streaming,
   drain time, errors, ack lag and search latency under load. ``stand-in`` uses a cheap
   projection touch sense (measures the service), ``real`` the shipped TactusEncoder.

    python benchmarks/service.py --rows 10000 --seconds 5            # quick (dev)
    nice python benchmarks/service.py --rows 100000 1000000          # full

Writes ``benchmarks/results/service.json`` (``--out``). Stores live in ``--workdir`` and are
reused across runs when their row count matches.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np

from load import Barrier, GloveStats, pct, queries, run_header, stream_gloves
from serving import free_port, stop_process, wait_ok

ROOT = Path(__file__).resolve().parents[1]
DIM = 384
K = 10
PHRASES = [
    "a hot mug of coffee",
    "a soft sponge",
    "a cold metal spoon",
    "a rough brick",
    "holding a glass bottle",
    "a squishy stress ball",
    "a sharp knife edge",
    "a wet towel",
    "a smooth ceramic plate",
    "pressing a button",
    "a heavy book",
    "a light paper cup",
    "a furry toy",
    "a plastic bag",
    "a wooden block",
    "a rubber glove",
    "a tennis ball",
    "a computer mouse",
    "a bunch of keys",
    "a pen in the hand",
    "an apple",
    "a banana",
    "the robot dropped the cup",
    "the operator said careful",
    "the box was heavy",
    "grasping firmly",
    "a gentle touch",
    "the table surface",
    "opening a door handle",
    "a slippery soap bar",
    "a crumpled sheet of paper",
    "a warm laptop",
    "a cold can of soda",
]


# ----------------------------------------------------------------------------- helpers
def summary_ms(xs: list[float]) -> dict[str, float]:
    return {
        "n": len(xs),
        "p50_ms": round(pct(xs, 50) * 1e3, 2),
        "p95_ms": round(pct(xs, 95) * 1e3, 2),
        "mean_ms": round(float(np.mean(xs)) * 1e3, 2) if xs else float("nan"),
    }


# ----------------------------------------------------------------------------- store
def build_store(path: Path, rows: int, seed: int = 0) -> dict[str, Any]:
    """Bulk-load ``rows`` synthetic text-sense rows (384-d) and build the index."""
    import pyarrow as pa

    from tactus_memory.memory.main import Memory
    from tactus_memory.spaces.minilm import MiniLMSpace

    space = MiniLMSpace()
    mem = Memory.open(str(path), space=space, background=False)
    have = mem.store.count("sense = 'text'")  # ingest runs add (and remove) touch rows
    if have == rows:
        return {"rows": rows, "reused": True}
    if have:
        raise SystemExit(f"{path} holds {have} rows, not {rows}; remove it or use --workdir")
    rng = np.random.default_rng(seed)
    cents = space.embed_texts(PHRASES, query=False)
    t0 = time.perf_counter()
    chunk = 100_000
    schema = mem.store.items.schema
    for a in range(0, rows, chunk):
        n = min(chunk, rows - a)
        c = cents[rng.integers(0, len(cents), n)]
        x = c + 0.8 * rng.standard_normal((n, DIM)).astype(np.float32) / np.sqrt(DIM)
        x /= np.linalg.norm(x, axis=1, keepdims=True)
        t = np.sort(rng.uniform(0, 86_400, n))
        data = pa.table(
            {
                "id": [f"r{a + i}" for i in range(n)],
                "session": [f"s{(a + i) % 100}" for i in range(n)],
                "sense": ["text"] * n,
                "t": t,
                "t_end": t + 1.0,
                "vector": pa.FixedSizeListArray.from_arrays(pa.array(x.reshape(-1)), DIM),
                "meta": ["{}"] * n,
                "text": [f"note {a + i}" for i in range(n)],
                "raw": pa.nulls(n, pa.binary()),
                "source": [""] * n,
                "episode": pa.nulls(n, pa.int64()),
                "created": [time.time()] * n,
            },
            schema=schema,
        )
        mem.store.write(data, upsert=False)  # the store's bulk path: one commit per chunk
    load_s = time.perf_counter() - t0
    t1 = time.perf_counter()
    mem.optimize()
    return {
        "rows": rows,
        "reused": False,
        "load_s": round(load_s, 1),
        "index_s": round(time.perf_counter() - t1, 1),
    }


# ----------------------------------------------------------------------------- server
class Child:
    """``tactus serve`` equivalent in a subprocess (a stand-in touch sense if none loads)."""

    def __init__(self, data: Path, log: Path, touch: str = "auto") -> None:
        self.port = free_port()
        self.base = f"http://127.0.0.1:{self.port}"
        cmd = [
            sys.executable,
            __file__,
            "--child",
            "--data",
            str(data),
            "--port",
            str(self.port),
            "--touch",
            touch,
        ]
        self.proc = subprocess.Popen(cmd, stdout=log.open("ab"), stderr=subprocess.STDOUT)
        r = wait_ok(self.proc, self.base + "/health", 300)
        if r is None and self.proc.poll() is not None:
            raise SystemExit(f"server died:\n{log.read_text()[-3000:]}")
        if r is None:
            self.stop()
            raise SystemExit("server did not start")
        self.health = r.json()

    def stop(self) -> None:
        stop_process(self.proc, 30)


def child_main(data: str, port: int, touch: str) -> None:
    import uvicorn

    from tactus_memory.service.app import create_app
    from tactus_memory.settings import Settings

    settings = Settings(data=data, port=port, log_level="warning", touch=touch != "stand-in")
    app = create_app(settings)
    state = app.state.tactus
    if touch == "real" and "touch" not in state.memory.senses:
        raise SystemExit(f"--touch real: {state.touch_unavailable}")
    if "touch" not in state.memory.senses:
        state.memory.add_sense(ProjectionTouch(DIM))
        print(f"touch: stand-in projection sense ({state.touch_unavailable})", flush=True)
        state.touch_unavailable = None
    uvicorn.run(app, host="127.0.0.1", port=port, log_level="warning", ws_per_message_deflate=False)


def ProjectionTouch(dim: int) -> Any:  # noqa: N802  (a factory; keeps imports lazy)
    from tactus_memory.senses.base import Sense
    from tactus_memory.vectors import as_unit_rows

    class _Projection(Sense):
        name = "touch"
        modality = "touch"

        def __init__(self) -> None:
            self.dim = dim
            self.proj = np.random.default_rng(0).standard_normal((1024, dim)).astype(np.float32)

        def validate(self, item: Any) -> np.ndarray:
            return np.asarray(item, dtype=np.float32)

        def embed(self, batch: Any) -> np.ndarray:
            x = np.stack([w.mean(axis=0).reshape(-1) for w in batch])
            return as_unit_rows((x - x.mean(axis=1, keepdims=True) + 1e-3) @ self.proj, dim)

        def provenance(self) -> dict[str, Any]:
            return {"encoder": "benchmark-projection-stand-in"}

    return _Projection()


# ----------------------------------------------------------------------------- search
def search_latency(
    path: Path, base: str, qs: list[str], block: int = 20, warmup: int = 60
) -> tuple[list[float], list[float], list[float]]:
    """The same queries on the library (in this process) and over HTTP (the server process).

    Both are warmed first (``warmup`` queries each: a freshly opened 1M-row store answers its
    first tens of queries slowly while LanceDB loads index partitions). Then blocks of
    ``block`` queries alternate between the two (and which goes first), so both see the same
    drift in machine load (this box is shared) without interfering query by query (a process
    that just ran torch keeps its threads spinning for a moment). Each process embeds every
    query itself: the queries are unique and each process has its own cache.
    """
    import httpx

    from tactus_memory.memory.main import Memory
    from tactus_memory.spaces.minilm import MiniLMSpace

    mem = Memory.open(str(path), space=MiniLMSpace(), background=False)
    # Searched from a worker thread, as the server does (on this box a main-thread torch call
    # measured up to 2x slower than the same call from a worker thread).
    worker = ThreadPoolExecutor(1)
    lib: list[float] = []
    http: list[float] = []
    inside: list[float] = []
    with httpx.Client(base_url=base, timeout=60) as c:

        def on_library(q: str, out: list[float] | None) -> None:
            t0 = time.perf_counter()
            worker.submit(mem.search, q, k=K).result()
            if out is not None:
                out.append(time.perf_counter() - t0)

        def on_http(q: str, out: list[float] | None) -> None:
            t0 = time.perf_counter()
            r = c.get("/search", params={"q": q, "k": K})
            if out is not None:
                out.append(time.perf_counter() - t0)
                dur = r.headers["server-timing"].partition(";dur=")[2]
                inside.append(float(dur) / 1e3)
            r.raise_for_status()
            assert len(r.json()["hits"]) == K

        for q in queries(warmup, seed=999_999):
            on_library(q, None)
            on_http(q, None)
        for b, a in enumerate(range(0, len(qs), block)):
            chunk = qs[a : a + block]
            runs = [(on_library, lib), (on_http, http)]
            for fn, out in runs if b % 2 == 0 else runs[::-1]:
                time.sleep(0.2)  # let the other process's threads go quiet
                for q in chunk:
                    fn(q, out)
    worker.shutdown()
    return lib, http, inside


# ----------------------------------------------------------------------------- ingest
async def ingest(port: int, clients: int, hz: float, seconds: float, window: int) -> dict:
    import httpx

    stats = GloveStats()
    run_id = f"{int(time.time())}"
    # Every client connects first; the clock starts when all are ready.
    clock = Barrier(clients + 1, seconds)

    search_lat: list[float] = []

    async def searcher() -> None:
        qs = queries(100_000, seed=7)
        async with httpx.AsyncClient(base_url=f"http://127.0.0.1:{port}", timeout=60) as c:
            await c.get("/health")
            await clock.ready()
            i = 0
            while time.monotonic() < clock.stop:
                t0 = time.perf_counter()
                r = await c.get("/search", params={"q": qs[i], "k": K})
                search_lat.append(time.perf_counter() - t0)
                r.raise_for_status()
                i += 1
                await asyncio.sleep(0.1)

    sessions = [f"bench-glove-{run_id}-{i}" for i in range(clients)]
    gloves = stream_gloves([port], sessions, stats, hz=hz, window=window, clock=clock)
    await asyncio.gather(gloves, searcher())
    wall = time.monotonic() - clock.start
    stop_at = clock.stop
    return {
        "clients": clients,
        "hz": hz,
        "window": window,
        "stride": window,
        "seconds": seconds,
        "frame_format": "binary .npy (32, 32) uint16, raw units",
        "sent_frames": stats.sent_frames,
        "frames_per_s": round(stats.sent_frames / seconds, 1),
        "target_frames_per_s": clients * hz,
        "windows_expected": stats.expected,
        "windows_stored": stats.stored,
        "windows_per_s": round(stats.stored / seconds, 1),
        "windows_stored_while_streaming": stats.stored_during,
        "windows_per_s_while_streaming": round(stats.stored_during / seconds, 1),
        "drain_s_after_stop": round(max(0.0, (stats.last_ack or stop_at) - stop_at), 2),
        "errors": stats.errors,
        "error_samples": stats.error_samples,
        "windows_unacked_after_60s": stats.late_windows,
        "ack_lag": summary_ms(stats.lag),
        "search_while_ingesting": summary_ms(search_lat),
        "wall_s": round(wall, 1),
    }


async def cleanup_bench_sessions(base: str) -> None:
    import httpx

    async with httpx.AsyncClient(base_url=base, timeout=120) as c:
        for s in (await c.get("/sessions")).json()["sessions"]:
            if s["id"].startswith("bench-glove-"):
                await c.delete(f"/sessions/{s['id']}")


# ----------------------------------------------------------------------------- main
def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--rows", type=int, nargs="+", default=[100_000, 1_000_000])
    ap.add_argument("--queries", type=int, default=200)
    ap.add_argument("--clients", type=int, default=64)
    ap.add_argument("--hz", type=float, default=30.0)
    ap.add_argument("--seconds", type=float, default=20.0)
    ap.add_argument("--window", type=int, default=8)
    ap.add_argument(
        "--ingest",
        nargs="*",
        default=["stand-in:64", "real:8"],
        metavar="TOUCH[:CLIENTS]",
        help="ingest runs; TOUCH: real (the shipped TactusEncoder), stand-in (a cheap "
        "projection: measures the service, not the encoder) or auto; CLIENTS default --clients",
    )
    ap.add_argument("--touch", default="auto", help=argparse.SUPPRESS)
    ap.add_argument("--workdir", default="/tmp/tactus-bench-service")
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "service.json"))
    ap.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--data", help=argparse.SUPPRESS)
    ap.add_argument("--port", type=int, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        child_main(args.data, args.port, args.touch)
        return
    sys.path.insert(0, str(ROOT))
    work = Path(args.workdir)
    work.mkdir(parents=True, exist_ok=True)
    log = work / "server.log"
    result: dict[str, Any] = {
        **run_header("service"),
        "search": [],
    }
    for rows in args.rows:
        path = work / f"rows-{rows}"
        print(f"[{rows}] building/reusing store at {path}", flush=True)
        build = build_store(path, rows)
        qs = queries(args.queries, seed=rows)
        server = Child(path, log)
        try:
            print(f"[{rows}] library and HTTP search x{len(qs)}, interleaved", flush=True)
            lib, http, inside = search_latency(path, server.base, qs)
        finally:
            server.stop()
        entry = {
            "rows": rows,
            "store": build,
            "k": K,
            "http": summary_ms(http),
            "library_in_server": summary_ms(inside),
            "library_in_client_process": summary_ms(lib),
            "overhead_ratio_p50": round(pct(http, 50) / pct(inside, 50), 3),
            "overhead_ratio_per_query_median": round(
                float(np.median(np.asarray(http) / np.asarray(inside))), 3
            ),
            "overhead_ms_p50": round(float(np.median(np.subtract(http, inside))) * 1e3, 2),
            "overhead_ratio_vs_client_process_p50": round(pct(http, 50) / pct(lib, 50), 3),
            "target_p50_ms": 25.0,
            "target_ratio": 1.3,
        }
        print(json.dumps(entry), flush=True)
        result["search"].append(entry)
    path = work / f"rows-{args.rows[-1]}"
    result["ingest"] = []
    for spec in args.ingest:  # `--ingest` with no value: search only
        touch, _, clients = spec.partition(":")
        n_clients = int(clients or args.clients)
        server = Child(path, log, touch)
        try:
            encoder = next(
                (s["provenance"] for s in httpx_senses(server.base) if s["name"] == "touch"), None
            )
            asyncio.run(cleanup_bench_sessions(server.base))  # leftovers of an interrupted run
            print(f"ingest [{touch}]: {n_clients} clients x {args.hz} Hz x {args.seconds}s")
            run = asyncio.run(ingest(server.port, n_clients, args.hz, args.seconds, args.window))
            run["touch"] = touch
            run["touch_encoder"] = {k: encoder.get(k) for k in ("encoder", "model", "checkpoint")}
            run["store_rows"] = args.rows[-1]
            print(json.dumps(run), flush=True)
            result["ingest"].append(run)
            asyncio.run(cleanup_bench_sessions(server.base))
        finally:
            server.stop()
    result["load_average_at_end"] = os.getloadavg()
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(result, indent=2) + "\n")
    print(f"wrote {out}")


def httpx_senses(base: str) -> list[dict[str, Any]]:
    import httpx

    return httpx.get(base + "/senses", timeout=30).json()["senses"]


if __name__ == "__main__":
    main()
