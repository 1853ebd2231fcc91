"""A match bar that means a precision (issue 46): how often a hit past a bar is right, and the
rule that chooses a bar from held-out questions.

**What is measured.** A question set, each question asked of a memory it was not tuned on,
its top hit kept: its calibrated score and whether it is right. At a bar ``b`` the *matches*
are the top hits scoring ``>= b`` and the precision is ``right matches / matches``, with its
95 % **Wilson** score interval (:func:`wilson`; ``scipy.stats.binomtest``).

**The rule** (:func:`choose_bar`). The bar is the lowest bar of the sweep whose precision's
*lower* Wilson bound reaches the target (:data:`TARGET_PRECISION`): the lower bound, not the
point estimate, so a bar passed by 3 of 3 right matches (lower bound 0.44) is not taken for
one that is right 80 % of the time. When no bar of the sweep reaches it, the rule says so
(``reached: false``, ``bar: null``) and the shipped bar stays what it was; ``GET /senses``
then reports the precision actually measured at the shipped bar, with its interval, the
question set, and ``target_reached: false``.

The benchmarks that apply it: ``benchmarks/touch_demo.py`` (touch grasps, the demo
checkpoint's held-out recordings), ``benchmarks/text_precision.py`` (text notes),
``benchmarks/teach_once.py`` (taught labels).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

#: the precision a match should have (issue 46: ">= 0.8 for grasps"; the same for text and
#: taught labels)
TARGET_PRECISION = 0.8
#: the confidence of the Wilson interval
CONFIDENCE = 0.95
#: the bars swept (calibrated scores): 2.0, 2.5, ... 9.0
BARS: tuple[float, ...] = tuple(round(2.0 + 0.5 * i, 1) for i in range(15))
#: how the rule reads the interval (``/senses`` names it)
RULE = (
    "the lowest bar whose precision's 95 % Wilson lower bound reaches the target "
    "(tactus_memory/training/bar_rule.py)"
)


def wilson(k: int, n: int, confidence: float = CONFIDENCE) -> dict[str, Any]:
    """``k`` right of ``n``: the proportion and its Wilson score interval (``value: None`` and
    no interval when ``n == 0``)."""
    from scipy.stats import binomtest

    if n == 0:
        return {"value": None, "k": 0, "n": 0}
    ci = binomtest(k, n).proportion_ci(confidence_level=confidence, method="wilson")
    return {"value": k / n, "k": k, "n": n, "lo": float(ci.low), "hi": float(ci.high)}


def precision_at(scores: np.ndarray, right: np.ndarray, bar: float) -> dict[str, Any]:
    """The precision of the top hits scoring at least ``bar``. scores: (Q,) float; right: (Q,)
    bool, one per question."""
    passed = np.asarray(scores, dtype=np.float64) >= bar
    ok = np.asarray(right, dtype=bool)
    return wilson(int((passed & ok).sum()), int(passed.sum()))


def choose_bar(
    scores: Sequence[float] | np.ndarray,
    right: Sequence[bool] | np.ndarray,
    shipped_bar: float,
    target: float = TARGET_PRECISION,
    bars: Sequence[float] = BARS,
) -> dict[str, Any]:
    """The rule of the module docstring over one question set's top hits: the sweep, the bar
    it chooses (None when none reaches ``target``) and the precision at ``shipped_bar``."""
    s = np.asarray(scores, dtype=np.float64)
    r = np.asarray(right, dtype=bool)
    if s.shape != r.shape or s.ndim != 1:
        raise ValueError(f"scores {s.shape} and right {r.shape} must be two (Q,) arrays")
    sweep = {str(b): precision_at(s, r, b) for b in bars}
    ok = [b for b in bars if sweep[str(b)].get("lo", 0.0) >= target]
    return {
        "questions": int(len(s)),
        "top1_right": wilson(int(r.sum()), int(len(r))),
        "shipped_bar": float(shipped_bar),
        "at_shipped_bar": precision_at(s, r, shipped_bar),
        "sweep": sweep,
        "target_precision": target,
        "bar_at_target": ok[0] if ok else None,
        "target_reached": bool(ok),
        "rule": RULE,
    }


def senses_row(chosen: dict[str, Any], questions: str, measured_on: str) -> dict[str, Any]:
    """What ``GET /senses`` reports as ``precision_at_bar``: the precision at the shipped bar
    (value, lo/hi, k of n), the bar, the question set, the target and whether the rule
    reached it (and at which bar)."""
    return {
        "bar": chosen["shipped_bar"],
        **chosen["at_shipped_bar"],
        "questions": questions,
        "measured_on": measured_on,
        "target_precision": chosen["target_precision"],
        "target_reached": chosen["target_reached"],
        "bar_at_target": chosen["bar_at_target"],
        "rule": chosen["rule"],
    }
