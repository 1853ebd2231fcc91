"""Place-filter benchmark (issue 23): ``search`` with ``near=`` against unfiltered search, at
``--rows`` rows (default 1M), with recall against the exact answer and the query plan
LanceDB runs (does the place filter use the x/y/z scalar indexes, or scan every row?).

Data: ``benchmarks/memory.py``'s 384-d Gaussian-mixture vectors (two vector senses, 50
sessions), each row placed uniformly in a 200 m x 200 m x 2 m warehouse (``frame`` map).
Indexes: the store's own (``Store.build_indexes``: IVF_SQ on the vector; BTREE on id,
session, t and x, y; BITMAP on sense). Search at the library level with a precomputed
query vector (``Memory.search_vector``), so text embedding is excluded.

    python benchmarks/places.py                       # 1M rows (a few minutes on 2 cores)
    python benchmarks/places.py --rows 100000         # quick
    python benchmarks/places.py --placement walk      # rows along per-session random walks

Writes JSON (default ``benchmarks/results/places.json``; one entry per row count).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks.memory import (  # noqa: E402
    K,
    exact_topk,
    ingest,
    make_data,
    mixture,
    open_memory,
    pct,
)
from tactus_memory.storage.codes import coded_query  # noqa: E402
from tactus_memory.storage.tables import IndexConfig  # noqa: E402
from tactus_memory.where import Where  # noqa: E402

#: the warehouse the rows are placed in (metres)
SIDE = 200.0
HEIGHT = 2.0
#: place filters measured: (name, radius in metres); ~0.2 % and ~3 % of the rows
RADII = (("near_5m", 5.0), ("near_20m", 20.0))
CENTRE = (100.0, 100.0, 1.0)


def place_rows(data: dict[str, np.ndarray], how: str, rng: np.random.Generator) -> np.ndarray:
    """(N, 3) positions: ``uniform`` over the warehouse (the worst case for the place filter:
    the rows near a place are scattered over the whole table), or ``walk``: each session's
    rows, in time order, follow its own random walk (1 m steps, reflected at the walls), as
    a robot's do, so the rows near a place come in runs."""
    n = len(data["t"])
    if how == "uniform":
        return np.column_stack([rng.uniform(0, SIDE, n), rng.uniform(0, SIDE, n),
                                rng.uniform(0, HEIGHT, n)])  # fmt: skip
    pos = np.empty((n, 3))
    for s in np.unique(data["session"]):
        idx = np.flatnonzero(data["session"] == s)
        idx = idx[np.argsort(data["t"][idx], kind="stable")]
        steps = rng.normal(0, 1.0, (idx.size, 2))
        walk = rng.uniform(0, SIDE, 2) + np.cumsum(steps, axis=0)
        walk = np.abs(np.mod(walk, 2 * SIDE) - SIDE)  # reflect into [0, SIDE]
        walk = SIDE - walk if s % 2 else walk
        pos[idx, :2] = walk
        pos[idx, 2] = rng.uniform(0, HEIGHT)
    return pos


def plan(mem: Any, vector: np.ndarray, sql: str) -> dict[str, Any]:
    """What LanceDB runs for the filter: the prefiltered vector search's plan and the count's
    (the ranker counts the allowed rows first), and whether each reads a scalar index."""
    vector = coded_query(vector, None, mem.store.codes())  # as stored: with its code columns
    q = mem.store.items.search(vector, vector_column_name="vector").distance_type("cosine")
    text = q.where(sql, prefilter=True).limit(K).explain_plan(verbose=True)
    scan = mem.store.items.search().where(sql).limit(None).explain_plan(verbose=True)
    uses = ("ScalarIndexQuery", "MaterializeIndex", "ScalarIndex")
    return {
        "search_plan_uses_scalar_index": any(u in text for u in uses),
        "scan_plan_uses_scalar_index": any(u in scan for u in uses),
        "search_plan": text,
        "scan_plan": scan,
    }


