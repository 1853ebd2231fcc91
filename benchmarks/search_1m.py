"""Search at 1M rows on realistic data: which ANN index, with which parameters.

Rows: :mod:`realistic_vectors` (real MiniLM note embeddings and real STAG windows embedded
by the shipped touch encoder as anchors, covariance-shaped noise with the real embeddings'
nearest-neighbour spread); queries: MiniLM embeddings of question texts. For each index
spec (type, rows per IVF partition) a copy of one bulk-loaded store gets that index; the
search settings (nprobes, refine factor, ef) are swept on separate tuning queries, the
fastest with recall@10 >= ``--target`` is kept, and the chosen settings of every spec are
then timed back to back (A/B, ``--repeats`` rounds) on the held-out queries, each beside
the settings the index chose for itself when it was built (``as_built``: the probes it
measured, StoreIndexes.probes; what a user gets). Filtered
searches (session, sense, time, session + time) are timed with their recall and LanceDB's
plan (a scalar-index prefilter, not a scan). ``--http`` also starts ``tactus serve`` on
the store of the first spec and times ``GET /search?q=...`` (MiniLM query embedding
included; every query text distinct, so the query cache never answers).

Stores and data are cached in ``--cache`` (outside git; ~2 GB per index spec) and reused.
The 2 cores are shared: the 1-minute load average is recorded next to every timing.

    python benchmarks/search_1m.py --specs IVF_SQ:4096 IVF_SQ:1024 --http
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
import time
from pathlib import Path
from typing import Any

import httpx
import numpy as np

import realistic_vectors as rv
from memory import exact_topk, ingest, measure, pct, tune
from places import plan
from serving import free_port, start_serve, stop_process, wait_ok
from tactus_memory.adapters.vectors import VectorSense
from tactus_memory.memory.main import Memory
from tactus_memory.query import Scope
from tactus_memory.search.ranking import Ranker
from tactus_memory.storage.codes import coded_query
from tactus_memory.storage.tables import IndexConfig

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results" / "search_1m.json"
K = 10
#: search settings tried per index type (nprobes x refine_factor [x ef]); IVF probes are for
#: 244 partitions (4096 rows each at 1M) and scale with a spec's partitions (``grid``)
GRIDS: dict[str, list[dict[str, Any]]] = {
    "IVF_SQ": [
        {"nprobes": p, "ef": None, "refine_factor": r}
        for p in (10, 20, 40, 64, 80, 96)
        for r in (None, 2, 5)
    ],
    "IVF_PQ": [
        {"nprobes": p, "ef": None, "refine_factor": r}
        for p in (10, 20, 40, 80)
        for r in (5, 10, 20)
    ],
    "IVF_RQ": [
        {"nprobes": p, "ef": None, "refine_factor": r}
        for p in (24, 40, 64, 80, 96)
        for r in (5, 10, 20)
    ],
    "IVF_HNSW_SQ": [
        {"nprobes": p, "ef": ef, "refine_factor": r}
        for p in (2, 4, 8, 16)
        for ef in (64, 150)
        for r in (None, 4)
    ],
}


def grid(kind: str, partitions: int) -> list[dict[str, Any]]:
    """GRIDS[kind] with its IVF probes scaled from 244 partitions to ``partitions``."""
    if kind.startswith("IVF_HNSW"):
        return GRIDS[kind]
    scale = partitions / 244
    return [{**g, "nprobes": min(partitions, round(g["nprobes"] * scale))} for g in GRIDS[kind]]


def load1() -> float:
    return round(os.getloadavg()[0], 2)


def open_store(path: Path, cfg: IndexConfig) -> Memory:
    mem = Memory.open(str(path), space="minilm-l6", index=cfg, background=False)
    for s in rv.SENSES:
        if s not in mem.senses:
            mem.add_sense(VectorSense(s, dim=rv.DIM))
    return mem


def base_store(cache: Path, data: dict[str, Any], batch: int) -> tuple[Path, np.ndarray]:
    """The bulk-loaded, compacted store with its scalar indexes (no ANN index), cached."""
    n = len(data["vectors"])
    path, ids_path = cache / f"store-{n}-base", cache / f"ids-{n}.npy"
    if not ids_path.exists():
        shutil.rmtree(path, ignore_errors=True)
        mem = open_store(path, IndexConfig(threshold=10**12, scalar_threshold=10**12))
        ids, rate = ingest(mem, data, batch, senses=rv.SENSES)
        mem.store.items.optimize()
        mem.store.build_scalar_indexes()
        mem.close()
        print(f"  loaded {n} rows at {rate:.0f} rows/s", flush=True)
        np.save(ids_path, ids.astype(str))
    return path, np.load(ids_path)


def spec_store(cache: Path, base: Path, n: int, kind: str, rows_per_part: int) -> dict[str, Any]:
    """A copy of the base store with the ANN index ``kind`` built on it (cached)."""
    path = cache / f"store-{n}-{kind}-{rows_per_part}"
    info_path = path / "bench-index.json"
    if not info_path.exists():
        shutil.rmtree(path, ignore_errors=True)
        shutil.copytree(base, path)
        cfg = IndexConfig(index_type=kind, rows_per_partition=rows_per_part, threshold=10**12)
        mem = open_store(path, cfg)
        # a store that has been searched holds the text probe bank (the score calibration's
        # queries), which the index's own probe measurement asks (StoreIndexes.probes)
        mem.search("something on the table", k=1)
        load = load1()
        t0 = time.perf_counter()
        mem.store.build_indexes()
        info = {
            "build_s": time.perf_counter() - t0,
            "load_1min_at_start": load,
            "partitions": mem.store.partitions(),
            # the probes the index chose for itself when built (measured recall, no sweep)
            "measured": json.loads(mem.store.get_meta("index") or "{}"),
        }
        mem.close()
        info_path.write_text(json.dumps(info))
        print(f"  built {kind} ({rows_per_part} rows/partition): {info}", flush=True)
    return {"path": path, **json.loads(info_path.read_text())}


def remeasure(info: dict[str, Any], kind: str, rows_per_part: int) -> None:
    """Measure the probes of a cached spec's index again (StoreIndexes.measure_probes, as
    a build does) and record them in its store and bench-index.json."""
    cfg = IndexConfig(index_type=kind, rows_per_partition=rows_per_part, threshold=10**12)
    mem = open_store(info["path"], cfg)
    t0 = time.perf_counter()
    measured = mem.store.measure_probes()
    record = json.loads(mem.store.get_meta("index") or "{}")
    record.update(measured, ladder={str(p): r for p, r in measured["ladder"].items()})
    mem.store.set_meta("index", json.dumps(record))
    mem.close()
    info["measured"] = record
    info["remeasured_s"] = time.perf_counter() - t0
    saved = {k: v for k, v in info.items() if k != "path"}
    (info["path"] / "bench-index.json").write_text(json.dumps(saved))
    print(f"  remeasured {kind}:{rows_per_part}: {record}", flush=True)


def filters(data: dict[str, Any]) -> dict[str, tuple[dict[str, Any], np.ndarray]]:
    """name -> (search_vector keyword filters, the row mask they allow)."""
    day = 86_400.0
    t0, t1 = 10 * day, 11 * day
    in_day = (data["t"] >= t0) & (data["t"] < t1)
    s3 = data["session"] == 3
    return {
        "session": ({"session": "s3"}, s3),
        "sense": ({"senses": ["notes"]}, data["sense"] == 1),
        "time_1_day": ({"after": t0, "before": t1}, in_day),
        "session_and_week": (
            {"session": "s3", "after": t0, "before": t0 + 7 * day},
            s3 & (data["t"] >= t0) & (data["t"] < t0 + 7 * day),
        ),
    }


def filtered(mem: Memory, data: dict[str, Any], ids: np.ndarray, q: np.ndarray) -> dict[str, Any]:
    """Each filter's p50/p95/recall beside the unfiltered search on the same queries, timed
    just before it (``ratio_p50``: filtered over unfiltered p50)."""
    out = {}
    truth = exact_topk(mem, data, ids, q, None, senses=rv.SENSES)
    for name, (kw, mask) in filters(data).items():
        truth = exact_topk(mem, data, ids, q, mask, senses=rv.SENSES)
        base = measure(mem, q, truth)
        r = measure(mem, q, truth, **kw)
        r["unfiltered_p50_ms"] = base["p50_ms"]
        r["ratio_p50"] = round(r["p50_ms"] / base["p50_ms"], 2)
        scope = Scope.of(**kw)
        sql = scope.where().senses(scope.senses).sql() or ""
        p = plan(mem, q[0], sql)
        r.update(
            {
                "allowed_rows": int(mask.sum()),
                "load_1min": load1(),
                "plan_uses_scalar_index": p["search_plan_uses_scalar_index"],
                "count_uses_scalar_index": p["scan_plan_uses_scalar_index"],
                "search_plan": p["search_plan"],
            }
        )
        out[name] = r
        print(
            f"    {name}: p50 {r['p50_ms']:.1f} p95 {r['p95_ms']:.1f} ms (x{r['ratio_p50']} of "
            f"unfiltered), recall {r['recall_at_10']:.3f}, scalar index "
            f"{r['plan_uses_scalar_index']}",
            flush=True,
        )
    return out


def split_vs_shared(
    mem: Memory, q: np.ndarray, truth: list[set[str]], repeats: int, settings: dict[str, Any]
) -> dict[str, Any]:
    """The per-sense queries (each sense at its own probes, at once: ``Ranker.split_senses``)
    against the shared query with its follow-ups (before), back to back on one store, at
    ``settings`` (the index's own probes)."""
    for key, val in settings.items():
        setattr(mem.store.index, key, val)
    out: dict[str, Any] = {"split": [], "shared": []}
    try:
        for r in range(repeats):
            for label, split in (("split", True), ("shared", False)):
                Ranker.split_senses = split
                m = {**measure(mem, q, truth), "load_1min": load1()}
                out[label].append(m)
                print(
                    f"  round {r} {label}: p50 {m['p50_ms']:.2f} p95 {m['p95_ms']:.2f} ms "
                    f"recall {m['recall_at_10']:.3f} load {m['load_1min']}",
                    flush=True,
                )
    finally:
        Ranker.split_senses = True
    return out


def where_time_goes(mem: Memory, q: np.ndarray) -> dict[str, Any]:
    """p50 ms of one library search and of its parts, at the store's search settings: the
    ANN queries it issues (counted), one such query with the hit columns, and LanceDB alone
    (ids only), with and without the refine step."""
    store, cfg = mem.store, mem.store.index
    calls = [0]
    inner = store.vector_search

    def counted(*a: Any, **kw: Any) -> Any:
        calls[0] += 1
        return inner(*a, **kw)

    def p50(fn: Any) -> float:
        fn(q[0])
        lat = []
        for v in q:
            t0 = time.perf_counter()
            fn(v)
            lat.append((time.perf_counter() - t0) * 1000)
        return round(pct(lat, 50), 2)

    def lance(v: np.ndarray, refine: int | None) -> Any:
        v = coded_query(v, None, store.codes())  # as stored: with the code columns
        s = store.items.search(v, vector_column_name="vector").distance_type("cosine")
        s = s.nprobes(min(store.probes(), store.partitions()))
        return (s.refine_factor(refine) if refine else s).select(["id"]).limit(2 * K).to_arrow()

    store.vector_search = counted  # type: ignore[method-assign]
    try:
        search = p50(lambda v: mem.search_vector(v, k=K))
    finally:
        del store.vector_search
    n = store.count()
    return {
        "settings": {
            "nprobes": store.probes(),
            "nprobes_by_sense": {s: store.probes([s]) for s in rv.SENSES},
            "refine_factor": cfg.refine_factor,
        },
        "search_vector_p50_ms": search,
        "ann_queries_per_search": calls[0] / (len(q) + 1),
        "one_ann_query_with_hit_columns_p50_ms": p50(
            lambda v: store.vector_search(v, 2 * K, None, allowed=n, total=n)
        ),
        "lancedb_ids_only_p50_ms": p50(lambda v: lance(v, cfg.refine_factor)),
        "lancedb_ids_only_no_refine_p50_ms": p50(lambda v: lance(v, None)),
        "load_1min": load1(),
    }


def compare_layouts(
    args: argparse.Namespace,
    real: dict[str, np.ndarray],
    data: dict[str, Any],
    first: str,
    built: dict[str, dict[str, Any]],
    ids: np.ndarray,
) -> dict[str, Any]:
    """The store of ``first`` (sense codes) against the same spec's store in ``--compare``
    (a cache made before sense codes, its own ids), each as built (the probes it measured
    for itself), interleaved for ``--repeats`` rounds on the held-out queries; with
    ``--http`` also ``GET /search`` on each, interleaved alike."""
    kind, rows_per_part = first.split(":")
    cfg = IndexConfig(index_type=kind, rows_per_partition=int(rows_per_part), threshold=10**12)
    old_ids = np.load(args.compare / f"ids-{args.rows}.npy")
    old_path = args.compare / f"store-{args.rows}-{kind}-{rows_per_part}"
    stores = {"codes": (built[first]["path"], ids), "before": (old_path, old_ids)}
    q = real["queries"]
    out: dict[str, Any] = {"spec": first, "before_cache": str(args.compare)}
    truth: dict[str, list[set[str]]] = {}
    for label, (path, its_ids) in stores.items():
        mem = open_store(path, cfg)
        truth[label] = exact_topk(mem, data, its_ids, q, None, senses=rv.SENSES)
        out[label] = {
            "codes": mem.store.codes(),
            "nprobes_by_sense": {s: mem.store.probes([s]) for s in rv.SENSES},
            "rounds": [],
            "http": [],
        }
        mem.close()
    for r in range(args.repeats):
        for label, (path, _) in stores.items():
            mem = open_store(path, cfg)
            measure(mem, q[:20], None)  # warm the index cache
            m = {**measure(mem, q, truth[label]), "load_1min": load1()}
            out[label]["rounds"].append(m)
            mem.close()
            print(f"  round {r} {label}: {m}", flush=True)
        if args.http:
            for label, (path, _) in stores.items():
                h = http_search(path, 100, args.cache / "serve.log")
                out[label]["http"].append(h)
                print(f"  http round {r} {label}: {h}", flush=True)
    diffs = [
        a["p50_ms"] - b["p50_ms"]
        for a, b in zip(out["codes"]["rounds"], out["before"]["rounds"], strict=True)
    ]
    out["paired_p50_diff_ms"] = diffs
    return out


def http_search(store: Path, n_queries: int, log: Path, *extra: str) -> dict[str, Any]:
    """p50/p95 of GET /search?q=... on ``tactus serve --data store *extra`` (distinct texts)."""
    port = free_port()
    base = f"http://127.0.0.1:{port}"
    proc = start_serve(port, store, log, *extra)
    try:
        if wait_ok(proc, base + "/ready", 300, interval=0.2) is None:
            sys.exit(f"the server did not get ready:\n{log.read_text()[-2000:]}")
        texts = rv.query_texts(n_queries + 10, seed=3)
        texts = [f"{t} #{i}" for i, t in enumerate(texts)]  # distinct: no query-cache hits
        lat = []
        with httpx.Client(base_url=base, timeout=60) as c:
            for i, text in enumerate(texts):
                t0 = time.perf_counter()
                c.get("/search", params={"q": text, "k": K}).raise_for_status()
                if i >= 10:  # the first ten warm the server
                    lat.append((time.perf_counter() - t0) * 1000)
    finally:
        stop_process(proc)
    return {"p50_ms": pct(lat, 50), "p95_ms": pct(lat, 95), "n": len(lat), "load_1min": load1()}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--rows", type=int, default=1_000_000)
    specs_help = "TYPE:ROWS_PER_PARTITION index specs, built and swept in turn"
    ap.add_argument("--specs", nargs="+", default=["IVF_SQ:4096"], help=specs_help)
    # the cache (1.6 GB of rows, ~2 GB per index) in the checkout's ignored runs/ folder
    ap.add_argument("--cache", type=Path, default=ROOT / "runs" / "bench1m")
    stag = Path(os.environ.get("TACTUS_STAG_DIR", ROOT.parent / "shared/data/stag"))
    ap.add_argument("--stag", type=Path, default=stag / "blindfolded_lite_train")
    ap.add_argument("--queries", type=int, default=200, help="held-out (and tuning) queries")
    ap.add_argument("--target", type=float, default=0.98, help="recall@10 to tune for")
    ap.add_argument("--repeats", type=int, default=3, help="A/B rounds of the chosen settings")
    ap.add_argument("--batch", type=int, default=20_000)
    ap.add_argument("--build-only", action="store_true")
    ap.add_argument("--remeasure", action="store_true", help="measure cached indexes' probes")
    ap.add_argument("--http", action="store_true", help="time /search on the first spec")
    ap.add_argument("--onnx", type=Path, help="also time /search on `tactus serve --onnx DIR`")
    ap.add_argument("--only-http", action="store_true", help="skip the library measurements")
    ap.add_argument("--out", type=Path, default=RESULTS)
    ap.add_argument("--filtered-only", action="store_true", help="only the filtered searches")
    compare_help = "a --cache made before sense codes: time its store against the first spec's"
    ap.add_argument("--compare", type=Path, help=compare_help)
    args = ap.parse_args()

    t_all = time.perf_counter()
    real = rv.profile(args.cache, args.stag, 2800, 2000, args.queries)
    data = rv.rows(args.cache, args.rows, real)
    base, ids = base_store(args.cache, data, args.batch)
    specs = [(s.split(":")[0], int(s.split(":")[1])) for s in args.specs]
    built = {f"{k}:{r}": spec_store(args.cache, base, args.rows, k, r) for k, r in specs}
    if args.remeasure:
        for (k, r), info in zip(specs, built.values(), strict=True):
            remeasure(info, k, r)
    if args.build_only:
        return
    result: dict[str, Any] = {
        "rows": args.rows,
        "data": {
            "senses": dict(zip(rv.SENSES, rv.SENSE_P, strict=True)),
            "sessions": rv.N_SESSIONS,
            "spread": data["spread"],
            "queries": "MiniLM embeddings of question texts",
        },
        "target_recall_at_10": args.target,
    }
    run: dict[str, Any] = {
        "args": vars(args),
        "cpus": os.cpu_count(),
        "load_avg_start": os.getloadavg(),
    }
    first = next(iter(built))
    if args.compare:
        result["codes_vs_before"] = compare_layouts(args, real, data, first, built, ids)
        args.http = False  # timed within the comparison
    elif args.filtered_only:
        kind, rows_per_part = first.split(":")
        cfg = IndexConfig(index_type=kind, rows_per_partition=int(rows_per_part), threshold=10**12)
        mem = open_store(built[first]["path"], cfg)
        q = real["queries"][:100]
        result["filtered"] = {"spec": first, **filtered(mem, data, ids, q)}
        result["where_time_goes"] = {"spec": first, **where_time_goes(mem, q)}
        mem.close()
    elif not args.only_http:
        result.update(library(args, real, data, ids, built))
    if args.http:
        log = args.cache / "serve.log"
        # `tactus serve` as started (ONNX Runtime, the default server), and --onnx DIR
        runs: dict[str, Any] = {"spec": first, "default": [], "onnx": []}
        for r in range(args.repeats):
            runs["default"].append(http_search(built[first]["path"], 100, log))
            if args.onnx:
                onnx = ("--onnx", str(args.onnx))
                runs["onnx"].append(http_search(built[first]["path"], 100, log, *onnx))
            print(f"  http round {r}: {runs['default'][-1]} {(runs['onnx'] or [None])[-1]}")
        result["http_search"] = runs
    run["load_avg_end"] = os.getloadavg()
    run["total_s"] = time.perf_counter() - t_all
    # merge into the file: specs by name, the latest filtered/http figures, every run's args
    merged = json.loads(args.out.read_text()) if args.out.exists() else {}
    merged.setdefault("specs", {}).update(result.pop("specs", {}))
    merged.update(result)
    merged.setdefault("runs", []).append(json.loads(json.dumps(run, default=str)))
    args.out.write_text(json.dumps(merged, indent=2, default=str) + "\n")
    print(f"wrote {args.out}")


def library(
    args: argparse.Namespace,
    real: dict[str, np.ndarray],
    data: dict[str, Any],
    ids: np.ndarray,
    built: dict[str, dict[str, Any]],
) -> dict[str, Any]:
    """Sweep each spec on the tuning queries, time the chosen settings back to back on the
    held-out ones, and the filtered searches on the first spec."""
    q, tq = real["queries"], real["tune_queries"]
    specs: dict[str, Any] = {}
    mems: dict[str, Memory] = {}
    truth = tune_truth = None
    for name, info in built.items():
        kind, rows_per_part = name.split(":")
        cfg = IndexConfig(index_type=kind, rows_per_partition=int(rows_per_part), threshold=10**12)
        mem = mems[name] = open_store(info["path"], cfg)
        if truth is None:
            truth = exact_topk(mem, data, ids, q, None, senses=rv.SENSES)
            tune_truth = exact_topk(mem, data, ids, tq, None, senses=rv.SENSES)
        print(f"== {name}", flush=True)
        chosen, sweep = tune(mem, tq, tune_truth, grid(kind, info["partitions"]), args.target)
        print(f"  chosen {chosen}", flush=True)
        specs[name] = {
            **{k: v for k, v in info.items() if k != "path"},
            "chosen": chosen,
            "sweep": sweep,
            "load_1min_after_sweep": load1(),
        }
    # what a user gets: the probes the index measured for itself, the default refine
    as_built = {"nprobes": None, "ef": None, "refine_factor": IndexConfig().refine_factor}
    for r in range(args.repeats):  # the chosen settings and the index's own, back to back
        for name, mem in mems.items():
            for label, values in (("held_out", specs[name]["chosen"]), ("as_built", as_built)):
                for key, val in values.items():
                    setattr(mem.store.index, key, val)
                m = {**measure(mem, q, truth), "load_1min": load1()}
                m["nprobes"] = mem.store.probes()
                m["nprobes_by_sense"] = {s: mem.store.probes([s]) for s in rv.SENSES}
                specs[name].setdefault(label, []).append(m)
                print(
                    f"  round {r} {name} {label}: p50 {m['p50_ms']:.2f} p95 {m['p95_ms']:.2f} ms "
                    f"recall {m['recall_at_10']:.3f} nprobes {m['nprobes']} load {m['load_1min']}",
                    flush=True,
                )
            for key, val in specs[name]["chosen"].items():
                setattr(mem.store.index, key, val)
    first = next(iter(mems))
    split_ab = split_vs_shared(mems[first], q, truth, args.repeats, as_built)
    print(f"== filtered ({first})", flush=True)
    out = {
        "split_vs_shared": {"spec": first, **split_ab},
        "specs": specs,
        "filtered": {"spec": first, **filtered(mems[first], data, ids, q[:100])},
        "where_time_goes": {"spec": first, **where_time_goes(mems[first], q[:100])},
    }
    print(f"  where the time goes: {out['where_time_goes']}", flush=True)
    for mem in mems.values():
        mem.close()
    return out


if __name__ == "__main__":
    main()
