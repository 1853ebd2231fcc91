"""Realistic 384-d rows for the 1M search benchmark (``search_1m.py``): a clustered mixture
built on REAL embeddings, with their measured spread, instead of uniform or isotropic noise.

* Anchors: MiniLM embeddings of templated robot notes (text) and embeddings of real STAG
  glove windows by the shipped touch encoder (touch, in the same space).
* Spread: each row is an anchor plus Gaussian noise with the covariance of that sense's real
  embeddings (so it stays in their low-dimensional, anisotropic cone), scaled so that the
  median cosine of a row to its anchor equals the median nearest-neighbour cosine measured
  among the real embeddings (``profile`` records both figures).
* Queries: MiniLM embeddings of question-style texts, disjoint from the notes.

Everything is cached under the cache folder (``real.npz``, ``rows.npz``), outside git.
"""

from __future__ import annotations

import itertools
import json
from pathlib import Path
from typing import Any

import numpy as np

DIM = 384
N_SESSIONS = 50
#: stored senses of the benchmark rows (VectorSense names; "touch"/"text" are live senses of
#: a server, so other names keep the 1M store servable as it is)
SENSES = ("glove", "notes")
SENSE_P = (0.75, 0.25)

_VERBS = (
    "picked up",
    "put down",
    "squeezed",
    "held",
    "dropped",
    "handed over",
    "wiped",
    "opened",
    "closed",
    "turned",
    "pressed",
    "stacked",
    "poured from",
    "shook",
)
_OBJECTS = (
    "the red mug",
    "a tennis ball",
    "the stapler",
    "a plastic bottle",
    "the kettle",
    "a sponge",
    "the door handle",
    "a glass",
    "the remote control",
    "a banana",
    "the scissors",
    "a cardboard box",
    "the drawer",
    "a metal spoon",
    "the phone",
    "a paper cup",
    "the screwdriver",
    "a soft toy",
    "the laptop lid",
    "a bag of rice",
)
_PLACES = (
    "on the kitchen table",
    "in the sink",
    "near the window",
    "on the top shelf",
    "in the living room",
    "by the charger",
    "on the workbench",
    "in the fridge",
    "next to the door",
    "on the floor",
)
_HOW = ("gently", "firmly", "slowly", "quickly", "with two fingers", "with the whole hand")
_QUESTIONS = (
    "where did I {v} {o}?",
    "when was {o} {p}?",
    "show me grasping {o} {h}",
    "what did it feel like to hold {o}?",
    "find the moment I {v} {o}",
)


def note_texts(n: int, seed: int = 0) -> list[str]:
    """n distinct robot-log notes from the templates (deterministic)."""
    every = [
        f"I {v} {o} {p} {h}" for v, o, p, h in itertools.product(_VERBS, _OBJECTS, _PLACES, _HOW)
    ]
    pick = np.random.default_rng(seed).choice(len(every), min(n, len(every)), replace=False)
    return [every[i] for i in pick]


def query_texts(n: int, seed: int) -> list[str]:
    """n question-style texts (another wording than the notes)."""
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(n):
        t = _QUESTIONS[rng.integers(len(_QUESTIONS))]
        out.append(
            t.format(
                v=rng.choice(_VERBS),
                o=rng.choice(_OBJECTS),
                p=rng.choice(_PLACES),
                h=rng.choice(_HOW),
            )
        )
    return out


def touch_windows(stag: Path, n: int, frames: int, seed: int = 0) -> np.ndarray:
    """n windows (n, K, 32, 32) int16 of K consecutive frames of one recording, from a STAG
    subset (real data)."""
    from tactus_memory.training.data import load_stag

    data = load_stag(stag)
    rec = data.recording_id
    ok = np.flatnonzero(rec[: len(rec) - frames + 1] == rec[frames - 1 :])
    starts = np.random.default_rng(seed).choice(ok, min(n, len(ok)), replace=False)
    return np.stack([data.pressure[s : s + frames] for s in np.sort(starts)])


