"""The touch captions' cosine gate (issue 50), chosen for a stated precision.

A question reaches a caption (``search.captions``) when their MiniLM cosine is at least the
gate (the best ``CAPTION_TOP`` such captions take part). The captions are every rule-``N``
caption a glove can have (``touch.facets.caption_words``): each firmness band, grip with its
usual regions, and for grasps each motion. The phrasings (``caption_gate_phrases.json``) are
positives, each naming what a caption it reaches must say (e.g. "a gentle touch": a light
band; "when did it slip": a slipping grasp), and negatives (object, place and unrelated
questions) that must reach none. A reached (phrase, caption) pair is right when the caption
says what the phrase means (every attribute it names), wrong otherwise (every pair of a
negative is wrong).

For each gate on a 0.01 grid: precision (right pairs / reached pairs) and recall (positive
phrases reaching at least one right caption), on the tuning half and on the held-out half.
The chosen gate is the lowest whose tuning precision is at least ``GATE_PRECISION``; the
held-out half is reported at it, and at the gate used before (0.55).

    python benchmarks/caption_gate.py   # results/caption_gate.json
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from tactus_memory.search.captions import CAPTION_MIN_COS, CAPTION_TOP, GATE_PRECISION
from tactus_memory.spaces.minilm import MiniLMSpace
from tactus_memory.touch.facets import CAPTION_RULE, FIRMNESS_BANDS, MOTIONS, caption_words

HERE = Path(__file__).parent
PHRASES = HERE / "caption_gate_phrases.json"
OUT = HERE / "results" / "caption_gate.json"
OLD_GATE = 0.55
#: each grip with the regions it usually has on the glove (most loaded first)
GRIP_REGIONS: list[tuple[str | None, list[str]]] = [
    ("pinch", ["thumb", "index"]),
    ("pinch", ["index", "thumb"]),
    ("pinch", ["thumb", "middle"]),
    ("tripod", ["thumb", "index", "middle"]),
    ("power", ["palm", "index", "middle"]),
    ("power", ["palm", "thumb", "index", "middle", "ring"]),
    ("press", ["palm"]),
    ("press", ["index"]),
    ("other", ["index", "middle", "ring"]),
    ("none", []),
    (None, []),
]


def vocabulary() -> list[dict[str, Any]]:
    """Every caption: its attributes and text (windows: no motion; grasps: each motion)."""
    out: dict[str, dict[str, Any]] = {}
    for band in FIRMNESS_BANDS:
        for grip, regions in GRIP_REGIONS:
            for move in (None, *MOTIONS):
                text = caption_words(band, grip, regions, move)
                said = regions if move is None else []  # a grasp's caption names no region
                attrs = {"band": band, "grip": grip, "move": move, "regions": said}
                out.setdefault(text, {"text": text, **attrs})
    return list(out.values())


def right(means: dict[str, list[str]] | None, cap: dict[str, Any]) -> bool:
    if means is None:
        return False
    for attr, ok in means.items():
        have = cap[attr]
        if attr == "regions":
            if not set(ok) & set(have):
                return False
        elif have not in ok:
            return False
    return True


def measure(cos: np.ndarray, caps: list[dict], phrases: list[dict], gate: float) -> dict:
    reached = good = found = positives = 0
    for row, p in zip(cos, phrases, strict=True):
        top = [int(i) for i in np.argsort(-row)[:CAPTION_TOP] if row[i] >= gate]
        oks = [right(p.get("means"), caps[i]) for i in top]
        reached += len(top)
        good += sum(oks)
        if p.get("means") is not None:
            positives += 1
            found += any(oks)
    return {
        "gate": round(gate, 2),
        "reached_pairs": reached,
        "precision": round(good / reached, 3) if reached else None,
        "recall": round(found / positives, 3) if positives else None,
    }


def main() -> None:
    spec = json.loads(PHRASES.read_text())
    phrases = [*spec["positives"], *spec["negatives"]]
    caps = vocabulary()
    space = MiniLMSpace()
    cv = space.embed_texts([c["text"] for c in caps])
    result: dict[str, Any] = {
        "what": "touch caption gate: precision of reached captions on phrasings",
        "caption_rule": CAPTION_RULE,
        "captions": len(caps),
        "gate_precision": GATE_PRECISION,
    }
    grid = [round(g, 2) for g in np.arange(0.40, 0.851, 0.01)]
    per: dict[str, Any] = {}
    for split in ("tune", "test"):
        ps = [p for p in phrases if p["split"] == split]
        qv = space.embed_texts([p["phrase"] for p in ps], query=True)
        cos = qv @ cv.T
        per[split] = {
            "phrases": len(ps),
            "grid": [measure(cos, caps, ps, g) for g in grid],
            "best": {
                p["phrase"]: [caps[int(np.argmax(r))]["text"], round(float(r.max()), 3)]
                for p, r in zip(ps, cos, strict=True)
            },
            "_cos": cos,
            "_ps": ps,
        }
    ok = [m["gate"] for m in per["tune"]["grid"] if (m["precision"] or 0) >= GATE_PRECISION]
    chosen = min(ok) if ok else None
    result["chosen_gate"] = chosen
    result["gate_in_code"] = CAPTION_MIN_COS
    for split, d in per.items():
        at = {g: measure(d["_cos"], caps, d["_ps"], g) for g in (OLD_GATE, chosen) if g}
        result[split] = {
            "phrases": d["phrases"],
            "at_old_gate": at[OLD_GATE],
            "at_chosen_gate": at.get(chosen),
            "grid": d["grid"],
            "best_caption": d["best"],
        }
    OUT.write_text(json.dumps(result, indent=2) + "\n")
    show = {k: v for k, v in result.items() if k not in ("tune", "test")}
    show.update({s: {k: v for k, v in result[s].items() if k != "grid"} for s in ("tune", "test")})
    print(json.dumps(show, indent=2))


if __name__ == "__main__":
    main()
