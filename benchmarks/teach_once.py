"""Teach once, find again: one recording per object taught under a MADE-UP label.

    python benchmarks/teach_once.py [--checkpoint CKPT] [--out benchmarks/results/teach_once.json]

The protocol's fold A: the checkpoint (default: the shipped demo checkpoint) was trained with
``--holdout one-per-object@blindfolded``. ``blindfolded_lite_train`` holds two recordings of each
of 26 objects: the one the checkpoint trained on is the ``lesson`` session, the held-out one
(never trained on) is laid end to end with the other objects' into the ``day`` session (the
stream windowing; idle windows are not stored). A real memory (real LanceDB, real MiniLM).

Each object's lesson recording is taught with ``memory.teach(<label>, session="lesson",
after=a, before=b)`` under a made-up label (:data:`LABELS`: nonsense words, so the words give
no help), then ``"when was I holding the <label>?"`` is asked over ``day``
(``memory.search(q, k=5, senses=["touch"], session="day")``). Per rule of
:class:`~tactus_memory.search.teaching.Teachings` (``w_text``, ``w_proto``, ``centre``):

* ``top1``: the share of the 26 labels whose first hit comes from the object's day recording;
* ``r5``: one of the first five does (95 % Wilson intervals over the 26 labels).

``assignment``: each day recording's mean window embedding assigned to its nearest taught
prototype (no text), the share right; ``knn``: labels ranked by the best cosine of a day
window to any single taught window of the label (several prototypes; not a search-path rule).
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
#: made-up labels, one per object (in sorted object order): no word of any STAG object
LABELS = (
    "blicket", "dax", "wug", "toma", "fep", "zib", "kiki", "bouba", "gorp", "mipp", "tufa",
    "zorp", "vink", "plon", "snib", "traz", "yemo", "kulp", "drev", "fosk", "glim", "hapu",
    "jeck", "lorn", "nuvo", "ploof",
)  # fmt: skip
QUESTION = "when was I holding the {}?"
#: (w_text, w_proto, centre) rules scored; (1, 1, False) is the rule before issue 46
RULES = ((1.0, 1.0, False), (1.0, 1.0, True), (0.0, 1.0, False), (0.0, 1.0, True))
RULES += ((0.5, 1.0, True),)


def wilson(k: int, n: int) -> dict[str, float]:
    from scipy.stats import binomtest

    ci = binomtest(k, n).proportion_ci(method="wilson")
    return {"value": k / n, "k": k, "n": n, "lo": float(ci.low), "hi": float(ci.high)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--stag", help="STAG folder (default: the data home's stag/)")
    ap.add_argument("--checkpoint", help="touch checkpoint (default: the shipped demo one)")
    ap.add_argument("--out", default=str(ROOT / "benchmarks/results/teach_once.json"))
    args = ap.parse_args()

    from tactus_memory.adapters.touch import TactusEncoder
    from tactus_memory.datasets.home import data_home
    from tactus_memory.memory.main import Memory
    from tactus_memory.touch.checkpoint import demo_checkpoint_path, heldout_recordings
    from tactus_memory.training import stream_eval
    from tactus_memory.training.data import load_stag

    stag = Path(args.stag) if args.stag else data_home().stag
    data = load_stag(stag / "blindfolded_lite_train")
    enc = TactusEncoder(args.checkpoint or demo_checkpoint_path())
    held = set(heldout_recordings(enc.ckpt.meta))
    by_obj: dict[str, list[int]] = {}
    for r in np.unique(data.recording_id):
        by_obj.setdefault(data.objects[int(data.object_id[data.recording_id == r][0])], [])
        by_obj[data.objects[int(data.object_id[data.recording_id == r][0])]].append(int(r))
    # (trained-on, held-out): the held-out recording of each object sorts last
    pairs = {o: sorted(rs, key=lambda r: data.recordings[r] in held) for o, rs in by_obj.items()}
    objects = sorted(o for o, rs in pairs.items() if len(rs) == 2)
    label = dict(zip(objects, LABELS, strict=False))
    lesson = stream_eval.build_stream(data, [pairs[o][0] for o in objects])
    day = stream_eval.build_stream(data, [pairs[o][1] for o in objects])
    out: dict = {
        "what": __doc__.split("\n")[0],
        "command": "python benchmarks/teach_once.py",
        "checkpoint": enc.ckpt.path.name,
        "objects": len(objects),
        "day_recordings_held_out": sum(data.recordings[pairs[o][1]] in held for o in objects),
        "lesson_recordings_trained_on": sum(
            data.recordings[pairs[o][0]] not in held for o in objects
        ),
        "leakage_day": stream_eval.leakage(enc.ckpt.meta, sorted(set(day.recording)), None),
        "labels": label,
        "question": QUESTION,
    }
    started = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        mem = Memory.open(str(Path(tmp) / "m"), background=False)
        mem.add_sense(enc)
        vecs: dict[str, tuple[np.ndarray, list[str]]] = {}
        for name, s in (("lesson", lesson), ("day", day)):
            keep = np.flatnonzero(~s.idle)
            mem.add_many(
                name, "touch", list(s.frames[keep]),
                t=s.t[keep].tolist(), t_end=s.t_end[keep].tolist(),
                meta=[{"object": s.obj[i]} for i in keep],
            )  # fmt: skip
            items = mem.timeline(name, senses=["touch"], limit=100000)
            v = np.stack([mem.get_item(h.id, vector=True).vector for h in items]).astype(np.float32)
            vecs[name] = (v, [h.meta["object"] for h in items])
        out["lesson_windows"], out["day_windows"] = len(vecs["lesson"][1]), len(vecs["day"][1])
        for rec, (a, b) in lesson.spans.items():
            mem.teach(label[lesson.rec_object[rec]], session="lesson", after=a, before=b)
        rules = {}
        for w_text, w_proto, centre in RULES:
            t = mem.teachings
            t.w_text, t.w_proto, t.centre = w_text, w_proto, centre
            top1 = r5 = 0
            for obj in objects:
                hits = mem.search(QUESTION.format(label[obj]), k=5, senses=["touch"], session="day")
                got = [h.meta["object"] for h in hits]
                top1 += bool(got) and got[0] == obj
                r5 += obj in got
            key = f"w_text={w_text:g},w_proto={w_proto:g},centre={centre}"
            rules[key] = {"top1": wilson(top1, len(objects)), "r5": wilson(r5, len(objects))}
            print(key, top1, r5, flush=True)
        out["search"] = rules
        mem.close()
    # offline: prototypes from the stored vectors (the rule's own prototypes, before mixing)
    lv, lo = vecs["lesson"]
    dv, do = vecs["day"]
    lo_a, do_a = np.array(lo), np.array(do)
    protos = np.stack([lv[lo_a == o].mean(0) for o in objects])
    protos /= np.linalg.norm(protos, axis=1, keepdims=True)
    recs = np.stack([dv[do_a == o].mean(0) for o in objects])
    recs /= np.linalg.norm(recs, axis=1, keepdims=True)
    centred = protos - (protos.sum(0) - protos) / (len(objects) - 1)
    centred /= np.linalg.norm(centred, axis=1, keepdims=True)
    n = len(objects)
    out["assignment"] = {
        "prototype": wilson(int((np.argmax(recs @ protos.T, 1) == np.arange(n)).sum()), n),
        "centred_prototype": wilson(int((np.argmax(recs @ centred.T, 1) == np.arange(n)).sum()), n),
    }
    top1 = r5 = 0
    for obj in objects:
        best = (dv @ lv[lo_a == obj].T).max(axis=1)  # per day window: nearest taught window
        order = [do[j] for j in np.argsort(-best)[:5]]
        top1 += order[0] == obj
        r5 += obj in order
    out["knn"] = {"top1": wilson(top1, n), "r5": wilson(r5, n)}
    out["wall_s"] = round(time.perf_counter() - started, 1)
    Path(args.out).write_text(json.dumps(out, indent=1) + "\n")
    print(json.dumps({k: out[k] for k in ("search", "assignment", "knn")}, indent=1))


if __name__ == "__main__":
    main()
