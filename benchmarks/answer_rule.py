"""Which occurrences answer ``last``/``first``/``count`` (``search.matching.ANSWER_KEEP``), and
how the grasp default moves the match bar's rates: measured on held-out STAG recordings.

For each fold checkpoint given (the protocol's runs, trained without the fold's held-out
recordings), the fold's held-out recordings are streamed into a real memory (real LanceDB,
real MiniLM; ``touch/training/stream_eval.py``'s session: one recording per object, idle
windows not stored) and every natural query of ``stream_queries.json`` is asked:

* ``answer`` sweep: the occurrences past the bar (touch asked of grasps, the default, and of
  windows) are taken once (``answer=0``), then ``search.matching.answering`` cuts them at
  each ratio (the first score step down to less than ratio x the score above it);
  ``last`` is right when the latest kept occurrence overlaps the object's recording,
  ``count`` exact when it is 1 (0 for a class with no recording);
* the match bar on grasps vs windows: how often another object's grasp (window) passes
  bars 3, 4, 5 among the hits of a query, and how often the object's own does.

A notes scenario (real MiniLM, no touch) checks the rule where the issue found it wrong:
``last "picked up the mug"`` among near-miss notes written later.

    python benchmarks/answer_rule.py runs/protocol_gpu/shipped/A-s0.safetensors ... \\
        --data $STAG/weights_lite --data $STAG/blindfolded_lite_train \\
        --json benchmarks/results/answer_rule.json
"""

from __future__ import annotations

import argparse
import json
import os
import re
import tempfile
import time
from pathlib import Path

import numpy as np

ANSWERS = (0.0, 0.5, 0.75, 0.9)
BARS = (2.0, 2.5, 3.0, 4.0, 5.0)
THRESHOLDS = (2.5, 3.0)  # the match bar for last/count (threshold=)
GROUPS = ("auto", "auto-max", "window")  # auto-max: grasps scored by their best window


def combo(k: tuple) -> str:
    return "|".join(str(x) for x in k)


#: (note, t): the mug picked up at 10 s, then near misses that pass the bar later
NOTES = [
    ("picked up the mug", 10.0),
    ("picked up the cup from the shelf", 40.0),
    ("put the mug down on the table", 70.0),
    ("picked up the screwdriver", 100.0),
    ("washed the mug in the sink", 130.0),
    ("the operator said hello", 160.0),
]
NOTE_QUESTIONS = {"picked up the mug": 10.0, "picked up the screwdriver": 100.0}


def fold_of(path: Path) -> str:
    m = re.match(r"([AB])-s\d+", path.stem)
    if not m:
        raise SystemExit(f"{path}: expected a fold run named A-s<seed> or B-s<seed>")
    return m.group(1)


