"""Validated store filters: the id / source / number validators and :class:`Where`, the
one builder of SQL ``WHERE`` fragments (every value passes a validator first; string
literals are also quote-escaped; no user string reaches LanceDB any other way)."""

from __future__ import annotations

import math
import re
import unicodedata
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager
from contextvars import ContextVar
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from tactus_memory.errors import InvalidInputError
from tactus_memory.limits import MAX_COORDINATE
from tactus_memory.names import validate_id, validate_sense_name


# --------------------------------------------------------------------------- validation
def refuse_format_chars(value: str, what: str) -> str:
    """``value`` unless it holds a Unicode format character (category Cf: a bidi override,
    a zero-width space...), which makes a name a person reads display as another one."""
    bad = [ch for ch in value if unicodedata.category(ch) == "Cf"]
    if bad:
        shown = ", ".join(f"U+{ord(ch):04X}" for ch in dict.fromkeys(bad))
        raise InvalidInputError(
            f"{what} {value!r} holds invisible format characters ({shown}: bidi overrides, "
            "zero-width spaces); send the name without them"
        )
    return value


def validate_source(value: Any) -> str:
    """A source (stream) id is an id or the empty string."""
    if value == "":
        return ""
    return validate_id(value, "source id")


def finite_float(value: Any, what: str) -> float:
    """A finite float (bools and non-numbers rejected)."""
    if isinstance(value, bool):
        raise InvalidInputError(f"{what} must be a number, got {value!r}")
    try:
        out = float(value)
    except (TypeError, ValueError):
        raise InvalidInputError(f"{what} must be a number, got {value!r}") from None
    if not math.isfinite(out):
        raise InvalidInputError(f"{what} must be finite, got {value!r}")
    return out


#: grip names a touch facet takes (tactus_memory.touch.facets: the rule that gives them)
GRIPS = ("none", "power", "press", "pinch", "tripod", "other")
#: orders a search's hits may be put in by a facet instead of the score: ``force``/``area``
#: ascending, ``-force``/``-area`` descending, ``t``/``-t`` by time
SORTS = ("force", "-force", "area", "-area", "t", "-t")
#: a region or pad name in a facet filter (``regions=thumb,index``)
REGION_RE = re.compile(r"[A-Za-z0-9_-]{1,64}")
#: a comma-separated list of region names, as a query string takes it (no spaces)
REGIONS_PATTERN = r"^[A-Za-z0-9_-]{1,64}(,[A-Za-z0-9_-]{1,64})*$"


def check_regions(value: Any) -> tuple[str, ...] | None:
    """Region names, as a sequence or one comma-separated string (``"thumb,index"``)."""
    if value is None:
        return None
    names = value.split(",") if isinstance(value, str) else list(value)
    for n in names:
        if not isinstance(n, str) or not REGION_RE.fullmatch(n):
            raise InvalidInputError(
                f"region names are 1-64 chars of [A-Za-z0-9_-] (thumb, index, palm, a pad's "
                f"name), got {n!r}"
            )
    if not names:
        raise InvalidInputError("regions needs at least one region name")
    return tuple(names)


def check_grip(value: Any) -> str | None:
    if value is not None and value not in GRIPS:
        raise InvalidInputError(f"unknown grip {value!r}; use one of {', '.join(GRIPS)}")
    return value


def check_sort(value: Any) -> str | None:
    if value is not None and value not in SORTS:
        raise InvalidInputError(f"unknown sort {value!r}; use one of {', '.join(SORTS)}")
    return value


#: the frame positions are in unless one is named (REP 105's world-fixed frame)
DEFAULT_FRAME = "map"
#: a place filter: ``((x, y, z), radius)``, metres in the items' frame
Near = tuple[tuple[float, float, float], float]


