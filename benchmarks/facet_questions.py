"""Physical questions asked of real STAG recordings, with answers known from the frames.

Each recording of a STAG file (default: the blindfolded subset) is streamed as its own session
(``stream_eval.build_stream``: 8-frame windows every 4, idle ones not stored) into a real
memory (MiniLM, the shipped touch encoder, LanceDB). Per session, four questions:

* **firmest**: ``search(q, session=S, sort="-force", k=1)``, right when it is the stored
  window of highest force;
* **first contact after t** (t = the middle of the recording): ``sort="t", after=t``, right
  when it is the earliest stored window still going on at t;
* **pinch**: ``grip="pinch"``, right when the top hit is a pinch (sessions with one only);
* **light touch**: ``force_max`` = the session's 25th force percentile, right when the top
  hit's force is at most it.

The known answers are computed from the raw frames by this script (a loop over the 548
public taxel coordinates, the calibration written out), not by the facets module; the grip of
a window is the documented rule applied to those shares. R@1 is the share of questions whose
first hit is right; ``words_only`` asks the same in a phrase (no facet filter or order), of
the memory as it is: the learned touch embedding and, since issue 50, the windows' captions.

**Words only** (issue 50, captions: :mod:`tactus_memory.search.captions`): questions asked
in words alone, no filter or order, each answered twice: ``captions`` by the memory as it
is (the touch encoder and the windows' captions), ``encoder`` by the touch encoder alone
(the caption channel switched off in this process). Right when the top window is

* "pinching something small", "a pinch with thumb and index": a pinch (sessions with one);
* "a power grasp with the palm": a power grasp (sessions with one);
* "squeezing hard": among the session's firmest quarter (force >= its 75th percentile);
* "touching lightly": among its lightest quarter (force <= its 25th percentile);

known from the frames as above. A session counts for a question when its right answers are
some but not all of its windows (otherwise any answer, or none, is right).

    TACTUS_DATA_HOME=... nice python benchmarks/facet_questions.py   # results/facet_questions.json
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from benchmarks.facet_grasp_words import (  # noqa: E402
    GRASP_WORDS,
    ask_grasps,
    cost,
    paired_sessions,
)
from tactus_memory.adapters.touch import TactusEncoder  # noqa: E402
from tactus_memory.datasets.home import data_home
from tactus_memory.memory.main import Memory
from tactus_memory.touch.facets import grip_of
from tactus_memory.touch.regions import STAG_REGIONS
from tactus_memory.training import stream_eval
from tactus_memory.training.data import load_stag

OUT = Path(__file__).parent / "results" / "facet_questions.json"
LEVEL = 1.0 / 6.0  # the contact level (touch/windows.py CONTACT_LEVEL)
PHRASES = {
    "firmest": "squeezing hard",
    "first_after": "the first touch",
    "pinch": "a pinch between thumb and finger",
    "light": "a light touch",
}


def truth(window: np.ndarray, coords: list[tuple[int, int]]) -> tuple[float, str, list | None]:
    """(force, grip, centroid) of a raw (K, 32, 32) window, from the coordinates, written
    out; the centroid (row, col) of the contact load (None without contact)."""
    vals = np.array([[min(max((float(f[r, c]) - 500) / 150, 0), 1) for r, c in coords]
                     for f in window])  # fmt: skip
    load = np.where(vals >= LEVEL, vals, 0).sum(axis=0)
    shares: dict[str, float] = {n: 0.0 for n in STAG_REGIONS.names}
    centroid = None
    if load.sum() > 0:
        for (r, c), v in zip(coords, load, strict=True):
            shares[STAG_REGIONS.names[STAG_REGIONS.index[r, c]]] += v / load.sum()
        rows, cols = np.array(coords, float).T
        centroid = [float(load @ rows / load.sum()), float(load @ cols / load.sum())]
    return float(vals.sum(axis=1).mean()), str(grip_of(shares)), centroid


#: words-only questions: (phrase, which windows of a session answer it)
WORDS: dict[str, Callable[[dict[str, tuple[float, float, float, str]]], set[str]]] = {
    "pinching something small": lambda rows: {i for i, v in rows.items() if v[3] == "pinch"},
    "a pinch with thumb and index": lambda rows: {i for i, v in rows.items() if v[3] == "pinch"},
    "a power grasp with the palm": lambda rows: {i for i, v in rows.items() if v[3] == "power"},
    "squeezing hard": lambda rows: _quarter(rows, top=True),
    "touching lightly": lambda rows: _quarter(rows, top=False),
}


def _quarter(rows: dict[str, tuple[float, float, float, str]], top: bool) -> set[str]:
    force = {i: v[2] for i, v in rows.items()}
    bar = float(np.percentile(list(force.values()), 75 if top else 25))
    return {i for i, f in force.items() if (f >= bar - 1e-6 if top else f <= bar + 1e-6)}


def ask_in_words(memory: Memory, known: dict[str, dict[str, tuple]]) -> dict[str, Any]:
    """Each WORDS question of each session it fits, R@1 with the captions and without; each
    session's outcome kept (``per_session``: [captions, encoder]) for paired intervals."""
    out: dict[str, Any] = {}
    captions = memory.ranker.captions
    for phrase, answers in WORDS.items():
        right: dict[str, list[bool]] = {"captions": [], "encoder": []}
        per_session: dict[str, list[bool]] = {}
        for session, rows in known.items():
            want = answers(rows)
            if not want or len(want) == len(rows):
                continue
            for way in right:
                if way == "encoder":  # the caption channel off: no caption is reached
                    captions.scores = lambda q: {}  # type: ignore[method-assign]
                hits = memory.search(phrase, k=1, senses=["touch"], group="window", session=session)
                if way == "encoder":
                    del captions.scores
                ok = bool(hits) and hits[0].id in want
                right[way].append(ok)
                per_session.setdefault(session, []).append(ok)
        out[phrase] = {
            "questions": len(right["captions"]),
            **{
                f"r@1_{way}": round(float(np.mean(v)), 3) if v else None for way, v in right.items()
            },
            "per_session": per_session,
        }
    return out


