"""A question's evidence in one pass: the Ranker, then the grouping step.

Every question that flags matches per sense (``search`` with ``group="auto"`` or ``"grasp"``,
moments, ``last``/``first``/``count``/``occurrences``, the anchor of ``before``/``after``,
``where``) asks :func:`ranked_evidence`:

1. **Rank** (:meth:`~tactus_memory.search.ranking.Ranker.rank`, ``each=True``): one call
   for every sense in scope, each sense its own top ``per_sense`` at its own query
   transform, the senses asked at once.
2. **Align**: each hit placed on its stream's session clock (``offsets``, the clock offsets
   of :mod:`tactus_memory.temporal.clocks`, passed in).
3. **Group**: the senses the :class:`~tactus_memory.search.grasps.GraspRule` groups (touch,
   by default) are answered by the grasps holding their hits, scored by the rule's pool
   (:func:`~tactus_memory.search.grasps.pool_grasps`).

The match bars and time logic that follow are the caller's
(:meth:`tactus_memory.temporal.operators.Temporal._scored`, :mod:`tactus_memory.matching`).
``search(group="window")`` asks the same Ranker for the merged top k instead (one call too).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from tactus_memory.results import Evidence, Hit
from tactus_memory.search.grasps import GraspRule, pool_grasps
from tactus_memory.search.ranking import Ranker
from tactus_memory.where import Where

#: a stream's clock offset, seconds: (session, sense, source) -> offset
Offsets = Mapping[tuple[str, str, str], float]


@dataclass
class SenseEvidence:
    """One sense's answer to a question: its evidence, best first."""

    sense: str
    #: hits the Ranker gave this sense (at most ``per_sense``; before grouping)
    ranked: int
    #: the hits as Evidence (aligned times), or the grasps holding them when ``grouped``
    evidence: list[Evidence]
    #: grasps scored by the rule's pool, not single items
    grouped: bool


def aligned(h: Hit, offsets: Offsets) -> Evidence:
    """A ranked hit as Evidence, its span on its stream's session clock."""
    off = offsets.get((h.session, h.sense, h.source), 0.0)
    return Evidence(
        **h.model_dump(exclude={"score", "cosine", "match", "bar"}),
        t_aligned=h.t + off,
        t_end_aligned=h.t_end + off,
        score=h.score,
        cosine=h.cosine,
    )


def ranked_evidence(
    ranker: Ranker,
    q: np.ndarray,
    names: Sequence[str],
    base: Where,
    per_sense: int,
    offsets: Offsets,
    rule: GraspRule | None = None,
) -> list[SenseEvidence]:
    """The (1, D) query ``q``'s evidence in every sense of ``names`` (in that order), one
    Ranker pass (see the module docstring); ``base`` holds the question's non-sense
    conditions; ``rule`` (None: items only) groups its senses' hits into grasps."""
    hits = ranker.rank(q, per_sense, names, base, transform=True, each=True)
    by_sense: dict[str, list[Hit]] = {name: [] for name in names}
    for h in hits:  # best first; each sense's hits in the order its own ranking gave
        by_sense[h.sense].append(h)
    out = []
    for name in names:
        evs = [aligned(h, offsets) for h in by_sense[name]]
        grouped = rule is not None and rule.applies(ranker.registry.search_sense(name).modality)
        if grouped:
            assert rule is not None  # for the type checker: grouped implies a rule
            evs = [*pool_grasps(ranker, q, name, evs, rule)]  # a Grasp is Evidence
        out.append(SenseEvidence(name, len(by_sense[name]), evs, grouped))
    return out
