"""Inference-side rungs of the touch ladder (issue 13): what changes at query or embed time.

    python benchmarks/touch_inference_ladder.py CKPT [CKPT ...] \
        [--out benchmarks/results/touch_inference_ladder.json]

Over the stream of the 26 held-out blindfolded recordings
(``touch/training/stream_eval.build_stream``, the same windows as ``tactus eval --stream``),
the natural queries embedded by MiniLM, and the
non-idle windows (what the memory stores), scores text -> touch R@1 / R@5 / MRR in numpy.
Ranking one sense by cosine is exactly the memory's ranking (its z-score is monotonic in
cosine within a sense), so ``plain`` reproduces the stream evaluation's served figures.
Variants (each applied to every checkpoint; the checkpoints' scores are averaged):

* ``query_snap``: the (centred) query replaced by a softmax mixture of the class targets
  (a text-side ensemble that snaps paraphrases onto the trained phrases), tau 0.05 / 0.1;
* ``window_snap``: each window's embedding replaced by its softmax mixture of class targets;
* ``csls3``: hubness correction, score = 2 cos(q, z) - mean of z's 3 best class cosines;
* ``tta_shift``: window embedding averaged over the window and its four 1-px shifts;
* ``smooth_causal_M``: window embedding averaged with the previous M-1 stored windows of its
  recording (what a live stream could do);
* ``ensemble``: all checkpoints given, scores averaged (a seed ensemble).

Also where the touch side fails: each checkpoint's class top-1 over the stored windows, split
into windows that hold a frame the dataset labels as a grasp and all the others.

Also the text side alone: how often a query's nearest class target is its own class, with the
4 shipped templates and with 6 more paraphrase templates. STAG files: ``$TACTUS_STAG_DIR``.
"""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path
from typing import Any

import numpy as np

from tactus_memory.training.metrics import unit_rows

ROOT = Path(__file__).resolve().parents[1]
HOLDOUT = "one-per-object@blindfolded"
#: paraphrase templates tried on the text side (not the shipped TEMPLATES)
PARAPHRASES = (
    "picking up {}",
    "squeezing {}",
    "using {}",
    "my fingers on {}",
    "gripping {} tightly",
    "{} in my palm",
)


def softmax_mix(s: np.ndarray, targets: np.ndarray, tau: float) -> np.ndarray:
    """s: (N, C) cosines to the class targets -> (N, D) unit softmax mixtures of the targets."""
    p = np.exp((s - s.max(axis=1, keepdims=True)) / tau)
    return unit_rows((p / p.sum(axis=1, keepdims=True)) @ targets)