def open_or_build(
    d: Any, coords: list[tuple[int, int]], keep: str | None
) -> tuple[Memory, dict, float | None]:
    """The benchmark's memory and known answers: built from ``d`` (in ``keep`` when given,
    with ``known.json`` beside it), or, when ``keep`` already holds them, reopened (its
    captions rebuilt to the current rule, as ``tactus maintain --facets`` does)."""
    root = Path(keep or tempfile.mkdtemp())
    saved = root / "known.json"
    if saved.exists():
        from tactus_memory.search.captions import Captions

        memory = Memory.open(str(root / "m"), background=False)
        memory.add_sense(TactusEncoder())
        Captions(memory.store, memory.space).rebuild()
        return memory, json.loads(saved.read_text()), None
    memory = Memory.open(str(root / "m"), background=False)
    memory.add_sense(TactusEncoder())
    known: dict[str, dict[str, tuple[float, float, float, str]]] = {}
    t0 = time.perf_counter()
    for r in np.unique(d.recording_id):
        s = stream_eval.build_stream(d, [int(r)])
        keep_i = np.flatnonzero(~s.idle)
        if len(keep_i) < 2:
            continue
        session = f"rec{int(r)}"
        ids = memory.add_many(session, "touch", list(s.frames[keep_i]),
                              t=s.t[keep_i].tolist(), t_end=s.t_end[keep_i].tolist())  # fmt: skip
        known[session] = {
            i: (float(s.t[j]), float(s.t_end[j]), *truth(s.frames[j], coords))
            for i, j in zip(ids, keep_i, strict=True)
        }
    ingest_s = time.perf_counter() - t0
    if keep:
        saved.write_text(json.dumps(known))
    return memory, known, ingest_s


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--subset", default="blindfolded_lite_train")
    ap.add_argument("--keep", help="build the store here (or reuse the one built there)")
    ap.add_argument("--out", type=Path, default=OUT)
    ap.add_argument("--before", help="an earlier run's JSON (per_session) to pair with")
    args = ap.parse_args()
    stag = data_home().stag
    d = load_stag(stag / args.subset / "metadata.mat")
    cj = json.loads((stag / "sensor_coords.json").read_text())
    coords = list(zip(cj["x"], cj["y"], strict=True))
    memory, known, ingest_s = open_or_build(d, coords, args.keep)
    in_words = ask_in_words(memory, known)
    grasp_words = ask_grasps(memory, known)
    search_cost = cost(memory, [*WORDS, *GRASP_WORDS])
    right: dict[str, list[bool]] = {k: [] for k in PHRASES}
    words: dict[str, list[bool]] = {k: [] for k in PHRASES}

    def top(q: str, session: str, **kw) -> str | None:
        hits = memory.search(q, k=1, senses=["touch"], group="window", session=session, **kw)
        return hits[0].id if hits else None

    for session, rows in known.items():
        force = {i: v[2] for i, v in rows.items()}
        firmest = max(force, key=force.get)
        right["firmest"].append(top("holding something", session, sort="-force") == firmest)
        words["firmest"].append(top(PHRASES["firmest"], session) == firmest)
        ts = sorted(v[0] for v in rows.values())
        t_mid = ts[len(ts) // 2]
        on = {i: v[0] for i, v in rows.items() if v[1] >= t_mid}
        first = min(on, key=lambda i: (on[i], i))
        right["first_after"].append(top("touching", session, sort="t", after=t_mid) == first)
        words["first_after"].append(top(PHRASES["first_after"], session, after=t_mid) == first)
        pinches = {i for i, v in rows.items() if v[3] == "pinch"}
        if pinches:
            right["pinch"].append(top("holding something", session, grip="pinch") in pinches)
            words["pinch"].append(top(PHRASES["pinch"], session) in pinches)
        bar = float(np.percentile(list(force.values()), 25))
        light = {i for i, f in force.items() if f <= bar + 1e-6}
        right["light"].append(top("touching", session, force_max=bar + 1e-6) in light)
        words["light"].append(top(PHRASES["light"], session) in light)

    def r1(v: list[bool]) -> dict[str, float | int]:
        return {"questions": len(v), "r@1": round(float(np.mean(v)), 3) if v else None}

    result = {
        "what": "physical questions on real STAG recordings, answers known from the frames",
        "subset": args.subset,
        "sessions": len(known),
        "windows": sum(len(v) for v in known.values()),
        "ingest_s": None if ingest_s is None else round(ingest_s, 1),  # None: store reused
        "facets": {k: r1(v) for k, v in right.items()},
        "words_only": {k: {**r1(v), "phrase": PHRASES[k]} for k, v in words.items()},
        "in_words": in_words,
        "grasps_in_words": grasp_words,
        "caption_cost": search_cost,
    }
    if args.before:  # the same store's sessions asked by the code before: paired intervals
        old = json.loads(Path(args.before).read_text())["in_words"]
        result["in_words_vs_before"] = {
            phrase: paired_sessions(v["per_session"], old[phrase]["per_session"])
            for phrase, v in in_words.items()
            if phrase in old and "per_session" in old[phrase]
        }
    args.out.parent.mkdir(exist_ok=True)
    args.out.write_text(json.dumps(result, indent=2) + "\n")
    print(json.dumps(result, indent=2))


if __name__ == "__main__":
    main()
