"""The demo checkpoint's held-out figures: what ``tactus demo`` prints beside its answers.

    python benchmarks/touch_demo.py [--checkpoint CKPT] [--out benchmarks/results/touch_demo.json]

The demo checkpoint (``tactus_memory/touch/checkpoints/tactus-lite-minilm-demo.safetensors``)
was trained with ``--holdout one-per-object@blindfolded`` (fold A of the protocol). Scored here
on exactly those 26 held-out recordings, which it never trained on (the stream evaluation's
leakage check must say ``clean``, or this script fails):

* tuple top-1: the fixed-seed 5-frame tuples of the held-out valid frames (``tactus eval``'s
  tuple evaluation), its 95 % t-interval over the 26 recordings' per-recording top-1;
* stream R@1 / R@5: the recordings laid end to end as one session in a real memory (real
  MiniLM, real LanceDB), natural questions asked, touch answered by grasp (``served_grasp``,
  the protocol's stream figures), 95 % t-interval over the 26 objects' per-object recall.

* precision at the bar: every question's top touch hit (a grasp, search's default), its score
  and whether it is the asked object; the rule of ``tactus_memory/training/bar_rule.py``: the
  precision of the hits past each bar of its sweep (95 % Wilson intervals), the lowest bar whose
  lower bound reaches its target (0.8), and the precision at the shipped grasp bar.
  ``--precision-only`` measures this part alone and updates it in the files below.

Writes the JSON to ``--out`` and the figures the demo prints to
``tactus_memory/touch/checkpoints/demo-heldout.json``. STAG: ``$TACTUS_STAG_DIR``.
"""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
HOLDOUT = "one-per-object@blindfolded"


def precision_at_bar(ckpt: Path, data: object) -> dict[str, object]:
    """Top touch hit per question over the held-out recordings (module docstring)."""
    import tempfile

    from tactus_memory.adapters.touch import TactusEncoder
    from tactus_memory.memory.main import Memory
    from tactus_memory.training.stream_eval import build_stream, load_queries
    from tactus_memory.training.train import holdout_recordings

    stream = build_stream(data, holdout_recordings(data, HOLDOUT))
    keep = np.flatnonzero(~stream.idle)
    present = set(stream.rec_object.values())
    tops: list[tuple[float, bool, bool, float]] = []  # (score, right, match, bar)
    with tempfile.TemporaryDirectory() as tmp:
        mem = Memory.open(str(Path(tmp) / "m"), background=False)
        mem.add_sense(TactusEncoder(ckpt))
        ids = mem.add_many(
            "day", "touch", list(stream.frames[keep]),
            t=stream.t[keep].tolist(), t_end=stream.t_end[keep].tolist(),
        )  # fmt: skip
        obj = {i: stream.obj[j] for i, j in zip(ids, keep, strict=True)}
        for cls, qs in load_queries().items():
            if cls not in present:
                continue
            for q in qs:
                h = mem.search(q, k=1, senses=["touch"], session="day")[0]
                members = {obj[i] for i in (getattr(h, "ids", None) or [h.id])}
                tops.append((h.score, members == {cls}, bool(h.match), float(h.bar)))
        mem.close()
    from tactus_memory.training.bar_rule import choose_bar

    chosen = choose_bar([t[0] for t in tops], [t[1] for t in tops], tops[0][3])
    chosen["matched"] = int(sum(t[2] for t in tops))  # flagged match by search: at the bar
    chosen["rows"] = [{"score": t[0], "right": t[1], "match": t[2]} for t in tops]
    return chosen


QUESTIONS = "stream_queries.json over the 26 held-out recordings (top grasp)"
MEASURED_ON = "this checkpoint's 26 held-out recordings"


def write_precision(ckpt: Path, bars: dict[str, object]) -> dict[str, object]:
    """The ``GET /senses`` row of ``ckpt`` into ``match-precision.json`` (beside it)."""
    from tactus_memory.hashing import file_sha256
    from tactus_memory.touch.checkpoint import MATCH_PRECISION
    from tactus_memory.training.bar_rule import senses_row

    row = senses_row(bars, QUESTIONS, MEASURED_ON)
    # the default checkpoint trained on every recording (no held-out recordings of its own, and
    # a longer recipe): none measured, so none written
    doc = {"source": "benchmarks/touch_demo.py", "precision_at_bar": {file_sha256(ckpt): row}}
    (Path(ckpt).parent / MATCH_PRECISION).write_text(json.dumps(doc, indent=1) + "\n")
    return row


def figure(values: list[float]) -> dict[str, float]:
    from tactus_memory.training.protocol_report import interval

    i = interval(values)
    return {"value": i["mean"], "lo": max(0.0, i["lo"]), "hi": min(1.0, i["hi"]), "n": i["n"]}