def retrieval(sim: np.ndarray, obj: np.ndarray, qcls: list[str]) -> dict[str, float]:
    """sim: (Q, W) scores of the stored windows; obj: (W,) class of each window."""
    ranks = []
    for i, c in enumerate(qcls):
        hit = np.flatnonzero(obj[np.argsort(-sim[i], kind="stable")] == c)
        ranks.append(hit[0] if hit.size else np.inf)
    r = np.asarray(ranks, dtype=float)
    return {
        "r@1": float((r < 1).mean()),
        "r@5": float((r < 5).mean()),
        "mrr": float(np.mean(1 / (r + 1))),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("checkpoints", nargs="+", type=Path)
    ap.add_argument(
        "--out", type=Path, default=ROOT / "benchmarks/results/touch_inference_ladder.json"
    )
    args = ap.parse_args()
    from tactus_memory.adapters.touch import TactusEncoder
    from tactus_memory.spaces.minilm import MiniLMSpace
    from tactus_memory.touch.targets import TEMPLATES, build_targets, centre
    from tactus_memory.training.stream_eval import build_stream, load_queries
    from tactus_memory.training.train import holdout_recordings, load_data

    stag = Path(os.environ.get("TACTUS_STAG_DIR", ROOT.parent / "shared/data/stag"))
    data = load_data([stag / "weights_lite", stag / "blindfolded_lite_train"])
    stream = build_stream(data, holdout_recordings(data, HOLDOUT))
    present = set(stream.rec_object.values())
    queries = {c: q for c, q in load_queries().items() if c in present}
    qtext = [q for qs in queries.values() for q in qs]
    qcls = [c for c, qs in queries.items() for _ in qs]
    space = MiniLMSpace()
    qvec = np.asarray(space.embed_texts(qtext, query=True), np.float32)

    keep = ~stream.idle  # (W,) what the memory stores
    frames = stream.frames[keep]  # (W, K, 32, 32) raw
    obj = np.asarray(stream.obj)[keep]
    rec = np.asarray(stream.recording)[keep]
    variants: dict[str, list[np.ndarray]] = {}
    window_top1: list[dict[str, float]] = []
    for ck in args.checkpoints:
        enc = TactusEncoder(ck)
        tgt = enc.ckpt.targets.centred  # (C, D) centred class targets
        q = enc.query_transform(qvec)  # (Q, D)
        z = enc.embed(frames)  # (W, D)
        shifted = [z] + [enc.embed(np.roll(frames, s, axis=a)) for a in (-1, -2) for s in (-1, 1)]
        sims = {
            "plain": q @ z.T,
            "query_snap_0.05": softmax_mix(q @ tgt.T, tgt, 0.05) @ z.T,
            "query_snap_0.1": softmax_mix(q @ tgt.T, tgt, 0.1) @ z.T,
            "window_snap_0.1": q @ softmax_mix(z @ tgt.T, tgt, 0.1).T,
            "csls3": 2 * (q @ z.T) - np.sort(z @ tgt.T, axis=1)[:, -3:].mean(axis=1)[None],
            "tta_shift": q @ unit_rows(np.mean(shifted, axis=0)).T,
        }
        for m in (2, 4):
            zs = z.copy()
            for r in np.unique(rec):
                ix = np.flatnonzero(rec == r)
                for j, i in enumerate(ix):
                    zs[i] = z[ix[max(0, j - m + 1) : j + 1]].mean(axis=0)
            sims[f"smooth_causal_{m}"] = q @ unit_rows(zs).T
        for name, s in sims.items():
            variants.setdefault(name, []).append(s)
        # where the touch side fails: class top-1 of the stored windows vs the labelled ones
        ci = {c: i for i, c in enumerate(enc.classes)}
        truth = np.array([ci[c] for c in obj])
        pred = np.argmax(z @ tgt.T, axis=1)
        lab = stream.labelled[keep]
        window_top1.append(
            {
                "stored_windows": float((pred == truth).mean()),
                "windows_holding_a_labelled_frame": float((pred[lab] == truth[lab]).mean()),
                "other_windows": float((pred[~lab] == truth[~lab]).mean()),
            }
        )
    per_ckpt = {name: [retrieval(s, obj, qcls) for s in ss] for name, ss in variants.items()}
    out: dict[str, Any] = {
        "what": __doc__.split("\n")[0],
        "command": "python benchmarks/touch_inference_ladder.py "
        + " ".join(str(c) for c in args.checkpoints),
        "checkpoints": [str(c) for c in args.checkpoints],
        "windows_stored": int(keep.sum()),
        "queries": len(qcls),
        "per_checkpoint": per_ckpt,
        "window_class_top1": window_top1,
        "mean_over_checkpoints": {
            name: {k: float(np.mean([r[k] for r in rs])) for k in rs[0]}
            for name, rs in per_ckpt.items()
        },
    }
    if len(args.checkpoints) > 1:
        out["ensemble"] = retrieval(np.mean(variants["plain"], axis=0), obj, qcls)

    def text_side(extra: tuple[str, ...]) -> float:
        t = build_targets(space, data.objects, templates=TEMPLATES + extra)
        pred = np.argmax(centre(qvec, t.centroid) @ t.centred.T, axis=1)
        return float(np.mean([t.classes[p] == c for p, c in zip(pred, qcls, strict=True)]))

    out["text_query_to_own_class"] = {
        "templates_4": text_side(()),
        "templates_4_plus_6_paraphrases": text_side(PARAPHRASES),
    }
    args.out.write_text(json.dumps(out, indent=1) + "\n")
    print(json.dumps(out["mean_over_checkpoints"], indent=1))
    print("ensemble", out.get("ensemble"), "text", out["text_query_to_own_class"])


if __name__ == "__main__":
    main()
