"""What "a match" is for the temporal operators, and how matches group into moments: the
thresholds, the relative gate, the grouping rule (pure functions, no store).

Everything here is deterministic (no LLM) and built on the memory's own search path: the query
is embedded once, each sense is searched with its query transform and scored by its calibrated
z-score (:mod:`tactus_memory.search.scoring`), then time logic runs in Python.

**What "a match" is.** A hit of sense *s* matches a query when

1. ``score >= threshold[s]``: its calibrated score (null standard deviations above the cosine
   that the generic probe queries get against *s*) clears an absolute, per-sense bar
   (:data:`MATCH_Z`, overridable per call with ``threshold=``). This is what makes an
   irrelevant query match *nothing*: a relative gate alone (e.g. "the top half of the
   candidates", as min-max normalised relevance does) always finds something.
2. ``score >= relative * best[s]``: it is also close to the best hit *of its own sense* for
   this query (``relative`` = :data:`RELATIVE_KEEP`; 0 disables it). This drops near misses
   that share words or texture with the real thing ("picked up the screwdriver" for "picked
   up the mug") once the real thing is in the memory. Per sense, so a strong note never
   suppresses a weaker but genuine touch match.

How the defaults were chosen (measured, real MiniLM + the shipped touch checkpoint):

* text (MiniLM notes): exact notes score 6-9, paraphrases ("holding a coffee cup" for
  "picked up the mug") about 3.4, unrelated queries at most 1.6 (generic ones such as
  "an object" 1.2) -> 3.0, on a nine-note memory's own calibration. The near miss "picked up
  the screwdriver" scored 3.1 for "picked up the mug" against 8.6 for the real notes there,
  removed by the relative gate; with the shipped text prior (issue 46: young memories'
  scores stay put) the same memory gives 3.6 against 8.8 and the paraphrase 3.9: the near
  miss is at 0.41 of the best, just past the gate, and the answer rule
  (:data:`ANSWER_KEEP`) leaves it out of ``count``/``last``/``first``. How often a text match
  is right at 3.0: ``GET /senses``' ``precision_at_bar`` (``benchmarks/text_precision.py``).
* touch (all 1,445 8-frame windows of the STAG ``weights`` subset, grasps and transitions):
  seven unrelated queries ("the weather in paris", "stock market prices fell", ...) have a
  99th percentile of 1.3-2.2 and a maximum of 2.1-2.8 ("a giraffe in the savanna", closest
  to the toy cat, reaches 3.7); object queries on valid-grasp windows have medians 5.2-8.2
  -> 3.0. Grasp-level on the 162 valid grasps, 10 object queries, threshold 3.0: relative
  0 finds 92% of the grasps of the queried object and matches 2.4% of other objects'
  grasps; 0.4 finds 92% / matches 2.2%; 0.6 finds 87% / 0.8%. Occurrence counting must
  not miss grasps, so RELATIVE_KEEP = 0.4.

**Occurrences.** ``count`` / ``last`` / ``first`` work on occurrences: matching items of one
session whose (aligned) spans ``[t, t_end]`` overlap or lie within ``merge_gap`` seconds of
each other merge into one; adjacent windows of one stream (same session + sense + source)
are one occurrence, and a touch window with the note written about it is one too.

**Which occurrences answer.** Past the bar, several occurrences can remain that match
unequally well: for "picked up the mug", the note that says it (7.9) and later notes that
share its words ("picked up the cup from the shelf" 5.5, "put the mug down on the table"
4.2). ``count``/``last``/``first`` answer from the occurrences above the first clear break
in their scores, per sense (the sense of each occurrence's best member): that sense's
occurrence scores (a moment's: its best member's score plus the corroboration bonus), best
first, are cut where one is less than the ratio x the one above it, and those above the cut
answer. The ratio is :data:`ANSWER_KEEP` per sense (0.75 for text; 0, no cut, for touch and
the others), or ``answer=R`` for every sense; ``answer=0`` answers from every occurrence past
the bar (the rule before). Per sense, because a note that says it scores far above any
grasp and must not silence the grasps. ``last`` is the latest answering occurrence,
``first`` the earliest, ``count`` their number; ``Occurrences.passed`` still counts every
occurrence past the bar. Scores are calibrated z (positive past the bar), so the ratio is
scale-free. Measured: the checkpoints README, "Grasps and the answer rule".

**Candidates.** Each sense contributes at most :data:`MATCH_CANDIDATES` candidates (the top of
a prefiltered search): ``count`` over a long session with more matching windows than that is
a lower bound, and :class:`Occurrences` says so (``capped=True``); narrow it with
``after``/``before``.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Any

from tactus_memory.errors import InvalidInputError
from tactus_memory.names import validate_sense_name
from tactus_memory.query import Scope, ScopeKwargs, split_scope
from tactus_memory.results import Evidence, Hit, Moment
from tactus_memory.signatures import reject_unknown
from tactus_memory.where import check_sort, finite_float

# --------------------------------------------------------------------------- constants
#: per-sense match threshold on the calibrated score (z vs the probe null); see the module
#: docstring and tests/temporal/test_temporal_real.py for the measured separation behind each value
MATCH_Z: dict[str, float] = {"text": 3.0, "touch": 3.0}
#: the bar on a grasp's pooled score (touch answered by grasps, the default) where it differs
#: from MATCH_Z: pooling averages a grasp's transition windows in, so the right object's
#: pooled scores run lower than its best windows'. Measured on held-out STAG recordings
#: (benchmarks/answer_rule.py, 4 fold checkpoints, 81 queries each): grasps at 2.0 pass
#: 27 % of the queried object's grasps and 12 % of other objects' (windows at 3.0: 27 % and
#: 14 %); grasps at 3.0 pass only 13 % of the right ones
GRASP_MATCH_Z: dict[str, float] = {"touch": 2.5}
#: threshold for senses not in MATCH_Z (motion, image, ...)
DEFAULT_MATCH_Z = 3.0
#: a match must also score >= RELATIVE_KEEP x the best score of its sense for the query
RELATIVE_KEEP = 0.4
#: count/last/first answer from the occurrences above the first score step down to less than
#: ANSWER_KEEP[sense] x the score above it, per sense (see "Which occurrences answer"; 0 for
#: senses not listed: every occurrence past the bar answers). Text: the note that says it
#: (7.9) against later near misses (5.5, 4.3, 4.2; tests/search/test_answer_rule.py). Touch: three
#: real mug grasps score 7.3, 6.7 and 3.4 (tests/temporal/test_temporal_real.py), so no ratio tells
#: a
#: weak repeat from a near miss; touch relies on the bar alone.
ANSWER_KEEP: dict[str, float] = {"text": 0.75}
#: candidates pulled per sense before thresholding (the cap on count over long sessions)
MATCH_CANDIDATES = 500
#: occurrences: matching items within this many seconds of each other are one occurrence
DEFAULT_MERGE_GAP = 2.0
#: moments (search grouping): hits within this many seconds of each other are one moment
DEFAULT_MOMENT_GAP = 1.0
#: moment score = best member score + this bonus per other sense with a *matching* member
CORROBORATION_BONUS = 0.5
#: moments: candidates per sense = max(k * MOMENT_POOL_FACTOR, MOMENT_POOL_MIN) (<= MAX_K)
MOMENT_POOL_FACTOR = 5
MOMENT_POOL_MIN = 50
#: moments: a candidate joins a moment only if it scores above the sense's null mean by this
MOMENT_MIN_Z = 1.0
#: before/after: the default window (seconds)
DEFAULT_WINDOW = 30.0
#: the most rows one timeline (or one before/after window) reads; narrow with after/before
TIMELINE_MAX = 100_000


# --------------------------------------------------------------------------- the match bar
@dataclass(frozen=True)
class Match:
    """The match bar: ``threshold`` (None: per sense, MATCH_Z; a number: every sense; a
    mapping: those senses) and the ``relative`` gate (0 disables it)."""

    threshold: float | Mapping[str, float] | None = None
    relative: float = RELATIVE_KEEP
    answer: float | None = None  # the answer rule's ratio (None: ANSWER_KEEP per sense)


class MatchKwargs(ScopeKwargs, total=False):
    """The keyword spelling of a scope and a :class:`Match` (``memory.count(q, session=...)``):
    ``threshold`` and ``relative``, or one ``match=`` (as ``scope=`` is one Scope)."""

    threshold: float | Mapping[str, float] | None
    relative: float
    answer: float | None
    match: Match | None


def split_match(kw: Mapping[str, Any]) -> tuple[Scope, Match]:
    """Keyword arguments -> (Scope, Match); unknown keywords raise TypeError."""
    scope, rest = split_scope(kw)
    reject_unknown(rest, {"threshold", "relative", "answer", "match"})
    match = rest.pop("match", None) or Match()
    given = {k: v for k, v in rest.items() if v is not None}
    return scope, replace(match, **given) if given else match


# --------------------------------------------------------------------------- pure helpers
def resolve_thresholds(
    threshold: float | Mapping[str, float] | None, senses: Sequence[str]
) -> dict[str, float]:
    """Per-sense thresholds: MATCH_Z / DEFAULT_MATCH_Z, overridden by a number (every sense)
    or a mapping (those senses)."""
    out = {s: MATCH_Z.get(s, DEFAULT_MATCH_Z) for s in senses}
    if threshold is None:
        return out
    if isinstance(threshold, Mapping):
        for name, value in threshold.items():
            out[validate_sense_name(name)] = finite_float(value, f"threshold[{name}]")
        return out
    value = finite_float(threshold, "threshold")
    return dict.fromkeys(out, value)


def check_relative(relative: float) -> float:
    value = finite_float(relative, "relative")
    if not 0.0 <= value <= 1.0:
        raise InvalidInputError(f"relative must be in [0, 1], got {relative!r}")
    return value


def answering(moments: Sequence[Moment], answer: float | None = None) -> list[Moment]:
    """The occurrences that answer count/last/first (see "Which occurrences answer"): per
    sense (of each occurrence's best member), scores best first are cut at the first step
    down to less than the ratio x the score above it; the ones above the cut answer. The
    ratio: ``answer`` for every sense, or None: :data:`ANSWER_KEEP` per sense (0 elsewhere).
    Order (time) kept; a ratio of 0 keeps every one."""
    if answer is not None:
        answer = finite_float(answer, "answer")
        if not 0.0 <= answer <= 1.0:
            raise InvalidInputError(f"answer must be in [0, 1], got {answer!r}")
    by_sense: dict[str, list[float]] = {}
    for m in moments:
        by_sense.setdefault(_lead_sense(m), []).append(m.score)
    floor = {}
    for sense, values in by_sense.items():
        ratio = ANSWER_KEEP.get(sense, 0.0) if answer is None else answer
        scores = sorted(values, reverse=True)
        floor[sense] = scores[-1]
        for hi, lo in zip(scores, scores[1:], strict=False):
            if lo < ratio * hi:
                floor[sense] = hi
                break
    return [m for m in moments if m.score >= floor[_lead_sense(m)]]


def _lead_sense(m: Moment) -> str:
    """The sense of a moment's best member (its score's source)."""
    return next((h.sense for h in m.hits if h.id == m.best), m.senses[0] if m.senses else "")


def check_seconds(value: float, what: str) -> float:
    out = finite_float(value, what)
    if out < 0:
        raise InvalidInputError(f"{what} must be >= 0 seconds, got {value!r}")
    return out


def sense_bar(scores: Sequence[float], threshold: float, relative: float) -> float:
    """The score one sense's candidates need for a query: ``threshold`` and ``relative`` x
    the best of ``scores`` (that sense's candidates, best included)."""
    return max(threshold, relative * max(scores)) if scores else threshold


def match_flags(scores: Sequence[float], threshold: float, relative: float) -> list[bool]:
    """Which of one sense's scores match: ``>= threshold`` and ``>= relative * best``."""
    bar = sense_bar(scores, threshold, relative)
    return [s >= bar for s in scores]


def mark_matches(hits: Sequence[Hit], match: Match | None = None) -> list[Hit]:
    """``hits`` (one ranked list, best first) with ``match`` and ``bar`` set by the rule of
    the temporal operators. A sense's best candidate is in the list whenever any of its hits
    is (the list is sorted by score), so the relative gate sees the same best here."""
    match = match or Match()
    names = sorted({h.sense for h in hits})
    thresholds = resolve_thresholds(match.threshold, names)
    relative = check_relative(match.relative)
    bars = {
        name: sense_bar([h.score for h in hits if h.sense == name], thresholds[name], relative)
        for name in names
    }
    return [
        h.model_copy(update={"match": h.score >= bars[h.sense], "bar": bars[h.sense]}) for h in hits
    ]


def group_moments(
    evidence: Sequence[Evidence], gap: float, *, per_stream: bool = False
) -> list[Moment]:
    """Merge evidence of one session (``per_stream``: of one session + sense + source) whose
    aligned spans overlap or lie within ``gap`` seconds (transitively) into moments; returns
    them in time order (t, t_end, session)."""
    by_key: dict[tuple[str, ...], list[Evidence]] = {}
    for e in evidence:
        key: tuple[str, ...] = (e.session, e.sense, e.source) if per_stream else (e.session,)
        by_key.setdefault(key, []).append(e)
    out: list[Moment] = []
    for key in sorted(by_key):
        items = sorted(
            by_key[key],
            key=lambda e: (e.t_aligned, e.t_end_aligned, e.sense, e.source, e.id),
        )
        group: list[Evidence] = []
        end = -math.inf
        for e in items:
            if group and e.t_aligned > end + gap:
                out.append(make_moment(group))
                group = []
            group.append(e)
            end = max(end, e.t_end_aligned) if len(group) > 1 else e.t_end_aligned
        if group:
            out.append(make_moment(group))
    out.sort(key=lambda m: (m.t, m.t_end, m.session))
    return out


def make_moment(hits: Sequence[Evidence]) -> Moment:
    """One moment from its members (see :class:`Moment` for the score)."""
    best = min(hits, key=lambda e: (-e.score, e.t_aligned, e.id))  # ties: the earliest
    corroborating = {e.sense for e in hits if e.match and e.sense != best.sense}
    placed = [e for e in hits if e.position is not None]
    where = min(placed, key=lambda e: (-e.score, e.t_aligned, e.id)) if placed else None
    return Moment(
        session=best.session,
        t=min(e.t_aligned for e in hits),
        t_end=max(e.t_end_aligned for e in hits),
        score=best.score + CORROBORATION_BONUS * len(corroborating),
        senses=sorted({e.sense for e in hits}),
        best=best.id,
        hits=list(hits),
        position=None if where is None else where.position,
        frame=None if where is None else where.frame,
    )


class OccurrenceKwargs(MatchKwargs, total=False):
    """``count``/``last``/``first`` keywords: the scope, the match bar, ``merge_gap``,
    ``per_stream``, ``group="grasp"`` with its ``pool`` (grasps.POOLS), and ``sort`` (the
    occurrences' order, :mod:`tactus_memory.search.ordering`: ``first``/``last`` are the ends
    of that order, ``count`` is the same whatever the order)."""

    merge_gap: float
    per_stream: bool
    group: str | None
    pool: str
    sort: str | None


class AroundKwargs(MatchKwargs, total=False):
    """``before``/``after`` keywords: the scope and match bar, and where the anchor is
    searched (``anchor_senses``; default: every sense with rows)."""

    anchor_senses: Sequence[str] | None


def grasp_params(kw: dict[str, Any]) -> dict[str, Any]:
    """The grasp and order keywords (``group``, ``pool``, ``sort``) popped from ``kw``, as the
    service's query parameters (the remote Client's questions; ``sort`` checked here)."""
    check_sort(kw.get("sort"))
    popped = {k: kw.pop(k, None) for k in ("group", "pool", "sort")}
    return {k: v for k, v in popped.items() if v is not None}
