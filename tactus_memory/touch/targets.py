"""Text targets: one natural grasp phrase per class, embedded in the frozen space, centred.

The 27 phrases share most of their wording, so their raw embeddings share a large common
component (paper, Method: mean off-diagonal cosine 0.504, nearest-distractor margin 0.354 in
its space). Removing the class centroid and re-normalising spreads them apart (paper: -0.038
and 0.777). The same centroid is later removed from text *queries* compared with touch
vectors (``TactusEncoder.query_transform``), so it is stored in every checkpoint.

Phrases are embedded on the document side (``query=False``): they are the stored meaning of a
class, and user queries are what gets compared against them.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from tactus_memory.spaces.base import Space

# Natural words for STAG class names (stag-format.md, class order). Names not listed fall back
# to underscores -> spaces.
NATURAL_NAMES: dict[str, str] = {
    "allen_key_set": "set of allen keys",
    "board_eraser": "whiteboard eraser",
    "bracket": "metal bracket",
    "brain": "squishy toy brain",
    "cat": "toy cat",
    "chain": "metal chain",
    "clip": "binder clip",
    "empty_can": "empty soda can",
    "full_can": "full soda can",
    "gel": "bottle of gel",
    "kiwano": "kiwano melon",
    "lotion": "bottle of lotion",
    "safety_glasses": "pair of safety glasses",
    "scissors": "pair of scissors",
    "screw_driver": "screwdriver",
    "spray_can": "spray can",
    "tape": "roll of tape",
    "tea_box": "box of tea",
}
EMPTY_HAND = "empty_hand"

# Template ensemble (CLIP-style): each class's phrases are embedded, averaged, re-normalised.
# The first template is the paper's phrase ("a human hand firmly grasping a mug").
TEMPLATES: tuple[str, ...] = (
    "a human hand firmly grasping {}",
    "a hand holding {}",
    "the feeling of {} gripped in a hand",
    "fingers and palm wrapped around {}",
)
EMPTY_HAND_PHRASES: tuple[str, ...] = (
    "an empty human hand, holding nothing",
    "an open hand with nothing in it",
    "the feeling of a bare hand touching nothing",
    "fingers and palm closing on empty air",
)


def natural_name(name: str) -> str:
    """``screw_driver`` -> ``screwdriver``; unknown names: underscores become spaces."""
    return NATURAL_NAMES.get(name, name.replace("_", " "))


def with_article(noun: str) -> str:
    return ("an " if noun[:1].lower() in "aeiou" else "a ") + noun


def class_phrases(name: str, templates: Sequence[str] = TEMPLATES) -> list[str]:
    """Every template filled in for one class; the first one is the class's display phrase."""
    if name == EMPTY_HAND:
        return list(EMPTY_HAND_PHRASES)
    noun = with_article(natural_name(name))
    return [t.format(noun) for t in templates]


def _unit(x: np.ndarray) -> np.ndarray:
    return (x / np.linalg.norm(x, axis=-1, keepdims=True).clip(1e-12)).astype(np.float32)


@dataclass
class Targets:
    """Class targets in one space. ``centred`` is what logits are computed against."""

    classes: list[str]  # class names in label order
    phrases: list[str]  # one display phrase per class (the first template)
    raw: np.ndarray  # (C, D) float32 unit rows: template-averaged phrase embeddings
    centroid: np.ndarray  # (D,) float32 mean of ``raw`` (not normalised)
    centred: np.ndarray  # (C, D) float32 unit rows: normalize(raw - centroid)
    space_name: str
    #: the space's model fingerprint (None for spaces named by their package, e.g. MiniLM)
    space_fingerprint: str | None = None

    def query_transform(self, q: np.ndarray) -> np.ndarray:
        """(N, D) text vectors -> (N, D) comparable with touch vectors: normalize(q - centroid)."""
        return centre(q, self.centroid)


def centre(q: np.ndarray, centroid: np.ndarray) -> np.ndarray:
    """normalize(q - centroid), rows. q: (N, D) or (D,)."""
    return _unit(np.asarray(q, dtype=np.float32) - np.asarray(centroid, dtype=np.float32))


def build_targets(
    space: Space,
    classes: Sequence[str],
    *,
    ensemble: bool = True,
    templates: Sequence[str] = TEMPLATES,
) -> Targets:
    """Embed every class's phrases through ``space`` (document side) and centre them.

    ``templates``: the phrase templates to fill in (default: the shipped :data:`TEMPLATES`)."""
    classes = list(classes)
    per_class = [class_phrases(c, templates)[: None if ensemble else 1] for c in classes]
    flat = [p for ps in per_class for p in ps]
    emb = np.asarray(space.embed_texts(flat, query=False), dtype=np.float32)
    rows, i = [], 0
    for ps in per_class:
        rows.append(_unit(emb[i : i + len(ps)].mean(axis=0)))
        i += len(ps)
    raw = np.stack(rows)
    centroid = raw.mean(axis=0).astype(np.float32)
    return Targets(
        classes=classes,
        phrases=[ps[0] for ps in per_class],
        raw=raw,
        centroid=centroid,
        centred=centre(raw, centroid),
        space_name=space.name,
        space_fingerprint=space.fingerprint(),
    )


def geometry(t: np.ndarray) -> dict[str, float]:
    """Mean off-diagonal cosine and mean nearest-distractor margin (1 - max off-diag cosine)."""
    t = _unit(np.asarray(t, dtype=np.float32))
    sim = t @ t.T
    n = len(t)
    off = sim[~np.eye(n, dtype=bool)].reshape(n, n - 1)
    return {
        "mean_offdiag_cos": float(off.mean()),
        "nearest_distractor_margin": float((1.0 - off.max(axis=1)).mean()),
        "min_margin": float((1.0 - off.max(axis=1)).min()),
    }


def target_report(targets: Targets) -> dict[str, dict[str, float]]:
    """Geometry before and after centring (paper: 0.504/0.354 -> -0.038/0.777 in its space)."""
    return {"before": geometry(targets.raw), "after": geometry(targets.centred)}