def check_position(value: Any, what: str = "position") -> tuple[float, float, float]:
    """Three finite numbers ``(x, y, z)``."""
    if isinstance(value, (str, bytes)) or not hasattr(value, "__len__") or len(value) != 3:
        raise InvalidInputError(f"{what} must be three numbers (x, y, z), got {value!r}")
    x, y, z = (finite_float(v, f"{what} coordinate") for v in value)
    if max(abs(x), abs(y), abs(z)) > MAX_COORDINATE:
        raise InvalidInputError(f"{what} is beyond +-{MAX_COORDINATE:g} m: {value!r}")
    return x, y, z


def check_near(near: Any) -> Near:
    """``((x, y, z), radius)`` with finite coordinates and a finite radius > 0."""
    if isinstance(near, (str, bytes)) or not hasattr(near, "__len__") or len(near) != 2:
        raise InvalidInputError(f"near must be ((x, y, z), radius), got {near!r}")
    center = check_position(near[0], "near centre")
    radius = finite_float(near[1], "near radius")
    if not 0 < radius <= MAX_COORDINATE:
        raise InvalidInputError(
            f"near radius must be > 0 and <= {MAX_COORDINATE:g}, got {radius!r}"
        )
    return center, radius


def validate_frame(value: Any) -> str:
    """A frame name (``map``, ``odom``, ...): an id, one leading ``/`` dropped (ROS 1 style)."""
    if isinstance(value, str) and value.startswith("/"):
        value = value[1:]
    return validate_id(value, "frame")


def _sql_str(value: str) -> str:
    return "'" + value.replace("'", "''") + "'"


def _sql_float(value: float) -> str:
    # ``repr`` gives the shortest round-tripping form; DataFusion parses 1e+20 and -0.0 too.
    return repr(float(value))


def _session_id(value: Any) -> str:
    return validate_id(value, "session id")


def _item_id(value: Any) -> str:
    return validate_id(value, "item id")