def run(n: int, args: argparse.Namespace) -> dict[str, Any]:
    print(f"== {n} rows", flush=True)
    data = make_data(n, args.centroids, seed=n)
    pos = place_rows(data, args.placement, np.random.default_rng(11))
    queries = mixture(args.queries, data["centroids"], np.random.default_rng(7))
    root = tempfile.mkdtemp(prefix=f"tactus-places-{n}-", dir=args.tmp)
    out: dict[str, Any] = {"rows": n, "queries": args.queries, "placement": args.placement}
    try:
        cfg = IndexConfig(threshold=10**12)  # no background index during the bulk load
        mem = open_memory(os.path.join(root, "mem"), cfg, background=False)
        ids, rate = ingest(mem, data, args.batch, pos)
        out["ingest_rows_per_s"] = rate
        t0 = time.perf_counter()
        mem.store.items.optimize()
        cfg.threshold = IndexConfig().threshold
        mem.store.build_indexes()
        out["index_build_s"] = time.perf_counter() - t0
        out["indexes"] = sorted(c for ix in mem.store.items.list_indices() for c in ix.columns)
        print(f"  ingest {rate:.0f} rows/s, indexes {out['index_build_s']:.0f}s", flush=True)
        # every query runs unfiltered and with each place filter in turn (interleaved), so
        # that load from other processes on a shared machine falls on all of them alike
        configs: dict[str, dict[str, Any]] = {"unfiltered": {}}
        truths = {"unfiltered": exact_topk(mem, data, ids, queries, None)}
        for name, radius in RADII:
            configs[name] = {"near": (CENTRE, radius)}
            mask = np.linalg.norm(pos - np.asarray(CENTRE), axis=1) <= radius
            truths[name] = exact_topk(mem, data, ids, queries, mask)
            out[name] = {"radius_m": radius, "allowed_rows": int(mask.sum()),
                         "selectivity": float(mask.mean())}  # fmt: skip
        lat: dict[str, list[float]] = {name: [] for name in configs}
        rec: dict[str, list[float]] = {name: [] for name in configs}
        for kw in configs.values():  # warm caches
            mem.search_vector(queries[0], k=K, **kw)
        for i, qv in enumerate(queries):
            for name, kw in configs.items():
                t0 = time.perf_counter()
                hits = mem.search_vector(qv, k=K, **kw)
                lat[name].append((time.perf_counter() - t0) * 1000)
                want = truths[name][i]
                rec[name].append(len({h.id for h in hits} & want) / max(1, min(K, len(want))))
        for name in configs:
            r = out.setdefault(name, {})
            r.update(p50_ms=pct(lat[name], 50), p95_ms=pct(lat[name], 95),
                     recall_at_10=float(np.mean(rec[name])))  # fmt: skip
        print(f"  unfiltered: p50 {out['unfiltered']['p50_ms']:.1f} ms", flush=True)
        for name, radius in RADII:
            r = out[name]
            r["p50_vs_unfiltered"] = r["p50_ms"] / out["unfiltered"]["p50_ms"]
            r.update(plan(mem, queries[0], Where().near((CENTRE, radius)).sql() or ""))
            print(f"  {name}: p50 {r['p50_ms']:.1f} ms ({r['p50_vs_unfiltered']:.2f}x), "
                  f"recall {r['recall_at_10']:.3f}, index {r['search_plan_uses_scalar_index']}",
                  flush=True)  # fmt: skip
        return out
    finally:
        shutil.rmtree(root, ignore_errors=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--rows", type=int, nargs="+", default=[1_000_000])
    ap.add_argument("--queries", type=int, default=100)
    ap.add_argument("--centroids", type=int, default=1000)
    ap.add_argument("--batch", type=int, default=10_000)
    ap.add_argument("--placement", choices=["uniform", "walk"], default="uniform")
    ap.add_argument("--tmp", default=None, help="where the stores are built (default: /tmp)")
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "places.json"))
    args = ap.parse_args()
    path = Path(args.out)
    merged = json.loads(path.read_text()) if path.exists() else {}
    for n in args.rows:
        t0 = time.perf_counter()
        res = run(n, args)
        res["total_s"] = time.perf_counter() - t0
        res["machine"] = {
            "cpus": os.cpu_count(),
            "platform": platform.platform(),
            "load_avg_end": os.getloadavg(),
        }
        res["placement"] = args.placement
        key = str(n) if args.placement == "uniform" else f"{n}-{args.placement}"
        merged[key] = res
        path.write_text(json.dumps(merged, indent=1) + "\n")
        print(f"wrote {path}", flush=True)


if __name__ == "__main__":
    main()
