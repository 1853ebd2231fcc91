"""One hold, one answer: the grasp cut measured against the protocol's known holds.

    python benchmarks/grasp_holds.py [--checkpoint CKPT] [--out benchmarks/results/grasp_holds.json]

Data: the protocol's fold A (``blindfolded_lite_train``; the default checkpoint, the shipped demo
one, was trained with ``--holdout one-per-object@blindfolded``): the held-out recording of each
of 26 objects (never trained on), laid end to end by the stream windowing
(``stream_eval.build_stream``; idle windows are not stored). Each recording is one KNOWN HOLD:
one object held (STAG labels a whole recording with its object). Two layouts:

* ``protocol``: recordings ``stream_eval.RECORDING_GAP_S`` (10 s) apart, the protocol's day;
* ``abutting``: the same recordings with no gap between them (each one's own idle frames are the
  only release between two objects): the stress case for purity.

Per cut rule (:class:`~tactus_memory.search.holds.HoldRule`: the rule before issue 46,
``max_gap`` 0.5 s, the shipped one and a sweep), :func:`~tactus_memory.search.holds.cut_quality`
against the known holds: ``purity`` (share of grasps from one hold), ``completeness`` (share of
holds in one grasp), grasps, single-window grasps; 95 % bootstrap intervals (completeness
resampling holds, purity resampling grasps).

Stream retrieval per rule (``protocol`` layout): the natural questions of
``touch/training/queries/stream_queries.json`` (none a training template), each turned into the
touch query vector the memory searches with (its space, the sense's query transform), every
grasp of the day ranked by its pooled (mean) vector as ``search(group="auto")`` ranks them
(exhaustively here, not through the ANN candidates); a grasp is right when all its windows come
from the named object's hold. R@1/R@5: mean per object over its phrasings, then over the 26
objects; 95 % intervals by bootstrap over the holds (objects, 2,000 resamples), the paired
difference against the rule before issue 46 likewise. ``oracle``: one grasp per known hold (the
mean of its windows), the upper reference the issue quotes. ``search_check``: the same R@5
through ``memory.search`` (real LanceDB, real MiniLM) with the shipped rule.
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
#: (max_gap, min_cos) rules scored; the first is the cut before issue 46
RULES = ((0.5, 0.2), (0.75, 0.2), (1.0, 0.2), (1.5, 0.2), (2.0, 0.2), (0.75, -1.0))
BOOTSTRAP = 2000
SEED = 0


def boot(per: np.ndarray, base: np.ndarray | None = None) -> dict[str, float]:
    """Mean of per-hold values (n,) with a 95 % bootstrap interval over holds; with ``base``,
    of the paired difference per - base."""
    x = per if base is None else per - base
    rng = np.random.default_rng(SEED)
    means = x[rng.integers(0, len(x), size=(BOOTSTRAP, len(x)))].mean(axis=1)
    lo, hi = np.quantile(means, [0.025, 0.975])
    return {"value": float(x.mean()), "lo": float(lo), "hi": float(hi), "n": len(x)}


def cut_intervals(labels: np.ndarray, truth: np.ndarray) -> dict[str, dict[str, float]]:
    """95 % bootstrap intervals of the cut's completeness (per known hold: in one grasp;
    resampling holds) and purity (per grasp: from one hold; resampling grasps)."""
    whole = np.array([len(np.unique(labels[truth == h])) == 1 for h in np.unique(truth)], float)
    pure = np.array([len(np.unique(truth[labels == g])) == 1 for g in np.unique(labels)], float)
    return {"completeness": boot(whole), "purity": boot(pure)}


def rank_scores(groups: np.ndarray, truth: np.ndarray, vecs: np.ndarray, queries, objects):
    """Per object: (R@1, R@5) means over its phrasings, grasps ranked by pooled cosine."""
    ids = np.unique(groups)
    pooled = np.stack([vecs[groups == g].mean(axis=0) for g in ids])
    pooled /= np.linalg.norm(pooled, axis=1, keepdims=True)
    owner = [set(truth[groups == g]) for g in ids]
    r1, r5 = [], []
    for obj in objects:
        qv = queries[obj]  # (P, D) one row per phrasing
        order = np.argsort(-(qv @ pooled.T), axis=1, kind="stable")
        right = np.array([[owner[j] == {obj} for j in row[:5]] for row in order])
        r1.append(right[:, 0].mean())
        r5.append(right.any(axis=1).mean())
    return np.array(r1), np.array(r5)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--stag", help="STAG folder (default: the data home's stag/)")
    ap.add_argument("--checkpoint", help="touch checkpoint (default: the shipped demo one)")
    ap.add_argument("--out", default=str(ROOT / "benchmarks/results/grasp_holds.json"))
    args = ap.parse_args()

    from tactus_memory.adapters.touch import TactusEncoder
    from tactus_memory.datasets.home import data_home
    from tactus_memory.memory.main import Memory
    from tactus_memory.search.holds import (
        HOLD_MAX_GAP,
        HOLD_MIN_COS,
        HoldRule,
        cut_quality,
        hold_labels,
    )
    from tactus_memory.touch.checkpoint import demo_checkpoint_path, heldout_recordings
    from tactus_memory.training import stream_eval
    from tactus_memory.training.data import load_stag

    started = time.perf_counter()
    stag = Path(args.stag) if args.stag else data_home().stag
    data = load_stag(stag / "blindfolded_lite_train")
    enc = TactusEncoder(args.checkpoint or demo_checkpoint_path())
    held = set(heldout_recordings(enc.ckpt.meta))
    recs = sorted(int(r) for r in np.unique(data.recording_id) if data.recordings[r] in held)
    out: dict = {
        "what": __doc__.split("\n")[0],
        "command": "python benchmarks/grasp_holds.py",
        "checkpoint": enc.ckpt.path.name,
        "holds": len(recs),
        "held_out": all(data.recordings[r] in held for r in recs),
        "shipped_rule": {"max_gap": HOLD_MAX_GAP, "min_cos": HOLD_MIN_COS},
        "before_rule": {"max_gap": RULES[0][0], "min_cos": RULES[0][1]},
    }
    all_q = stream_eval.load_queries()
    layouts = {}
    with tempfile.TemporaryDirectory() as tmp:
        mem = Memory.open(str(Path(tmp) / "m"), background=False)
        mem.add_sense(enc)
        for layout, gap in (("protocol", stream_eval.RECORDING_GAP_S), ("abutting", 0.0)):
            saved = stream_eval.RECORDING_GAP_S
            stream_eval.RECORDING_GAP_S = gap  # build_stream lays recordings this far apart
            try:
                s = stream_eval.build_stream(data, recs)
            finally:
                stream_eval.RECORDING_GAP_S = saved
            keep = np.flatnonzero(~s.idle)
            layouts[layout] = (s, keep, enc.embed(list(s.frames[keep])))
        s, keep, vecs = layouts["protocol"]
        objects = sorted(set(s.rec_object.values()) & set(all_q))
        queries = {}
        for obj in objects:
            qv = np.asarray(mem.space.embed_texts(all_q[obj], query=True), np.float32)
            queries[obj] = np.asarray(mem.ranker.query_for(qv, "touch"), np.float32)
        truth_obj = np.array(s.obj)[keep]
        out["windows"] = len(keep)
        out["questions"] = sum(len(all_q[o]) for o in objects)
        # the shipped rule through the memory's own search path (a cross-check of the ranking)
        mem.add_many(
            "day", "touch", list(s.frames[keep]),
            t=s.t[keep].tolist(), t_end=s.t_end[keep].tolist(),
            meta=[{"object": o} for o in truth_obj],
        )  # fmt: skip
        hit5 = []
        for obj in objects:
            per = []
            for q in all_q[obj]:
                hits = mem.search(q, k=5, senses=["touch"], session="day")
                per.append(any({mem.get_item(i).meta["object"] for i in h.ids} == {obj}
                               for h in hits))  # fmt: skip
            hit5.append(np.mean(per))
        out["search_check"] = {"rule": "shipped", "r5": boot(np.array(hit5))}
        mem.close()
    truth_rec = np.array(s.recording)[keep]
    base1 = base5 = None
    rules = {}
    for max_gap, min_cos in RULES:
        rule = HoldRule(max_gap, min_cos)
        key = f"max_gap={max_gap:g},min_cos={min_cos:g}"
        entry: dict = {}
        for layout, (ls, lkeep, lvecs) in layouts.items():
            lab = hold_labels(ls.t[lkeep], ls.t_end[lkeep], lvecs, rule)
            truth = np.array(ls.recording)[lkeep]
            entry[layout] = cut_quality(lab, truth).__dict__
            entry[layout]["intervals"] = cut_intervals(lab, truth)
        lab = hold_labels(s.t[keep], s.t_end[keep], vecs, rule)
        r1, r5 = rank_scores(lab, truth_obj, vecs, queries, objects)
        if base1 is None:
            base1, base5 = r1, r5
        entry["r1"], entry["r5"] = boot(r1), boot(r5)
        entry["r1_minus_before"], entry["r5_minus_before"] = boot(r1, base1), boot(r5, base5)
        rules[key] = entry
        print(key, json.dumps({k: entry[k] for k in ("protocol", "abutting")}), flush=True)
        print("   r1", entry["r1"]["value"], "r5", entry["r5"]["value"], flush=True)
    out["rules"] = rules
    codes = {r: i for i, r in enumerate(sorted(set(truth_rec)))}
    oracle = np.array([codes[r] for r in truth_rec])
    r1, r5 = rank_scores(oracle, truth_obj, vecs, queries, objects)
    out["oracle_one_grasp_per_known_hold"] = {"r1": boot(r1), "r5": boot(r5)}
    out["wall_s"] = round(time.perf_counter() - started, 1)
    Path(args.out).write_text(json.dumps(out, indent=1) + "\n")
    print(json.dumps({k: out[k] for k in ("search_check", "oracle_one_grasp_per_known_hold")}))


if __name__ == "__main__":
    main()
