"""Memory benchmark: ingest rate, search latency and recall@10, with and without filters,
and search latency under streaming appends. Writes JSON (default benchmarks/results/memory.json).

Data: 384-d "embedding-like" vectors: a Gaussian mixture of ``--centroids`` random unit
centroids plus isotropic noise (cosine to own centroid ~0.7), renormalised. Rows are spread
over 50 sessions and two vector senses ("touch" 75 %, "motion" 25 %). Queries are fresh
draws from the same mixture. Search is measured at the library level with a precomputed
query vector (``Memory.search_vector``), so text-embedding time is excluded; MiniLM query
embedding time is reported separately.

Ground truth is exact: cosine against every allowed row, per-sense z-scores with the
memory's own calibration, merged top 10 (exactly what ``search_vector`` approximates).

    python benchmarks/memory.py --sizes 10000            # quick
    nice python benchmarks/memory.py                      # 10k, 100k, 1M (~20 min on 2 cores)
    python benchmarks/memory.py --sizes 100000 --compare --stream-seconds 0  # index types

Results merge into the output JSON: ``sizes`` (the default index) and ``index_comparison``
are kept side by side, each with the machine and arguments of its run under ``runs``.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import statistics
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from tactus_memory.adapters.vectors import VectorSense  # noqa: E402
from tactus_memory.memory.main import Memory  # noqa: E402
from tactus_memory.spaces.base import Space  # noqa: E402
from tactus_memory.storage.tables import IndexConfig  # noqa: E402

DIM = 384
N_SESSIONS = 50
SENSES = ("touch", "motion")
SENSE_P = (0.75, 0.25)
K = 10


class BenchSpace(Space):
    """A 384-d stand-in space for vector-only benchmarks (never embeds text here)."""

    name = "bench-384"
    dim = DIM

    def __init__(self) -> None:
        self.rng = np.random.default_rng(0)  # a fresh vector per text (disk.py stores notes)

    def embed_texts(self, texts: Any, *, query: bool = False) -> np.ndarray:
        x = self.rng.standard_normal((len(texts), DIM)).astype(np.float32)
        return x / np.linalg.norm(x, axis=1, keepdims=True)


# ----------------------------------------------------------------------------- data
def mixture(n: int, centroids: np.ndarray, rng: np.random.Generator, noise: float = 1.0):
    """n draws: (n, D) unit float32. noise 1.0 -> cosine to own centroid ~0.7."""
    out = np.empty((n, DIM), np.float32)
    step = 100_000
    for a in range(0, n, step):
        b = min(n, a + step)
        c = centroids[rng.integers(0, len(centroids), b - a)]
        x = c + noise * rng.standard_normal((b - a, DIM)).astype(np.float32) / np.sqrt(DIM)
        out[a:b] = x / np.linalg.norm(x, axis=1, keepdims=True)
    return out


def make_data(n: int, n_centroids: int, seed: int) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(seed)
    cents = rng.standard_normal((n_centroids, DIM)).astype(np.float32)
    cents /= np.linalg.norm(cents, axis=1, keepdims=True)
    return {
        "centroids": cents,
        "vectors": mixture(n, cents, rng),
        "session": rng.integers(0, N_SESSIONS, n),
        "sense": rng.choice(len(SENSES), n, p=SENSE_P),
        "t": np.sort(rng.uniform(0, 86_400, n)),
    }


# ----------------------------------------------------------------------------- helpers
def pct(xs: list[float], p: float) -> float:
    return float(np.percentile(np.asarray(xs), p))


def open_memory(path: str, cfg: IndexConfig, background: bool) -> Memory:
    mem = Memory.open(path, space=BenchSpace(), index=cfg, background=background)
    for s in SENSES:
        if s not in mem.senses:
            mem.add_sense(VectorSense(s, dim=DIM))
    return mem


def ingest(
    mem: Memory,
    data: dict[str, np.ndarray],
    batch: int,
    pos: np.ndarray | None = None,
    senses: tuple[str, ...] = SENSES,
) -> tuple[np.ndarray, float]:
    """Bulk add grouped by (session, sense) in chunks; returns ids (row order) and rows/s.
    With ``pos`` ((N, 3), row order) each row is placed at its position in frame ``map``;
    ``data["sense"]`` indexes ``senses``."""
    n = len(data["vectors"])
    ids = np.empty(n, dtype=object)
    t0 = time.perf_counter()
    order = np.lexsort((data["t"], data["sense"], data["session"]))
    groups = np.split(
        order, np.flatnonzero(np.diff(data["session"][order] * 10 + data["sense"][order])) + 1
    )
    for g in groups:
        s, k = int(data["session"][g[0]]), int(data["sense"][g[0]])
        for a in range(0, len(g), batch):
            idx = g[a : a + batch]
            placed = {} if pos is None else {"position": pos[idx], "frame": "map"}
            ids[idx] = mem.add_many(
                f"s{s}", senses[k], list(data["vectors"][idx]), t=data["t"][idx].tolist(), **placed
            )
    return ids, n / (time.perf_counter() - t0)


def exact_topk(
    mem: Memory,
    data: dict[str, np.ndarray],
    ids: np.ndarray,
    q: np.ndarray,
    mask: np.ndarray | None,
    senses: tuple[str, ...] = SENSES,
) -> list[set[str]]:
    """Exact merged top-K under the memory's per-sense calibration; q: (Q, D)."""
    mu = np.zeros(len(senses))
    sd = np.ones(len(senses))
    for j, s in enumerate(senses):
        c = mem.calibration(s)
        mu[j], sd[j] = c.mu, c.sigma
    vec = data["vectors"]
    allowed = np.arange(len(vec)) if mask is None else np.flatnonzero(mask)
    best_z = np.empty((0, len(q)), np.float32)
    best_i = np.empty((0, len(q)), np.int64)
    for a in range(0, len(allowed), 100_000):  # all queries at once: one pass over the rows
        idx = allowed[a : a + 100_000]
        sense = data["sense"][idx]
        z = (vec[idx] @ q.T - mu[sense][:, None]) / sd[sense][:, None]  # (chunk, Q)
        top = np.argpartition(-z, K - 1, axis=0)[:K] if len(idx) > K else np.indices(z.shape)[0]
        best_z = np.concatenate([best_z, np.take_along_axis(z, top, 0)])
        best_i = np.concatenate([best_i, idx[top]])
    order = np.argsort(-best_z, axis=0)[:K]
    return [set(ids[best_i[order[:, j], j]]) for j in range(len(q))]


