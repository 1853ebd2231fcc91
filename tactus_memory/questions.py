"""The temporal questions in the memory's keyword API: ``memory.count(q, session="s1")``,
``memory.last(...)``, ``memory.timeline(...)`` ... Each turns its keywords into one
:class:`~tactus_memory.query.Scope` and one :class:`~tactus_memory.matching.Match` and asks
the :class:`~tactus_memory.temporal.Temporal` object; ``Memory`` inherits these methods.
"""

from __future__ import annotations

from collections.abc import Sequence

from typing_extensions import Unpack

from tactus_memory.episodes import Episode
from tactus_memory.matching import MatchKwargs, split_match
from tactus_memory.query import Scope, embed_query
from tactus_memory.spaces.base import Space
from tactus_memory.store import validate_id
from tactus_memory.temporal import (
    DEFAULT_MERGE_GAP,
    DEFAULT_MOMENT_GAP,
    DEFAULT_WINDOW,
    ClockOffset,
    Context,
    Evidence,
    Moment,
    Occurrences,
    Side,
    Temporal,
    TimelineItem,
)
from tactus_memory.where import Near


class OccurrenceKwargs(MatchKwargs, total=False):
    """``occurrences``/``count`` keywords: the scope, the match bar, ``merge_gap`` and
    ``per_stream``."""

    merge_gap: float
    per_stream: bool


class AroundKwargs(MatchKwargs, total=False):
    """``before``/``after`` keywords: the scope and match bar, and where the anchor is
    searched (``anchor_senses``; default: every sense with rows)."""

    anchor_senses: Sequence[str] | None


class TemporalQuestions:
    """Keyword front of :class:`~tactus_memory.temporal.Temporal` (see there for each rule).

    Keywords: the scope (``session``, ``senses``, ``source``, ``after``, ``before``, or one
    ``scope=``) and the match bar (``threshold``, ``relative``)."""

    temporal: Temporal
    space: Space

    def matches(self, query: str, **kw: Unpack[MatchKwargs]) -> list[Evidence]:
        """Every item matching ``query`` (see :mod:`tactus_memory.matching`), in aligned time
        order. Keywords: the scope (session, senses, source, after, before, or ``scope=``)
        and the match bar (``threshold``, ``relative``)."""
        return self.temporal.matches(query, *split_match(kw))

    def occurrences(
        self,
        query: str,
        *,
        merge_gap: float = DEFAULT_MERGE_GAP,
        per_stream: bool = False,
        **kw: Unpack[MatchKwargs],
    ) -> Occurrences:
        """Distinct occurrences of ``query`` (see :meth:`Temporal.occurrences`)."""
        scope, match = split_match(kw)
        return self.temporal.occurrences(query, scope, match, merge_gap, per_stream)

    def count(self, query: str, **kw: Unpack[OccurrenceKwargs]) -> int:
        """How many distinct times ``query`` happened (see :meth:`occurrences`)."""
        return self.occurrences(query, **kw).count

    def last(
        self, query: str, *, merge_gap: float = DEFAULT_MERGE_GAP, **kw: Unpack[MatchKwargs]
    ) -> Moment | None:
        """The most recent occurrence of ``query`` (latest aligned start), or None."""
        moments = self.occurrences(query, merge_gap=merge_gap, **kw).moments
        return moments[-1] if moments else None

    def first(
        self, query: str, *, merge_gap: float = DEFAULT_MERGE_GAP, **kw: Unpack[MatchKwargs]
    ) -> Moment | None:
        """The earliest occurrence of ``query`` (earliest aligned start), or None."""
        moments = self.occurrences(query, merge_gap=merge_gap, **kw).moments
        return moments[0] if moments else None

    def before(
        self, anchor: str, window: float = DEFAULT_WINDOW, **kw: Unpack[AroundKwargs]
    ) -> Context | None:
        """What happened in the ``window`` seconds before the best match of ``anchor``
        (searched in ``anchor_senses``; see :meth:`Temporal.around`)."""
        return self._around("before", anchor, window, kw)

    def after(
        self, anchor: str, window: float = DEFAULT_WINDOW, **kw: Unpack[AroundKwargs]
    ) -> Context | None:
        """What happened in the ``window`` seconds after the best match of ``anchor``
        (searched in ``anchor_senses``; see :meth:`Temporal.around`)."""
        return self._around("after", anchor, window, kw)

    def _around(self, side: Side, anchor: str, window: float, kw: AroundKwargs) -> Context | None:
        rest = dict(kw)
        anchor_senses = rest.pop("anchor_senses", None)
        scope, match = split_match(rest)
        return self.temporal.around(side, anchor, window, scope, match, anchor_senses)

    def search_moments(
        self, query: str, k: int = 10, *, gap: float = DEFAULT_MOMENT_GAP, **kw: Unpack[MatchKwargs]
    ) -> list[Moment]:
        """Search grouped into moments (see :meth:`Temporal.moments`)."""
        scope, match = split_match(kw)
        return self.temporal.moments(embed_query(self.space, query), k, scope, match, gap)

    def timeline(
        self,
        session: str,
        senses: Sequence[str] | None = None,
        after: float | None = None,
        before: float | None = None,
        episodes: bool = False,
        *,
        source: str | None = None,
        limit: int | None = None,
        near: Near | None = None,
        frame: str | None = None,
    ) -> list[TimelineItem] | list[Episode]:
        """The session's items (or, with ``episodes=True``, its episodes) in aligned time
        order; ``after``/``before`` use overlap semantics on the aligned clock, ``near`` /
        ``frame`` keep the items placed there (not episodes). Raises
        NotFoundError for an unknown session."""
        session = validate_id(session, "session id")
        scope = Scope(
            session=session, senses=senses, source=source, after=after, before=before,
            near=near, frame=frame,
        )  # fmt: skip
        return self.temporal.timeline(scope, episodes, limit)

    def segment_episodes(self, session: str | None = None, **rule: float) -> int:
        """Segment streams into stored episodes; ``rule``: ``min_cos``, ``mean_cos``,
        ``max_gap`` (see :meth:`Temporal.segment_episodes`)."""
        return self.temporal.segment_episodes(session, **rule)

    def episodes(
        self, session: str, *, senses: Sequence[str] | None = None, source: str | None = None
    ) -> list[Episode]:
        """The session's episodes in aligned time order (segmenting it first if needed)."""
        return self.temporal.episodes(session, senses=senses, source=source)

    def set_clock_offset(self, session: str, sense: str, offset: float, source: str = "") -> None:
        """Place the stream (session, sense, source) at ``t + offset`` on the session clock."""
        self.temporal.set_clock_offset(session, sense, offset, source)

    def clock_offsets(self, session: str | None = None) -> list[ClockOffset]:
        """Every recorded clock offset (of one session), sorted."""
        return self.temporal.clock_offsets(session)
