"""Objects you teach, measured on the real STAG recordings: one taught grasp per object.

    python benchmarks/teach.py [--stag DIR] [--out benchmarks/results/teach.json]

Data: the ``blindfolded_lite_train`` subset (26 objects, two recordings each). The first
recording of every object is stored as the session ``lesson``; the second recordings are laid
end to end as the session ``day`` (``stream_eval.build_stream``: the stream windowing of the
WebSocket and recordings, idle windows not stored). A real memory: real LanceDB, real MiniLM,
the shipped touch encoder.

With ``--checkpoint`` of a model trained with ``--holdout one-per-object@blindfolded``, the
``day`` recordings are the held-out ones (never trained on) and the lesson recordings the
other ones; the shipped checkpoint was trained on both recordings of every object, so its
figures are not held out (``day_recordings_held_out`` says which case a result is).

Teaching: ``memory.teach(<object>, session="lesson", after=a, before=b)`` over the span of
that object's lesson recording (one grasp per object). Questions: the natural phrasings of
``touch/training/queries/stream_queries.json`` (none a training template), asked through
``memory.search(q, senses=["touch"], session="day")``.

Scores, per configuration (no teaching; the rule with each weight pair, the words counting only
where the prototype agrees with them, ``TEXT_AGREE_TOP``; the prototype alone; ``words_always``:
the (1, 1) rule before issue 46, the words always counting):

* ``r@1`` / ``r@5``: the share of questions whose first / any of the first five ``day``
  windows comes from the asked object's recording;
* ``recording_top1``: per ``day`` recording, the object whose question vectors (as the
  memory searches with them: the sense's query transform and the teaching's steering, mean of
  the phrasings) are nearest the recording's mean window embedding; the share right.

The leakage field says whether the shipped checkpoint was trained on these recordings.
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
#: (W_TEXT, W_PROTO) pairs scored; (1, 1) is the shipped rule (search/teaching.py)
WEIGHTS = ((1.0, 0.5), (1.0, 1.0), (1.0, 2.0), (0.0, 1.0))


def _stag_dir(arg: str | None) -> Path:
    if arg:
        return Path(arg)
    from tactus_memory.datasets.home import data_home

    return data_home().stag


def score(mem, day, queries, rec_vecs) -> dict[str, float]:
    """R@1, R@5 over the questions and recording top-1 (module docstring)."""
    r1 = r5 = n = 0
    objects = sorted(queries)
    qvecs = []
    for obj in objects:
        vs = []
        for q in queries[obj]:
            hits = mem.search(q, k=5, senses=["touch"], session="day")
            recs = [h.meta["object"] for h in hits]
            r1 += bool(recs) and recs[0] == obj
            r5 += obj in recs
            n += 1
            qv = mem.space.embed_texts([q], query=True)
            vs.append(mem.ranker.query_for(np.asarray(qv, np.float32), "touch")[0])
        m = np.mean(vs, axis=0)
        qvecs.append(m / np.linalg.norm(m))
    sims = np.stack([rec_vecs[o] for o in objects]) @ np.stack(qvecs).T
    top1 = float(np.mean(np.argmax(sims, axis=1) == np.arange(len(objects))))
    return {"r@1": r1 / n, "r@5": r5 / n, "recording_top1": top1, "questions": n}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--stag", help="STAG folder (default: the data home's stag/)")
    ap.add_argument("--checkpoint", help="touch checkpoint (default: the shipped one)")
    ap.add_argument("--out", default=str(ROOT / "benchmarks/results/teach.json"))
    args = ap.parse_args()

    from tactus_memory.adapters.touch import TactusEncoder
    from tactus_memory.memory.main import Memory
    from tactus_memory.training import stream_eval
    from tactus_memory.training.data import load_stag

    data = load_stag(_stag_dir(args.stag) / "blindfolded_lite_train")
    per_obj: dict[int, list[int]] = {}
    for r in np.unique(data.recording_id):
        per_obj.setdefault(int(data.object_id[data.recording_id == r][0]), []).append(int(r))
    enc = TactusEncoder(args.checkpoint)
    # a checkpoint that held recordings out of training is asked over exactly those
    held = set(enc.ckpt.meta.get("metrics", {}).get("heldout", {}).get("recordings_named") or [])
    pairs = {}
    for o, rs in sorted(per_obj.items()):
        if len(rs) >= 2:
            rs = sorted(rs[:2], key=lambda r: data.recordings[r] in held)  # held out: 2nd
            pairs[o] = rs
    lesson = stream_eval.build_stream(data, [rs[0] for rs in pairs.values()])
    day = stream_eval.build_stream(data, [rs[1] for rs in pairs.values()])
    all_q = stream_eval.load_queries()
    queries = {c: all_q[c] for c in sorted(set(day.rec_object.values())) if c in all_q}

    started = time.perf_counter()
    out: dict = {
        "data": "blindfolded_lite_train",
        "objects": len(pairs),
        "checkpoint": enc.ckpt.path.name,
        "model": enc.ckpt.meta["model"]["name"],
        "steps": enc.ckpt.meta.get("steps"),
        "day_recordings_held_out": sum(r in held for r in set(day.recording)),
        "leakage": stream_eval.leakage(
            enc.ckpt.meta, sorted(set(lesson.recording) | set(day.recording)), data.fingerprint()
        ),
        "lesson_windows": int((~lesson.idle).sum()),
        "day_windows": int((~day.idle).sum()),
    }
    with tempfile.TemporaryDirectory() as tmp:
        mem = Memory.open(str(Path(tmp) / "m"), background=False)
        mem.add_sense(enc)
        for name, s in (("lesson", lesson), ("day", day)):
            keep = np.flatnonzero(~s.idle)
            mem.add_many(
                name, "touch", list(s.frames[keep]),
                t=s.t[keep].tolist(), t_end=s.t_end[keep].tolist(),
                meta=[{"object": s.obj[i], "recording": s.recording[i]} for i in keep],
            )  # fmt: skip
        rec_vecs = {}
        for obj in queries:
            hits = [h for h in mem.timeline("day", senses=["touch"], limit=100000)
                    if h.meta["object"] == obj]  # fmt: skip
            v = np.mean([mem.get_item(h.id, vector=True).vector for h in hits], axis=0)
            rec_vecs[obj] = v / np.linalg.norm(v)
        out["untaught"] = score(mem, day, queries, rec_vecs)
        for rec, (a, b) in lesson.spans.items():
            mem.teach(lesson.rec_object[rec], session="lesson", after=a, before=b)
        out["taught_labels"] = len(mem.taught())
        for w_text, w_proto in WEIGHTS:
            mem.teachings.w_text, mem.teachings.w_proto = w_text, w_proto
            out[f"taught_w{w_text:g}_{w_proto:g}"] = score(mem, day, queries, rec_vecs)
        # the rule before issue 46: the words always count (no agreement gate)
        mem.teachings.w_text, mem.teachings.w_proto, mem.teachings.agree_top = 1.0, 1.0, None
        out["taught_w1_1_words_always"] = score(mem, day, queries, rec_vecs)
        mem.close()
    out["wall_s"] = round(time.perf_counter() - started, 1)
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(out, indent=2) + "\n")
    print(json.dumps(out, indent=2))


if __name__ == "__main__":
    main()
