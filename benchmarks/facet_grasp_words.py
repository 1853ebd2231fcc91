"""Grasps asked in words (issue 50), the cost of the captions per search, and paired intervals;
used by ``benchmarks/facet_questions.py`` on its store of real STAG recordings.

**Grasp questions.** The memory cuts each recording's windows into grasps (its grasp rule;
nearly one per recording here). Each grasp's duration and centroid speed (slip) are computed
here from the known windows (their spans and the contact-load centroids written out from the
raw frames, ``facet_questions.truth``), not by the facets module. Asked of the whole store
(``group="grasp"``, every grasp ranked), right grasps are

* "a long steady hold": duration in the grasps' top quarter and slip at most their median;
* "slipping": slip in the grasps' top quarter;
* "squeezing hard": force (the firmest member window's) in the grasps' top quarter;

and the figure is the average precision of the ranking (a grasp not returned ranks last),
with the captions and with the touch encoder alone. Intervals: paired bootstrap over
recordings (a grasp belongs to one recording), 2,000 draws, 95 %.

**Cost.** Each words question is timed with the captions and without (alternating, three
rounds), ``group="auto"`` (grasps, as a user asks); the added milliseconds per search: the
median of the paired differences, with a bootstrap interval over questions.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

import numpy as np

from tactus_memory.memory.main import Memory

DRAWS = 2000
SEED = 0


def no_captions(memory: Memory) -> Callable[[], None]:
    """Switch the caption channel off (no caption is reached); returns the switch back."""
    captions = memory.ranker.captions
    captions.scores = lambda q: {}  # type: ignore[method-assign]
    captions.grasp_caption_score = lambda *a, **k: None  # type: ignore[method-assign]

    def back() -> None:
        del captions.scores
        del captions.grasp_caption_score

    return back


def grasps_of(memory: Memory, known: dict[str, dict[str, list]]) -> list[dict[str, Any]]:
    """Every grasp of the store (the memory's cut), with its truth from the known windows."""
    out = []
    for session, rows in known.items():
        hits = memory.search("touching", k=len(rows), senses=["touch"], group="grasp",
                             session=session)  # fmt: skip
        for g in hits:
            members = [rows[i] for i in g.ids if i in rows]
            t0, t1 = min(m[0] for m in members), max(m[1] for m in members)
            path = [(0.5 * (m[0] + m[1]), m[4]) for m in sorted(members, key=lambda m: m[0])
                    if m[4] is not None]  # fmt: skip
            dist = sum(float(np.hypot(b[1][0] - a[1][0], b[1][1] - a[1][1]))
                       for a, b in zip(path, path[1:], strict=False))  # fmt: skip
            dt = path[-1][0] - path[0][0] if len(path) > 1 else 0.0
            out.append({
                "id": g.id, "ids": set(g.ids), "session": session, "duration": t1 - t0,
                "slip": dist / dt if dt > 0 else 0.0, "force": max(m[2] for m in members),
                "facets": g.facets,
            })  # fmt: skip
    return out


def quarter(vals: list[float], top: bool) -> float:
    return float(np.percentile(vals, 75 if top else 25))


GRASP_WORDS: dict[str, Callable[[list[dict[str, Any]]], set[str]]] = {
    "a long steady hold": lambda gs: {
        g["id"]
        for g in gs
        if g["duration"] >= quarter([x["duration"] for x in gs], True)
        and g["slip"] <= float(np.median([x["slip"] for x in gs]))
    },  # fmt: skip
    "slipping": lambda gs: {
        g["id"] for g in gs if g["slip"] >= quarter([x["slip"] for x in gs], True)
    },
    "squeezing hard": lambda gs: {
        g["id"] for g in gs if g["force"] >= quarter([x["force"] for x in gs], True)
    },
}


def ranks(memory: Memory, phrase: str, grasps: list[dict[str, Any]], k: int) -> dict[str, int]:
    """Each grasp's rank for ``phrase`` (the grasps' first window ids matched by membership);
    a grasp not returned ranks last."""
    hits = memory.search(phrase, k=k, senses=["touch"], group="grasp")
    out: dict[str, int] = {}
    for r, h in enumerate(hits):
        for g in grasps:
            if g["id"] not in out and g["ids"] & set(h.ids or [h.id]):
                out[g["id"]] = r
    return {g["id"]: out.get(g["id"], len(hits) + 1) for g in grasps}


def average_precision(rank: dict[str, int], right: set[str], pick: list[str]) -> float:
    """AP of the grasps ``pick`` (a multiset: a bootstrap draw) ranked by ``rank``."""
    order = sorted(range(len(pick)), key=lambda i: (rank[pick[i]], pick[i], i))
    hits, total = 0, 0.0
    for n, i in enumerate(order, 1):
        if pick[i] in right:
            hits += 1
            total += hits / n
    return total / hits if hits else 0.0


def ask_grasps(memory: Memory, known: dict[str, dict[str, list]]) -> dict[str, Any]:
    """GRASP_WORDS asked of every grasp: AP with captions and with the encoder alone."""
    grasps = grasps_of(memory, known)
    k = sum(len(v) for v in known.values())
    by_session: dict[str, list[str]] = {}
    for g in grasps:
        by_session.setdefault(g["session"], []).append(g["id"])
    sessions = sorted(by_session)
    rng = np.random.default_rng(SEED)
    draws = [rng.integers(0, len(sessions), len(sessions)) for _ in range(DRAWS)]
    out: dict[str, Any] = {"grasps": len(grasps), "stats": grasp_stats(grasps)}
    for phrase, answer in GRASP_WORDS.items():
        right = answer(grasps)
        with_c = ranks(memory, phrase, grasps, k)
        back = no_captions(memory)
        alone = ranks(memory, phrase, grasps, k)
        back()
        ids = [g["id"] for g in grasps]
        diffs = []
        for d in draws:
            pick = [i for j in d for i in by_session[sessions[j]]]
            diffs.append(
                average_precision(with_c, right, pick) - average_precision(alone, right, pick)
            )
        out[phrase] = {
            "right": len(right),
            "ap_captions": round(average_precision(with_c, right, ids), 3),
            "ap_encoder": round(average_precision(alone, right, ids), 3),
            "ap_chance": round(len(right) / len(ids), 3),
            "diff_ci95": [round(float(np.percentile(diffs, q)), 3) for q in (2.5, 97.5)],
        }
    return out


def grasp_stats(grasps: list[dict[str, Any]]) -> dict[str, Any]:
    """Percentiles of the grasps' duration and slip as the facets module computes them (the
    source of ``touch.facets.LONG_HOLD_S`` and ``SLIP_SPEED``)."""
    fs = [g["facets"] for g in grasps if g["facets"]]
    pct = (25, 50, 75)
    return {
        f"{name}_p{p}": round(float(np.percentile([f[name] for f in fs], p)), 2)
        for name in ("duration", "slip")
        for p in pct
    }


def paired_sessions(
    after: dict[str, list[bool]], before: dict[str, list[bool]], col: int = 0
) -> dict:
    """R@1 after minus before on the sessions both asked (``per_session``: [captions,
    encoder]), with a paired bootstrap interval over those sessions."""
    common = sorted(set(after) & set(before))
    a = np.array([after[s][col] for s in common], float)
    b = np.array([before[s][col] for s in common], float)
    rng = np.random.default_rng(SEED)
    d = [
        float((a[i] - b[i]).mean()) for i in (rng.integers(0, len(a), len(a)) for _ in range(DRAWS))
    ]
    return {
        "sessions": len(common),
        "before": round(float(b.mean()), 3),
        "after": round(float(a.mean()), 3),
        "diff_ci95": [round(float(np.percentile(d, q)), 3) for q in (2.5, 97.5)],
    }


def cost(memory: Memory, phrases: list[str], rounds: int = 3) -> dict[str, Any]:
    """Added ms per search (``group="auto"``) with the captions against without: each phrase
    asked once both ways first (query embedding and grasp captions cached, as in a running
    server), then ``rounds`` timed pairs, the order alternating."""

    def timed(on: bool, phrase: str) -> float:
        back = None if on else no_captions(memory)
        t0 = time.perf_counter()
        memory.search(phrase, k=10, senses=["touch"])
        dt = (time.perf_counter() - t0) * 1e3
        if back is not None:
            back()
        return dt

    diffs, on_ms, off_ms = [], [], []
    for phrase in phrases:
        timed(True, phrase), timed(False, phrase)
        for r in range(rounds):
            first = r % 2 == 0
            a = timed(first, phrase)
            b = timed(not first, phrase)
            on, off = (a, b) if first else (b, a)
            on_ms.append(on)
            off_ms.append(off)
            diffs.append(on - off)
    rng = np.random.default_rng(SEED)
    boot = [float(np.median(rng.choice(diffs, len(diffs)))) for _ in range(DRAWS)]
    return {
        "searches": len(diffs),
        "p50_ms_captions": round(float(np.median(on_ms)), 1),
        "p50_ms_encoder": round(float(np.median(off_ms)), 1),
        "added_ms_p50": round(float(np.median(diffs)), 1),
        "added_ms_ci95": [round(float(np.percentile(boot, q)), 1) for q in (2.5, 97.5)],
    }
