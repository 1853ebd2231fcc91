"""Hits put in order by a touch facet instead of their score (``search(q, sort="-force")``):
the question chooses the candidates (the :data:`SORT_CANDIDATES` best hits in scope), the
facet orders them, the first ``k`` are the answer. "The firmest grasp of session S" is
``search("holding something", session="S", sort="-force", k=1)``.

Hits without facets (other senses, rows stored before facets) come after those with, in
their score order; ``t``/``-t`` order by start time (aligned when the hit has it).

A moment (``group="moment"``, ``search_moments``, the occurrences of ``count``/``last``/
``first``) is ordered by its touch members: its ``force`` (``area``) is the highest of its
members' (as a grasp's is the highest of its windows'), so ``sort="force"`` puts the moment
whose firmest touch is lightest first; a moment without a touch member with facets comes
last."""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING, Any, TypeVar

from tactus_memory.limits import MAX_K
from tactus_memory.query import Scope
from tactus_memory.storage.tables import check_facet_columns
from tactus_memory.where import check_sort

if TYPE_CHECKING:
    import pyarrow as pa

#: how many best hits a sorted search orders by the facet (the question's candidates)
SORT_CANDIDATES = MAX_K // 4

H = TypeVar("H")


def check_order(sort: str | None, scope: Scope, schema: pa.Schema) -> None:
    """An unknown ``sort``, or a facet filter or order on a store without facet columns
    (``schema``, the items table's), raises InvalidInputError
    (``storage.tables.check_facet_columns``)."""
    if scope.faceted or (check_sort(sort) or "t").lstrip("-") != "t":
        check_facet_columns(schema)


def candidates(k: int, sort: str | None, scope: Scope, schema: pa.Schema) -> int:
    """How many hits to ask for: ``k``, or :data:`SORT_CANDIDATES` (at least k) when sorted
    (:func:`check_order` first)."""
    check_order(sort, scope, schema)
    return k if sort is None else max(k, SORT_CANDIDATES)


def _key(hit: Any, sort: str) -> tuple[int, float]:
    name = sort.lstrip("-")
    sign = -1.0 if sort.startswith("-") else 1.0
    if name == "t":
        t = getattr(hit, "t_aligned", None)
        return 0, sign * float(hit.t if t is None else t)
    value = facet_value(hit, name)
    return (1, 0.0) if value is None else (0, sign * float(value))


def facet_value(hit: Any, name: str) -> float | None:
    """A hit's (grasp's, window's) facet ``name``; a moment's: the highest of its members'
    (None: no member has it)."""
    members = getattr(hit, "hits", None)
    if members is not None:  # a Moment
        values = [v for v in (facet_value(m, name) for m in members) if v is not None]
        return max(values) if values else None
    value = (getattr(hit, "facets", None) or {}).get(name)
    return None if value is None else float(value)


def sort_hits(hits: Sequence[H], sort: str | None, k: int) -> list[H]:
    """``hits`` (best first) in ``sort`` order (None: as they are), the first ``k``."""
    if check_sort(sort) is None:
        return list(hits)[:k]
    order = sorted(range(len(hits)), key=lambda i: (*_key(hits[i], sort), i))  # type: ignore[arg-type]
    return [hits[i] for i in order[:k]]