def tuple_top1(ckpt_path: Path, data: object) -> tuple[dict[str, float], dict[str, float]]:
    """(tuple top-1 with its interval over recordings, the eval summary)."""
    from tactus_memory.touch.checkpoint import load_checkpoint
    from tactus_memory.training.train import (
        EVAL_SEED,
        embed_windows,
        evaluate,
        holdout_recordings,
        prepare_data,
    )
    from tactus_memory.training.tuples import TupleSampler

    ck = load_checkpoint(ckpt_path)
    td = prepare_data(data, holdout_recordings(data, HOLDOUT))
    k = int(ck.meta["model"]["frames"])
    summary = evaluate(ck.model, ck.targets.centred, td, td.heldout_valid, k=k)
    sampler = TupleSampler(td.calibrated, td.recording_id, td.heldout_valid, k=k, seed=EVAL_SEED)
    idx = sampler.fixed(EVAL_SEED)  # the same tuples evaluate() scored
    z = embed_windows(ck.model, td.calibrated[idx])
    right = (z @ ck.targets.centred.T).argmax(axis=1) == td.labels[idx[:, 0]]
    rec = td.recording_id[idx[:, 0]]
    per_rec = [float(right[rec == r].mean()) for r in np.unique(rec)]
    fig = figure(per_rec)  # the mean over recordings; tuple_eval.top1 is the mean over tuples
    return fig, {k: v for k, v in summary.items() if k != "per_recording"}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--checkpoint", type=Path, default=None)
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks/results/touch_demo.json")
    ap.add_argument("--precision-only", action="store_true", help="the precision at the bar alone")
    args = ap.parse_args()
    from tactus_memory.touch.checkpoint import demo_checkpoint_path, heldout_recordings
    from tactus_memory.training.stream_eval import build_stream, evaluate_stream, load_queries
    from tactus_memory.training.train import holdout_recordings, load_data

    ckpt = args.checkpoint or demo_checkpoint_path()
    stag = Path(os.environ.get("TACTUS_STAG_DIR", ROOT.parent / "shared/data/stag"))
    data = load_data([stag / "weights_lite", stag / "blindfolded_lite_train"])
    if args.precision_only:
        bars = precision_at_bar(ckpt, data)
        row = write_precision(ckpt, bars)
        print("precision at bar", json.dumps(row), flush=True)
        out = json.loads(args.out.read_text())
        out["precision_at_bar"] = bars
        out["figures"]["precision_at_bar"] = row
        args.out.write_text(json.dumps(out, indent=1) + "\n")
        held = Path(ckpt).parent / "demo-heldout.json"
        figures = json.loads(held.read_text())
        figures["precision_at_bar"] = row
        held.write_text(json.dumps(figures, indent=1) + "\n")
        return
    top1, tuple_summary = tuple_top1(ckpt, data)
    print("tuple top-1", top1, flush=True)
    recs = holdout_recordings(data, HOLDOUT)
    res = evaluate_stream(
        ckpt, build_stream(data, recs), load_queries(), modes=("served",), groups=("grasp",),
        data_fingerprint=data.fingerprint(),
    )  # fmt: skip
    if res["leakage"]["status"] != "clean":
        raise SystemExit(f"the scored recordings are not held out: {res['leakage']}")
    g = res["served_grasp"]
    per_obj = g["per_class"].values()
    r1 = figure([c["r@1"] for c in per_obj])
    r5 = figure([c["r@5"] for c in per_obj])
    r1["value"], r5["value"] = g["r@1"], g["r@5"]  # over queries (the per-object mean's CI)
    bars = precision_at_bar(ckpt, data)
    row = write_precision(ckpt, bars)
    print("precision at bar", json.dumps(row), flush=True)
    from tactus_memory.touch.checkpoint import load_checkpoint

    meta = load_checkpoint(ckpt, weights=False).meta
    figures = {
        "checkpoint": Path(ckpt).name,
        "holdout": HOLDOUT,
        "recordings": len(heldout_recordings(meta)),
        "tuple_top1": top1,
        "stream_r1": r1,
        "stream_r5": r5,
        "stream_match_precision": g["match_precision"],
        "precision_at_bar": row,
        "queries": g["queries_scored"],
        "source": "benchmarks/touch_demo.py",
    }
    print(json.dumps(figures, indent=1), flush=True)
    out = {
        "what": __doc__.split("\n")[0],
        "command": "python benchmarks/touch_demo.py",
        "figures": figures,
        "train_args": meta["train_args"],
        "pretrained": meta["metrics"].get("pretrained"),
        "steps": meta["steps"],
        "tuple_eval": tuple_summary,
        "precision_at_bar": bars,
        "stream": {k: v for k, v in res.items() if k != "served_grasp"}
        | {"served_grasp": {k: v for k, v in g.items() if k != "per_class"}},
    }
    args.out.write_text(json.dumps(out, indent=1) + "\n")
    (Path(ckpt).parent / "demo-heldout.json").write_text(json.dumps(figures, indent=1) + "\n")


if __name__ == "__main__":
    main()
