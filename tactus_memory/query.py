"""What a search is asked with: the query checks, the k limit, one ``embed_query``, and the
:class:`Scope` (session, senses, source, after, before, near, frame) every search and
temporal operator takes. ``Memory.search``, the temporal operators and both HTTP routers
build one Scope and pass it down; nothing re-spells the filters.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, fields, replace
from typing import TYPE_CHECKING, Any, TypedDict

import numpy as np

from tactus_memory.errors import InvalidInputError
from tactus_memory.limits import MAX_K, MAX_TEXT_CHARS
from tactus_memory.signatures import reject_unknown
from tactus_memory.times import check_time
from tactus_memory.vectors import as_unit_rows
from tactus_memory.where import Near, Where

if TYPE_CHECKING:
    from tactus_memory.spaces.base import Space


def check_k(k: Any) -> int:
    """An int in [1, MAX_K] (bools and floats rejected)."""
    if isinstance(k, bool) or not isinstance(k, (int, np.integer)) or not 1 <= k <= MAX_K:
        raise InvalidInputError(f"k must be an int in [1, {MAX_K}], got {k!r}")
    return int(k)


def check_query_text(query: Any) -> str:
    """A non-empty string of at most MAX_TEXT_CHARS characters."""
    if not isinstance(query, str) or not query.strip():
        raise InvalidInputError("query must be a non-empty string")
    if len(query) > MAX_TEXT_CHARS:
        raise InvalidInputError(f"query has {len(query)} characters, limit {MAX_TEXT_CHARS}")
    return query


def embed_query(space: Space, query: str) -> np.ndarray:
    """The checked query text -> its (1, D) unit query embedding in ``space``."""
    text = check_query_text(query)
    return as_unit_rows(space.embed_texts([text], query=True), space.dim, what="query")


class ScopeKwargs(TypedDict, total=False):
    """The keyword spelling of a :class:`Scope` (``memory.search(q, session=..., ...)``)."""

    scope: Scope | None
    session: str | None
    senses: Sequence[str] | None
    source: str | None
    after: float | None
    before: float | None
    near: Near | None
    frame: str | None


@dataclass(frozen=True)
class Scope:
    """Where a search or temporal question looks: a session, senses (None: every sense with
    rows), a source (stream) id, and ``after``/``before`` with overlap semantics (an item
    spanning ``[t, t_end]`` is in scope when ``t_end >= after`` and ``t <= before``), and a
    place: ``near=((x, y, z), radius)`` keeps items placed within ``radius`` metres of the
    point (unplaced items never match), ``frame`` items placed in that frame."""

    session: str | None = None
    senses: Sequence[str] | None = None
    source: str | None = None
    after: float | None = None
    before: float | None = None
    near: Near | None = None
    frame: str | None = None

    @classmethod
    def of(cls, scope: Scope | None = None, **kw: Any) -> Scope:
        """``scope`` (default: everything) with the filter keywords given (non-None) applied.
        Unknown keywords raise TypeError, as a misspelt keyword argument would."""
        reject_unknown(kw, {f.name for f in fields(cls)})
        base = scope if scope is not None else cls()
        given = {k: v for k, v in kw.items() if v is not None}
        return replace(base, **given) if given else base

    def keywords(self) -> dict[str, Any]:
        """Every field but the session, as keywords (``memory.timeline(session, **kw)``)."""
        return {f.name: getattr(self, f.name) for f in fields(self) if f.name != "session"}

    def bounds(self) -> tuple[float | None, float | None]:
        """``(after, before)`` as finite floats, checked in order."""
        after = None if self.after is None else check_time(self.after, "after")
        before = None if self.before is None else check_time(self.before, "before")
        if after is not None and before is not None and after > before:
            raise InvalidInputError(f"after ({after}) is later than before ({before})")
        return after, before

    def where(self, pad: float = 0.0) -> Where:
        """The non-sense conditions as a store filter; ``pad`` widens the time bounds (so a
        stream placed on the session clock by a clock offset of at most ``pad`` is not
        missed)."""
        after, before = self.bounds()
        return (
            Where()
            .session(self.session)
            .overlaps(
                None if after is None else after - pad, None if before is None else before + pad
            )
            .source(self.source)
            .near(self.near)
            .frame(self.frame)
        )


class TimelineKwargs(TypedDict, total=False):
    """The keywords of ``timeline`` (the memory's and the client's): the senses, ``after`` /
    ``before`` (overlap semantics on the aligned clock), ``episodes`` (episodes instead of
    items), the source (stream) id, the place (``near``/``frame``, items only) and ``limit``
    (keep the first N)."""

    senses: Sequence[str] | None
    after: float | None
    before: float | None
    episodes: bool
    source: str | None
    limit: int | None
    near: Near | None
    frame: str | None


def timeline_scope(session: str | None, kw: Mapping[str, Any]) -> tuple[Scope, int | None]:
    """A ``timeline`` call's keywords -> (its Scope, its checked ``limit``). Unknown keywords
    raise TypeError (as a misspelt keyword would); a limit that is not a positive int raises
    InvalidInputError."""
    reject_unknown(kw, TimelineKwargs.__annotations__)
    limit = kw.get("limit")
    if limit is not None and (isinstance(limit, bool) or not isinstance(limit, int) or limit < 1):
        raise InvalidInputError(f"limit must be a positive int, got {limit!r}")
    names = ("senses", "source", "after", "before", "near", "frame")
    return Scope(session, *(kw.get(name) for name in names)), limit


class TeachSpan(TypedDict, total=False):
    """The span a ``teach`` marks (the memory's and the client's): the ``sense`` windows
    (default touch) overlapping ``[after, before]`` (either open)."""

    after: float | None
    before: float | None
    sense: str


def teach_span(span: Mapping[str, Any]) -> tuple[float | None, float | None, str]:
    """A ``teach`` call's span keywords -> ``(after, before, sense)``; others raise
    InvalidInputError naming them."""
    unknown = sorted(set(span) - set(TeachSpan.__annotations__))
    if unknown:
        raise InvalidInputError(f"teach takes after, before and sense, not {unknown}")
    after, before = span.get("after"), span.get("before")
    return (
        None if after is None else check_time(after, "after"),
        None if before is None else check_time(before, "before"),
        span.get("sense", "touch"),
    )


def split_scope(kw: Mapping[str, Any]) -> tuple[Scope, dict[str, Any]]:
    """Keyword arguments -> (the Scope they describe, the remaining keywords)."""
    names = {f.name for f in fields(Scope)} | {"scope"}
    scope_kw = {k: v for k, v in kw.items() if k in names}
    rest = {k: v for k, v in kw.items() if k not in names}
    return Scope.of(**scope_kw), rest