def measure(
    mem: Memory, queries: np.ndarray, truth: list[set[str]] | None, **filters: Any
) -> dict[str, float]:
    lat, rec = [], []
    mem.search_vector(queries[0], k=K, **filters)  # warm caches
    cpu0 = time.process_time()
    for i, qv in enumerate(queries):
        t0 = time.perf_counter()
        hits = mem.search_vector(qv, k=K, **filters)
        lat.append((time.perf_counter() - t0) * 1000)
        if truth is not None:
            rec.append(len({h.id for h in hits} & truth[i]) / max(1, min(K, len(truth[i]))))
    out = {
        "p50_ms": pct(lat, 50),
        "p95_ms": pct(lat, 95),
        "mean_ms": statistics.fmean(lat),
        # CPU seconds of all this process's threads per query: less sensitive than wall time
        # to other processes competing for the two cores
        "cpu_ms_per_query": (time.process_time() - cpu0) * 1000 / len(queries),
    }
    if rec:
        out["recall_at_10"] = float(np.mean(rec))
    return out


def tune(
    mem: Memory,
    queries: np.ndarray,
    truth: list[set[str]],
    grid: list[dict[str, Any]],
    target: float,
) -> tuple[dict[str, Any], list[dict[str, Any]]]:
    """Try each search setting; pick the fastest with recall >= target (else best recall)."""
    rows = []
    for g in grid:
        for key, val in g.items():
            setattr(mem.store.index, key, val)
        r = measure(mem, queries, truth)
        rows.append({**g, **r})
    ok = [r for r in rows if r["recall_at_10"] >= target]
    best = min(ok, key=lambda r: r["p50_ms"]) if ok else max(rows, key=lambda r: r["recall_at_10"])
    chosen = {k: best[k] for k in grid[0]}
    for key, val in chosen.items():
        setattr(mem.store.index, key, val)
    return chosen, rows


def grid_for(index_type: str) -> list[dict[str, Any]]:
    if index_type == "IVF_HNSW_SQ":
        return [
            {"nprobes": p, "ef": ef, "refine_factor": rf}
            for p in (2, 4, 8)
            for ef in (64, 128)
            for rf in (None, 4)
        ]
    return [
        {"nprobes": p, "ef": None, "refine_factor": rf}
        for p in ((5, 10, 20) if index_type == "IVF_SQ" else (10, 20, 40))
        for rf in ((None, 2, 5) if index_type == "IVF_SQ" else (5, 10, 20))
    ]