@dataclass
class Where:
    """A conjunction of validated conditions, rendered to one LanceDB SQL filter.

    Build with the methods (each validates its input) and render with :meth:`sql`.
    Temporal operators reuse this: ``Where().session("s1").overlaps(10, 20).sql()``.
    """

    parts: list[str] = field(default_factory=list)
    #: conditions checked only on the rows ``parts`` let through (a place filter's sphere,
    #: after its indexed box); :meth:`count_sql` leaves them out to estimate cheaply
    refine: list[str] = field(default_factory=list)
    #: the rows that pass are scattered over the table (a place filter): reading each one's
    #: vector for an exact scan costs more than the ANN index's prefiltered search
    scattered: bool = False
    #: a part -> what :meth:`count_sql` counts instead: ``t_end >= after`` (no index
    #: answers it; a BTREE on t_end intersected with t's costs more still) is counted as
    #: ``t >= after``, the items that start in the window (benchmarks/search_1m.py)
    estimate: dict[str, str] = field(default_factory=dict)
    #: the time window's lower bound (:meth:`overlaps`), for :meth:`narrowed`
    after: float | None = None

    def copy(self) -> Where:
        out = Where(list(self.parts), list(self.refine), self.scattered, dict(self.estimate))
        out.after = self.after
        return out

    def narrowed(self, longest: float) -> Where:
        """A copy that also asks ``t >= after - longest`` when a time window has a lower
        bound: the same rows when no item lasts longer than ``longest`` seconds
        (:class:`tactus_memory.storage.spans.Spans`), a range the ``t`` index answers."""
        out = self.copy()
        if self.after is not None:
            bound = finite_float(self.after - finite_float(longest, "longest"), "after")
            out.parts.append(f"t >= {_sql_float(bound)}")
        return out

    def _eq(self, column: str, value: str | None, check: Callable[[Any], str | None]) -> Where:
        checked = None if value is None else check(value)
        if checked is not None:
            self.parts.append(f"{column} = {_sql_str(checked)}")
        return self

    def _in(self, column: str, values: Iterable[str] | None, check: Callable[[Any], str]) -> Where:
        if values is not None:
            vals = [_sql_str(check(v)) for v in values]
            self.parts.append(f"{column} IN ({', '.join(vals)})" if vals else "false")
        return self

    def session(self, session: str | None) -> Where:
        return self._eq("session", session, _session_id)

    def sessions(self, sessions: Iterable[str] | None) -> Where:
        return self._in("session", sessions, _session_id)

    def session_prefix(self, prefix: str | None) -> Where:
        """Sessions whose id starts with ``prefix`` (itself an id)."""
        if prefix is not None:
            self.parts.append(f"starts_with(session, {_sql_str(validate_session_prefix(prefix))})")
        return self

    def sense(self, sense: str | None) -> Where:
        return self._eq("sense", sense, validate_sense_name)

    def senses(self, senses: Iterable[str] | None) -> Where:
        return self._in("sense", senses, validate_sense_name)

    def ids(self, ids: Iterable[str] | None) -> Where:
        return self._in("id", ids, _item_id)

    def source(self, source: str | None) -> Where:
        return self._eq("source", source, validate_source)

    def episode(self, episode: int | None) -> Where:
        if episode is not None:
            if isinstance(episode, bool) or not isinstance(episode, (int, np.integer)):
                raise InvalidInputError(f"episode must be an int, got {episode!r}")
            self.parts.append(f"episode = {int(episode)}")
        return self

    def overlaps(self, after: float | None = None, before: float | None = None) -> Where:
        """Items whose interval ``[t, t_end]`` overlaps ``[after, before]`` (ends inclusive).

        ``after`` alone: items still going on at or after ``after`` (``t_end >= after``);
        ``before`` alone: items that started at or before ``before`` (``t <= before``).
        """
        if after is not None:
            value = _sql_float(finite_float(after, "after"))
            self.parts.append(f"t_end >= {value}")
            self.after = finite_float(after, "after")
            self.estimate[f"t_end >= {value}"] = f"t >= {value}"
        if before is not None:
            self.parts.append(f"t <= {_sql_float(finite_float(before, 'before'))}")
        if after is not None and before is not None and float(after) > float(before):
            raise InvalidInputError(f"after ({after}) is later than before ({before})")
        return self

    def t_range(self, start: float | None = None, end: float | None = None) -> Where:
        """Items that *start* in ``[start, end)`` (for ordering-style temporal queries)."""
        if start is not None:
            self.parts.append(f"t >= {_sql_float(finite_float(start, 'start'))}")
        if end is not None:
            self.parts.append(f"t < {_sql_float(finite_float(end, 'end'))}")
        return self

    def frame(self, frame: str | None) -> Where:
        return self._eq("frame", frame, validate_frame)

    def facet_range(self, column: str, lo: float | None, hi: float | None = None) -> Where:
        """Touch rows whose facet ``column`` (``force``, ``area``) lies in [lo, hi] (rows
        without facets never match)."""
        if column not in ("force", "area", "peak"):
            raise InvalidInputError(f"no facet column {column!r}")
        if lo is not None:
            self.parts.append(f"{column} >= {_sql_float(finite_float(lo, column + '_min'))}")
        if hi is not None:
            self.parts.append(f"{column} <= {_sql_float(finite_float(hi, column + '_max'))}")
        if lo is not None and hi is not None and float(lo) > float(hi):
            raise InvalidInputError(f"{column}_min ({lo}) is above {column}_max ({hi})")
        return self

    def regions(self, names: Iterable[str] | str | None) -> Where:
        """Touch rows where every region of ``names`` is active (carries a share of the
        load, tactus_memory.touch.facets.ACTIVE_SHARE)."""
        for n in check_regions(names) or ():
            self.parts.append(f"strpos(regions, {_sql_str(',' + n + ',')}) > 0")
        return self

    def caption_key(
        self, grip: str | None, regions: str, lo: float | None, hi: float | None
    ) -> Where:
        """Touch rows whose window caption (:mod:`tactus_memory.search.captions`) is the one
        of ``grip`` (None: a sensor without regions), exactly the active regions ``regions``
        (the stored form, ``",thumb,index,"``) and a ``force`` in [lo, hi) (the firmness
        band's pressure bounds times the sensor's taxels)."""
        if grip is None:
            self.parts.append("grip IS NULL")
        else:
            self._eq("grip", grip, check_grip)
        self.parts.append(f"regions = {_sql_str(regions)}")
        if lo is not None:
            self.parts.append(f"force >= {_sql_float(finite_float(lo, 'force'))}")
        if hi is not None:
            self.parts.append(f"force < {_sql_float(finite_float(hi, 'force'))}")
        return self

    def grip(self, grip: str | None) -> Where:
        """Touch rows of this grip (one of :data:`GRIPS`)."""
        return self._eq("grip", grip, check_grip)

    def near(self, near: Near | None) -> Where:
        """Items placed within ``radius`` of ``(x, y, z)`` (unplaced items never match). The
        x/y bounding box comes first so the x and y scalar indexes answer it; the sphere test
        (z included: robots mostly share one floor, so a z index would select almost every
        row) then runs on the rows in the box only (benchmarks/places.py)."""
        if near is not None:
            (x, y, z), r = check_near(near)
            for col, c in (("x", x), ("y", y)):
                lo, hi = _sql_float(c - r), _sql_float(c + r)
                self.parts.append(f"{col} >= {lo} AND {col} <= {hi}")
            terms = [f"({col} - {_sql_float(c)}) * ({col} - {_sql_float(c)})" for col, c in (
                ("x", x), ("y", y), ("z", z))]  # fmt: skip
            self.refine.append(f"{' + '.join(terms)} <= {_sql_float(r * r)}")
            self.scattered = True
        return self

    def sql(self) -> str | None:
        every = [*self.parts, *self.refine]
        return " AND ".join(f"({p})" for p in every) if every else None

    def count_sql(self) -> str | None:
        """What the scalar indexes alone answer, to size a search (not to return rows): the
        filter without its refine conditions (a place's box: a superset) and with a time
        window's lower bound on the items' start (those that start in it: a subset, which
        errs towards probing more or an exact scan; items that began before it and last
        into it are left out, so a count of 0 is no proof of none)."""
        if not self.parts:
            return None
        return " AND ".join(f"({self.estimate.get(p, p)})" for p in self.parts)