def profile(cache: Path, stag: Path, n_text: int, n_touch: int, n_queries: int) -> dict[str, Any]:
    """Real embeddings (cached in ``cache/real.npz``): notes, touch windows, queries."""
    path = cache / "real.npz"
    if path.exists():
        with np.load(path) as z:
            return {k: z[k] for k in z.files}
    from tactus_memory.adapters.touch import TactusEncoder
    from tactus_memory.spaces import get_space

    space = get_space("minilm")
    enc = TactusEncoder()
    wins = touch_windows(stag, n_touch, enc.frames)
    real = {
        "notes": space.embed_texts(note_texts(n_text)),
        "glove": enc.embed(wins),
        "queries": space.embed_texts(query_texts(n_queries, seed=1)),
        "tune_queries": space.embed_texts(query_texts(n_queries, seed=2)),
    }
    cache.mkdir(parents=True, exist_ok=True)
    np.savez(path, **real)
    return real


def nn_cosine(x: np.ndarray) -> np.ndarray:
    """(N, D) unit rows -> (N,) cosine of each row to its nearest other row."""
    s = x @ x.T
    np.fill_diagonal(s, -np.inf)
    return s.max(axis=1)


class Spread:
    """Anchor + covariance-shaped noise for one sense's real embeddings ``real`` (N, D)."""

    def __init__(self, real: np.ndarray, rng: np.random.Generator) -> None:
        self.anchors = real.astype(np.float32)
        centred = real - real.mean(axis=0)
        _, s, vt = np.linalg.svd(centred, full_matrices=False)
        self.basis = (s[:, None] * vt / np.sqrt(len(real))).astype(np.float32)  # (r, D)
        self.target = float(np.median(nn_cosine(real)))
        self.scale = self._fit(rng)

    def noise(self, n: int, rng: np.random.Generator) -> np.ndarray:
        return rng.standard_normal((n, len(self.basis))).astype(np.float32) @ self.basis

    def _fit(self, rng: np.random.Generator) -> float:
        """Noise scale whose median cosine(row, anchor) is the real median NN cosine."""
        a = self.anchors[rng.integers(0, len(self.anchors), 4000)]
        e = self.noise(4000, rng)
        lo, hi = 0.0, 20.0
        for _ in range(40):
            mid = (lo + hi) / 2
            x = a + mid * e
            cos = np.median((x * a).sum(1) / np.linalg.norm(x, axis=1))
            lo, hi = (mid, hi) if cos > self.target else (lo, mid)
        return (lo + hi) / 2

    def draw(self, n: int, rng: np.random.Generator) -> np.ndarray:
        """n rows (n, D) float32 unit."""
        a = self.anchors[rng.integers(0, len(self.anchors), n)]
        x = a + self.scale * self.noise(n, rng)
        return x / np.linalg.norm(x, axis=1, keepdims=True)

    def describe(self, rng: np.random.Generator) -> dict[str, float]:
        x = self.draw(2000, rng)
        return {
            "real_rows": len(self.anchors),
            "real_nn_cosine_median": self.target,
            "noise_scale": self.scale,
            "synthetic_nn_cosine_median_2000": float(np.median(nn_cosine(x))),
            "real_nn_cosine_median_2000": float(np.median(nn_cosine(self.anchors[:2000]))),
        }


def rows(cache: Path, n: int, real: dict[str, np.ndarray], seed: int = 0) -> dict[str, Any]:
    """n rows (cached in ``cache/rows-N.npz``): vectors (n, D), session, sense (index into
    SENSES), t (sorted seconds), and the spread figures."""
    path = cache / f"rows-{n}.npz"
    if path.exists():
        with np.load(path, allow_pickle=False) as z:
            out: dict[str, Any] = {k: z[k] for k in z.files}
        out["spread"] = json.loads(str(out["spread"]))
        return out
    rng = np.random.default_rng(seed)
    sense = rng.choice(len(SENSES), n, p=SENSE_P)
    vectors = np.empty((n, DIM), np.float32)
    spread = {}
    for j, name in enumerate(SENSES):
        sp = Spread(real[name], rng)
        where = np.flatnonzero(sense == j)
        for a in range(0, len(where), 100_000):
            idx = where[a : a + 100_000]
            vectors[idx] = sp.draw(len(idx), rng)
        spread[name] = sp.describe(rng)
    out = {
        "vectors": vectors,
        "session": rng.integers(0, N_SESSIONS, n),
        "sense": sense,
        "t": np.sort(rng.uniform(0, 30 * 86_400, n)),
    }
    np.savez(path, **out, spread=np.array(json.dumps(spread)))
    out["spread"] = spread
    return out