def partition_rows(index_type: str, n: int) -> int:
    # IVF_HNSW_SQ: few large partitions (HNSW inside); IVF_SQ/PQ: ~sqrt(n) partitions
    if index_type == "IVF_HNSW_SQ":
        return max(16_384, n // 16)
    return max(1024, int(np.sqrt(n)) * 4)


def streaming(
    mem: Memory, queries: np.ndarray, seconds: float, batch: int, per_s: float, phase: float = 2.0
) -> dict[str, Any]:
    """Search latency while a writer thread appends small batches (with background
    compaction every ``compact_every`` appends), against quiet periods.

    The writer is switched on and off in alternating ``phase``-second windows and every search
    is tagged "busy" (writer on, or maintenance running) or "quiet", so slow drifts in the
    machine's background load hit both sides alike.
    """
    rng = np.random.default_rng(99)
    cents = rng.standard_normal((64, DIM)).astype(np.float32)
    cents /= np.linalg.norm(cents, axis=1, keepdims=True)
    stop, on = threading.Event(), threading.Event()
    written = [0]

    def writer() -> None:
        while not stop.is_set():
            if not on.is_set():
                on.wait(0.05)
                continue
            t0 = time.perf_counter()
            vec = mixture(batch, cents, rng)
            mem.add_many("stream", "touch", list(vec), t=[time.time()] * batch)
            written[0] += batch
            stop.wait(max(0.0, 1.0 / per_s - (time.perf_counter() - t0)))

    def maintaining() -> bool:
        th = mem._maint_thread
        return th is not None and th.is_alive()

    mem.search_vector(queries[0], k=K)
    th = threading.Thread(target=writer, daemon=True)
    th.start()
    lat: dict[str, list[float]] = {"busy": [], "quiet": []}
    t_start = time.perf_counter()
    i = 0
    while (now := time.perf_counter()) < t_start + seconds:
        if int((now - t_start) / phase) % 2:
            on.set()
        else:
            on.clear()
        busy = on.is_set() or maintaining()
        t0 = time.perf_counter()
        mem.search_vector(queries[i % len(queries)], k=K)
        lat["busy" if busy or on.is_set() else "quiet"].append((time.perf_counter() - t0) * 1000)
        i += 1
        time.sleep(0.002)
    stop.set()
    on.set()
    th.join()
    mem.wait_for_maintenance(300)
    after = measure(mem, queries, None)
    q50, b50 = pct(lat["quiet"], 50), pct(lat["busy"], 50)
    q95, b95 = pct(lat["quiet"], 95), pct(lat["busy"], 95)
    return {
        "writer": {"batch": batch, "batches_per_s": per_s, "rows_written": written[0]},
        "compact_every": mem.store.index.compact_every,
        "quiet": {"p50_ms": q50, "p95_ms": q95, "n": len(lat["quiet"])},
        "during_appends": {"p50_ms": b50, "p95_ms": b95, "n": len(lat["busy"])},
        "after_appends_and_compaction": after,
        "slowdown_p50": b50 / q50,
        "slowdown_p95": b95 / q95,
    }


def text_embedding_ms(n: int = 30) -> dict[str, float] | None:
    try:
        from tactus_memory.spaces import get_space

        space = get_space("minilm")
        space.embed_texts(["warm up"], query=True)
    except Exception as exc:  # noqa: BLE001
        return {"error": str(exc)}  # type: ignore[dict-item]
    lat = []
    for i in range(n):
        t0 = time.perf_counter()
        space.embed_texts([f"where did I put the red mug number {i}?"], query=True)
        lat.append((time.perf_counter() - t0) * 1000)
    return {"p50_ms": pct(lat, 50), "p95_ms": pct(lat, 95), "space": space.name}


# ----------------------------------------------------------------------------- one size
def run_size(n: int, args: argparse.Namespace, index_types: list[str]) -> dict[str, Any]:
    print(f"== {n} rows", flush=True)
    data = make_data(n, args.centroids, seed=n)
    rng = np.random.default_rng(7)
    queries = mixture(args.queries, data["centroids"], rng)
    sess_q = "s3"
    filt_mask = (data["session"] == 3) & (data["sense"] == 0)
    root = tempfile.mkdtemp(prefix=f"tactus-bench-{n}-", dir=args.tmp)
    result: dict[str, Any] = {"rows": n, "filter_selectivity": float(filt_mask.mean())}
    try:
        path = os.path.join(root, "mem")
        cfg = IndexConfig(threshold=10**12)  # no background index during the bulk load
        mem = open_memory(path, cfg, background=False)
        ids, rate = ingest(mem, data, args.batch)
        result["ingest_rows_per_s"] = rate
        t0 = time.perf_counter()
        mem.store.items.optimize()
        result["compact_s"] = time.perf_counter() - t0
        print(f"  ingest {rate:.0f} rows/s, compact {result['compact_s']:.1f}s", flush=True)
        truth = exact_topk(mem, data, ids, queries, None)
        # tuning queries are separate draws, so the reported recall is not tuned on
        tune_q = mixture(args.tune_queries, data["centroids"], np.random.default_rng(8))
        tune_truth = exact_topk(mem, data, ids, tune_q, None)
        truth_f = exact_topk(mem, data, ids, queries, filt_mask)
        filters = {"session": sess_q, "senses": ["touch"]}
        result["flat"] = {
            "unfiltered": measure(mem, queries[: args.flat_queries], truth),
            "filtered": measure(mem, queries[: args.flat_queries], truth_f, **filters),
        }
        print(f"  flat {result['flat']}", flush=True)
        if n < args.index_from:
            result["index"] = None
            return result
        result["indexes"] = {}
        for it in index_types:
            cfg.index_type = it
            cfg.rows_per_partition = partition_rows(it, n)
            t0 = time.perf_counter()
            mem.store.build_indexes()
            build_s = time.perf_counter() - t0
            chosen, sweep = tune(mem, tune_q, tune_truth, grid_for(it), args.tune_target)
            r = {
                "build_s": build_s,
                "partitions": max(1, n // cfg.rows_per_partition),
                "chosen": chosen,
                "sweep": sweep,
                "unfiltered": measure(mem, queries, truth),
                "filtered": measure(mem, queries, truth_f, **filters),
            }
            print(
                f"  {it}: build {build_s:.1f}s chosen {chosen} unf {r['unfiltered']} "
                f"filt {r['filtered']}",
                flush=True,
            )
            result["indexes"][it] = r
        if args.stream_seconds > 0:
            mem.background = True
            cfg.compact_every = args.compact_every
            result["streaming"] = streaming(
                mem, queries, args.stream_seconds, args.stream_batch, args.stream_rate
            )
            print(f"  streaming {result['streaming']}", flush=True)
        return result
    finally:
        shutil.rmtree(root, ignore_errors=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[10_000, 100_000, 1_000_000])
    ap.add_argument("--index-type", default="IVF_SQ", help="index measured at every size")
    ap.add_argument(
        "--compare",
        action="store_true",
        help="measure IVF_SQ, IVF_HNSW_SQ and IVF_PQ (stored under index_comparison)",
    )
    ap.add_argument("--index-from", type=int, default=50_000, help="build indexes from this size")
    ap.add_argument("--centroids", type=int, default=1000)
    ap.add_argument("--queries", type=int, default=200)
    ap.add_argument("--tune-queries", type=int, default=100, help="separate tuning queries")
    ap.add_argument("--tune-target", type=float, default=0.99, help="recall@10 to tune for")
    ap.add_argument("--flat-queries", type=int, default=30)
    ap.add_argument("--batch", type=int, default=10_000, help="rows per add_many in bulk load")
    ap.add_argument("--stream-seconds", type=float, default=20.0)
    ap.add_argument("--stream-batch", type=int, default=50)
    ap.add_argument("--stream-rate", type=float, default=10.0, help="batches per second")
    ap.add_argument("--compact-every", type=int, default=64)
    ap.add_argument("--tmp", default=None, help="where the temporary stores go")
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "memory.json"))
    ap.add_argument("--no-text", action="store_true", help="skip MiniLM query timing")
    args = ap.parse_args()

    import lancedb

    results: dict[str, Any] = {
        "machine": {
            "cpus": os.cpu_count(),
            "platform": platform.platform(),
            "python": platform.python_version(),
            "lancedb": lancedb.__version__,
            "load_avg_start": os.getloadavg(),
        },
        "args": vars(args),
        "sizes": {},
    }
    t_all = time.perf_counter()
    section = "index_comparison" if args.compare else "sizes"
    results[section] = {}
    for n in args.sizes:
        types = ["IVF_SQ", "IVF_HNSW_SQ", "IVF_PQ"] if args.compare else [args.index_type]
        results[section][str(n)] = run_size(n, args, types)
    if not args.no_text:
        results["text_query_embedding"] = text_embedding_ms()
    results["total_s"] = time.perf_counter() - t_all
    results["machine"]["load_avg_end"] = os.getloadavg()
    out = Path(args.out)
    merged: dict[str, Any] = json.loads(out.read_text()) if out.exists() else {}
    run = {k: v for k, v in results.items() if k not in ("sizes", "index_comparison")}
    merged.setdefault("runs", {})[section] = run  # machine/args of the run behind each section
    merged.setdefault(section, {}).update(results[section])
    if "text_query_embedding" in results:
        merged["text_query_embedding"] = results["text_query_embedding"]
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(merged, indent=2, default=str))
    print(f"wrote {args.out} in {results['total_s']:.0f}s")


if __name__ == "__main__":
    main()
