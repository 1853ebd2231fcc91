"""The memory's API as one typed contract: what :class:`~tactus_memory.memory.main.Memory` (in
process) and :class:`~tactus_memory.client.main.Client` (over the service's HTTP) both answer,
with the same names, arguments and results.

``MemoryAPI`` is a :class:`typing.Protocol`: both classes implement it structurally, and the
type checker (``make lint``: mypy on the package) checks each against it where the class is
defined (``_: type[MemoryAPI] = Memory``). ``tests/client/test_client_parity.py`` still runs one
scenario against both, for the answers themselves. ``Memory`` offers more than this (writes with
a place, search by raw vector, maintenance, re-embedding): those are its own.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any, Protocol, runtime_checkable

import numpy as np
from typing_extensions import Unpack

from tactus_memory.batches import AddKwargs, WriteKwargs
from tactus_memory.matching import AroundKwargs, MatchKwargs, OccurrenceKwargs
from tactus_memory.query import ScopeKwargs, TeachSpan, TimelineKwargs
from tactus_memory.results import (
    ClockOffset,
    Context,
    Episode,
    Grasp,
    Hit,
    Moment,
    Occurrences,
    SenseInfo,
    SessionSummary,
    Teaching,
    Timeline,
)
from tactus_memory.senses.base import Sense


@runtime_checkable
class MemoryAPI(Protocol):
    """A robot memory, local or remote: write, search, ask when, teach."""

    # ----------------------------------------------------------- writes
    def add(self, session: str, sense: str, item: Any, **kw: Unpack[AddKwargs]) -> str:
        """Remember one item; returns its id."""
        ...

    def add_many(
        self, session: str, sense: str, items: Sequence[Any], **kw: Unpack[WriteKwargs]
    ) -> list[str]:
        """Remember N items of one sense; returns their ids, in order."""
        ...

    def add_sense(self, sense: Sense) -> None:
        """Register a sense."""
        ...

    def delete_session(self, session: str) -> int:
        """Delete every item of a session; returns how many."""
        ...

    # ----------------------------------------------------------- search
    def search(
        self,
        query: str,
        k: int = 10,
        *,
        group: str | None = ...,
        gap: float | None = None,
        pool: str = "mean",
        **scope: Unpack[ScopeKwargs],
    ) -> list[Hit] | list[Moment] | list[Grasp]:
        """Natural-language search."""
        ...

    def search_moments(
        self, query: str, k: int = 10, *, sort: str | None = None, **kw: Unpack[MatchKwargs]
    ) -> list[Moment]:
        """Search grouped into moments (``sort``: by a touch facet or time)."""
        ...

    def search_like(
        self,
        sense: str,
        example: Any = None,
        k: int = 10,
        *,
        vector: np.ndarray | Sequence[float] | None = None,
        options: Mapping[str, Any] | None = None,
        **scope: Unpack[ScopeKwargs],
    ) -> list[Hit]:
        """Query by example."""
        ...

    # ----------------------------------------------------------- temporal questions
    def occurrences(self, query: str, **kw: Unpack[OccurrenceKwargs]) -> Occurrences:
        """Distinct occurrences of ``query``."""
        ...

    def count(self, query: str, **kw: Unpack[OccurrenceKwargs]) -> int:
        """How many distinct times ``query`` happened."""
        ...

    def last(self, query: str, **kw: Unpack[OccurrenceKwargs]) -> Moment | None:
        """The most recent occurrence of ``query``, or None."""
        ...

    def first(self, query: str, **kw: Unpack[OccurrenceKwargs]) -> Moment | None:
        """The earliest occurrence of ``query``, or None."""
        ...

    def before(
        self, anchor: str, window: float = ..., **kw: Unpack[AroundKwargs]
    ) -> Context | None:
        """What happened in the ``window`` seconds before the best match of ``anchor``."""
        ...

    def after(self, anchor: str, window: float = ..., **kw: Unpack[AroundKwargs]) -> Context | None:
        """What happened in the ``window`` seconds after the best match of ``anchor``."""
        ...

    def timeline(self, session: str, **kw: Unpack[TimelineKwargs]) -> Timeline:
        """The session's items or episodes in aligned time order."""
        ...

    def episodes(
        self, session: str, *, senses: Sequence[str] | None = None, source: str | None = None
    ) -> list[Episode]:
        """The session's episodes in aligned time order."""
        ...

    def segment_episodes(self, session: str) -> int:
        """Segment a session's streams into stored episodes; returns how many."""
        ...

    def set_clock_offset(self, session: str, sense: str, offset: float, source: str = "") -> None:
        """Place the stream (session, sense, source) at ``t + offset`` on the session clock."""
        ...

    def clock_offsets(self, session: str) -> list[ClockOffset]:
        """The session's clock offsets."""
        ...

    # ----------------------------------------------------------- teaching
    def teach(self, label: str, *, session: str, **span: Unpack[TeachSpan]) -> Teaching:
        """Teach ``label`` from the windows of a span of ``session``."""
        ...

    def taught(self, sense: str | None = None) -> list[Teaching]:
        """Every teaching (of ``sense``)."""
        ...

    def forget(self, label: str | None = None, *, id: str | None = None) -> int:  # noqa: A002
        """Delete the teachings of ``label`` (or the one ``id``); returns how many."""
        ...

    # ----------------------------------------------------------- sessions, senses
    def sessions(self) -> list[SessionSummary]:
        """A summary per session, sorted by id."""
        ...

    def session(self, session: str) -> SessionSummary:
        """One session's summary."""
        ...

    def session_ids(self) -> list[str]:
        """Every session id, sorted."""
        ...

    def sense_info(self) -> list[SenseInfo]:
        """Every sense the store knows."""
        ...

    def close(self) -> None:
        """Release what the memory holds."""
        ...