def touch_rows(ckpt: Path, data, memory_dir: Path) -> dict:
    from tactus_memory.adapters.touch import TactusEncoder
    from tactus_memory.matching import answering
    from tactus_memory.memory.main import Memory
    from tactus_memory.training.protocol import FOLDS
    from tactus_memory.training.stream_eval import SESSION, _store, build_stream, load_queries
    from tactus_memory.training.train import holdout_recordings

    stream = build_stream(data, holdout_recordings(data, FOLDS[fold_of(ckpt)]))
    queries = load_queries()
    mem = Memory.open(str(memory_dir), background=False)
    try:
        mem.add_sense(TactusEncoder(ckpt))
        idx = np.flatnonzero(~stream.idle)
        ids = _store(mem, stream, idx)
        where = dict(zip(ids, idx.tolist(), strict=True))
        present = set(stream.rec_object.values())
        ask = {"session": SESSION, "senses": ["touch"]}
        # (group, threshold, answer) -> per query: last right?, count exact?
        last = {(g, b, a): [] for g in GROUPS for b in THRESHOLDS for a in ANSWERS}
        exact = {(g, b, a): [] for g in GROUPS for b in THRESHOLDS for a in ANSWERS}
        passes = {g: {b: {"own": 0, "own_n": 0, "other": 0, "other_n": 0} for b in BARS}
                  for g in GROUPS}  # fmt: skip
        for cls, qs in queries.items():
            spans = [stream.spans[r] for r, c in stream.rec_object.items() if c == cls]
            truth = len(spans) if cls in present else 0
            for q in qs:
                for g in GROUPS:
                    group, _, how = g.partition("-")
                    pool = {"": "mean", "max": "max"}[how]
                    for b in THRESHOLDS:
                        occ = mem.occurrences(
                            q, answer=0.0, group=group, pool=pool, threshold=b, **ask
                        )
                        for a in ANSWERS:
                            kept = answering(occ.moments, a)
                            exact[(g, b, a)].append(float(len(kept) == truth))
                            if cls in present:
                                m = kept[-1] if kept else None
                                ok = m is not None and any(
                                    m.t <= e and m.t_end >= s for s, e in spans
                                )
                                last[(g, b, a)].append(float(ok))
                    for h in mem.search(q, k=50, group=group, pool=pool, **ask):
                        objs = {stream.obj[where[i]] for i in (h.ids or [h.id])}
                        own = objs == {cls}
                        for b in BARS:
                            key = "own" if own else "other"
                            passes[g][b][f"{key}_n"] += 1
                            passes[g][b][key] += int(h.score >= b)
        rates = {
            g: {
                str(b): {
                    "own_pass": v["own"] / max(1, v["own_n"]),
                    "other_pass": v["other"] / max(1, v["other_n"]),
                }
                for b, v in per.items()
            }
            for g, per in passes.items()
        }
        return {
            "checkpoint": str(ckpt),
            "fold": fold_of(ckpt),
            "queries": len(exact[(GROUPS[0], THRESHOLDS[0], ANSWERS[0])]),
            "last_correct": {combo(k): float(np.mean(v)) for k, v in last.items()},
            "count_exact": {combo(k): float(np.mean(v)) for k, v in exact.items()},
            "bar_rates": rates,
        }
    finally:
        mem.close()


def notes_rows(memory_dir: Path) -> dict:
    from tactus_memory.matching import answering
    from tactus_memory.memory.main import Memory

    mem = Memory.open(str(memory_dir), background=False)
    try:
        for text, t in NOTES:
            mem.add("notes", "text", text, t=t)
        out = {}
        for q, truth in NOTE_QUESTIONS.items():
            occ = mem.occurrences(q, session="notes", answer=0.0)
            out[q] = {
                "passed": [(m.t, round(m.score, 2)) for m in occ.moments],
                "last_t": {
                    str(a): (answering(occ.moments, a) or [None])[-1].t
                    if answering(occ.moments, a)
                    else None
                    for a in ANSWERS
                },
                "truth_t": truth,
            }
        return out
    finally:
        mem.close()


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("checkpoints", nargs="+", type=Path)
    ap.add_argument("--data", action="append", required=True)
    ap.add_argument("--json", type=Path, default=Path("benchmarks/results/answer_rule.json"))
    args = ap.parse_args()
    from tactus_memory.training.train import load_data

    data = load_data(args.data)
    t0 = time.time()
    with tempfile.TemporaryDirectory() as tmp:
        runs = [touch_rows(c, data, Path(tmp) / f"m{i}") for i, c in enumerate(args.checkpoints)]
        notes = notes_rows(Path(tmp) / "notes")
    keys = list(runs[0]["last_correct"])
    summary = {
        "keys": "group|threshold|answer",
        "last_correct_mean": {
            k: float(np.mean([r["last_correct"][k] for r in runs])) for k in keys
        },
        "count_exact_mean": {k: float(np.mean([r["count_exact"][k] for r in runs])) for k in keys},
    }
    out = {
        "summary": summary,
        "runs": runs,
        "notes": notes,
        "wall_s": round(time.time() - t0, 1),
        "load_avg": os.getloadavg(),
    }
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps(out, indent=1) + "\n")
    print(json.dumps({"summary": summary, "notes": notes}, indent=1))


if __name__ == "__main__":
    main()