# --------------------------------------------------------------------------- session walls
#: the session-id prefix every read of the items in this context is limited to (a key made
#: with ``tactus keys create --sessions PREFIX``; the service's gate sets it per request);
#: None: every session. :func:`within_sessions` ANDs it into each filter the store runs.
SESSION_PREFIX: ContextVar[str | None] = ContextVar("tactus_session_prefix", default=None)


def validate_session_prefix(value: Any) -> str:
    """A session-id prefix: itself an id (1-128 chars of ``[A-Za-z0-9._:-]``)."""
    return validate_id(value, "session prefix")


def session_visible(session: str) -> bool:
    """Whether ``session`` lies under this context's :data:`SESSION_PREFIX`."""
    prefix = SESSION_PREFIX.get()
    return prefix is None or session.startswith(prefix)


def within_sessions(where: str | None) -> str | None:
    """``where`` AND the session prefix of this context (``where`` itself when none)."""
    term = Where().session_prefix(SESSION_PREFIX.get()).sql()
    if term is None:
        return where
    return term if not where else f"({where}) AND {term}"


@contextmanager
def sessions_under(prefix: str | None) -> Iterator[None]:
    """Limit the store reads inside the block to sessions starting with ``prefix`` (None:
    every session, e.g. for a tenant-wide statistic read while a request's prefix is set)."""
    token = SESSION_PREFIX.set(None if prefix is None else validate_session_prefix(prefix))
    try:
        yield
    finally:
        SESSION_PREFIX.reset(token)
