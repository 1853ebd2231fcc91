"""Grasps: a stream's contiguous windows grouped into the moments a user asks about; the
grouping step after the Ranker (:mod:`tactus_memory.search.evidence`: the senses a
:class:`GraspRule` groups are answered by the grasps holding their ranked hits).

A touch stream stores overlapping K-frame windows (8 frames, a new one every 4); a
question ("when was I holding the screwdriver?") is about a grasp, seconds long. A *grasp* is
a maximal run of one stream's items (one session + sense + source), in time order ``(t, id)``,
with no boundary between consecutive items, where item *i* starts a new grasp when

1. **contact offset/onset**: ``t[i] - max(t_end of the run so far) > max_gap`` seconds. The
   touch sense does not store idle windows (``TactusEncoder.validate``: no contact), so a
   release of the hand is a hole in the stored windows; overlapping windows have gaps <= 0;
2. **change point**: ``cos(v[i], v[i-1]) < min_cos``: the embedding jumps between consecutive
   windows (another object taken without an idle window in between).

Never from labels, recording ids or meta: only times and stored vectors. Both rules look at
consecutive items only, so the grasp around a window is found from its neighbourhood alone
(no pass over the whole session): :func:`find_grasps` reads the candidates' neighbourhoods
(:data:`GRASP_READ_S` around them, widened up to :data:`GRASP_MAX_S` while a grasp touches the
edge of what was read) and returns each grasp's members and its pooled vector, the mean of the
members' unit vectors renormalised (the paper's recording-level pooling).

Computed at query time from the stored windows, not stored: no write-path change, no schema
change, a new rule or checkpoint applies to old data at once; the cost is one scan for every
neighbourhood of a question together (a second, narrower one while a grasp reaches an edge).

The rule (where a hold starts and ends) lives in :mod:`tactus_memory.search.holds`, with its
measured defaults (``max_gap`` 1.0 s, ``min_cos`` 0.2: one grasp per hold on the protocol's
held-out glove day, ``benchmarks/grasp_holds.py``); ``tactus eval --stream --group grasp``
measures the result.

Scores: a grasp's pooled vector is scored with its sense's calibration (estimated on single
stored windows). Pooling averages noise away, so pooled scores run higher than window scores
for the right object and for near misses alike: ranking grasps against each other is sound,
but the match bar (``MATCH_Z``) was set on windows and is not re-measured for grasps.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from tactus_memory.errors import InvalidInputError
from tactus_memory.results import Evidence, Grasp, Hit
from tactus_memory.search.holds import HOLD_MAX_GAP, HOLD_MIN_COS, HoldRule, hold_labels
from tactus_memory.vectors import vector_column
from tactus_memory.where import Where, finite_float

if TYPE_CHECKING:
    from tactus_memory.search.ranking import Ranker
    from tactus_memory.storage.store import Store

#: a hole longer than this (seconds) between a stream's items ends a grasp (a release: the
#: cutting rule's, :data:`tactus_memory.search.holds.HOLD_MAX_GAP`)
GRASP_MAX_GAP = HOLD_MAX_GAP
#: consecutive items whose cosine is below this are in different grasps (change point)
GRASP_MIN_COS = HOLD_MIN_COS
#: seconds read on each side of a candidate to find its grasp (widened while needed)
GRASP_READ_S = 30.0
#: the widest neighbourhood read around candidates; a longer grasp is cut at its edges
GRASP_MAX_S = 600.0
#: the most reads of one neighbourhood: each round doubles its width (60 s, 120, 240, 480,
#: 600 = GRASP_MAX_S: 5 reads), so the rounds end before the width does; the bound also
#: holds where widening cannot change a span (at |t| ~ 1e18 s, t - 30 == t: issue 48,
#: a read span re-read forever)
GRASP_MAX_ROUNDS = 8
#: group values the search and temporal operators take: ``auto`` (the default) asks of grasps
#: for touch senses and of items for the others; ``window`` of items everywhere (one hit per
#: stored window); ``grasp`` of grasps for every sense; ``moment`` (search only) moments
GROUPS = ("moment", "grasp", "window", "auto")
DEFAULT_GROUP = "auto"
#: the modality whose items ``auto`` groups into grasps: streams of short windows
GRASP_MODALITY = "touch"
#: how a grasp is scored: ``mean`` the pooled vector of every member (the paper's
#: recording-level pooling), ``top`` the pooled vector of its GRASP_TOP members closest to the
#: query, ``max`` its best member window
POOLS = ("mean", "top", "max")
GRASP_TOP = 3
#: how last/first/count score a grasp by default: by its best window. The pooled mean ranks
#: grasps better (search's default) but dilutes the right grasp under the match bar: on
#: held-out STAG recordings (benchmarks/answer_rule.py) mean-pooled grasps made ``last``
#: right for 8 % of questions against 15 % for windows; a grasp's best window matches as a
#: window does, and the answer is still the whole grasp
OCCURRENCE_POOL = "max"


@dataclass(frozen=True)
class GraspRule:
    """The grasp boundary rule (see the module docstring)."""

    max_gap: float = GRASP_MAX_GAP
    min_cos: float = GRASP_MIN_COS
    pool: str = "mean"  # one of POOLS
    modality: str | None = None  # group only senses of this modality (None: every sense)

    def applies(self, modality: str) -> bool:
        """Whether this rule groups the items of a sense of ``modality``."""
        return self.modality is None or modality == self.modality

    def __post_init__(self) -> None:
        if self.pool not in POOLS:
            raise InvalidInputError(f"unknown grasp pool {self.pool!r}; use one of {POOLS}")
        if finite_float(self.max_gap, "max_gap") < 0:
            raise InvalidInputError(f"max_gap must be >= 0, got {self.max_gap!r}")
        if not -1.0 <= finite_float(self.min_cos, "min_cos") <= 1.0:
            raise InvalidInputError(f"min_cos must be in [-1, 1], got {self.min_cos!r}")


def check_group(group: str | None, allowed: Sequence[str] = GROUPS) -> str | None:
    """``group`` if it is None or one of ``allowed``, else InvalidInputError naming them."""
    if group is not None and group not in allowed:
        raise InvalidInputError(f"unknown group {group!r}; use one of {', '.join(allowed)}")
    return group


def grasp_rule(group: str | None, pool: str = "mean") -> GraspRule | None:
    """The grasp rule of ``group``: ``"grasp"`` groups every sense, ``"auto"`` (the default)
    touch senses only (:data:`GRASP_MODALITY`); ``"window"`` or None: items, not grasps.
    Anything else raises InvalidInputError."""
    g = check_group(group, ("grasp", "window", "auto"))
    if g == "grasp":
        return GraspRule(pool=pool)
    if g == "auto":
        return GraspRule(pool=pool, modality=GRASP_MODALITY)
    return None


def as_hit(e: Evidence) -> Hit:
    """A search answer as a :class:`Hit`: a Grasp keeps its span, pooled score, ``n`` and
    member ``ids`` (its ``id`` is its best window); other evidence is one item."""
    fields = e.model_dump(include=set(Hit.model_fields))
    if isinstance(e, Grasp):
        fields.update(n=e.n, ids=e.ids, window_score=e.window_score)
    return Hit(**fields)


def windows_group(windows: bool) -> str:
    """The group of a ``--windows`` / ``windows: true`` flag (CLI, MCP): ``"window"`` asks of
    single windows, else the default (``"auto"``: touch asked of grasps)."""
    return "window" if windows else DEFAULT_GROUP


def grasp_labels(
    t: np.ndarray, t_end: np.ndarray, vectors: np.ndarray, rule: GraspRule = GraspRule()
) -> np.ndarray:
    """Grasp labels 0, 1, ... for N items of one stream sorted by ``(t, id)``: one grasp per
    hold (:func:`tactus_memory.search.holds.hold_labels`, the cutting rule).

    t, t_end: (N,) seconds; vectors: (N, D) unit rows. Returns (N,) int64, non-decreasing."""
    return hold_labels(t, t_end, vectors, HoldRule(rule.max_gap, rule.min_cos))


def pooled(vectors: np.ndarray) -> np.ndarray:
    """(N, D) unit rows -> (D,) float32: their mean, renormalised."""
    mean = np.asarray(vectors, dtype=np.float64).mean(axis=0)
    return (mean / max(float(np.linalg.norm(mean)), 1e-12)).astype(np.float32)


@dataclass
class GraspRows:
    """One grasp found around candidate evidence: member ids (time order), stored span,
    pooled vector (D,), member vectors (n, D), and the candidates (search hits) it holds."""

    session: str
    sense: str
    source: str
    ids: list[str]
    t: float
    t_end: float
    vector: np.ndarray
    members: np.ndarray
    candidates: list[Evidence]
    #: the members' stored facets JSON and spans (None: a row without facets)
    facets: list[str | None] | None = None
    spans: tuple[np.ndarray, np.ndarray] | None = None

    def grasp_facets(self, taxels: int | None = None) -> dict[str, Any] | None:
        """The grasp's facets (:func:`tactus_memory.touch.facets.grasp_facets`) from its
        members' stored ones; None when a member has none (another sense, an old row).
        ``taxels``: the sensor's taxel count where the stored facets do not say it."""
        if not self.facets or any(f is None for f in self.facets) or self.spans is None:
            return None
        from tactus_memory.touch.facets import facets_of_rows, grasp_facets

        rows = [json.loads(f) for f in self.facets if f is not None]
        return grasp_facets(facets_of_rows(rows, taxels), *self.spans)

    def cosine(self, q: np.ndarray, pool: str) -> float:
        """The grasp's cosine to the (D,) query ``q`` under ``pool`` (see POOLS)."""
        if pool == "mean":
            return float(self.vector @ q)
        cos = self.members @ q
        if pool == "max":
            return float(cos.max())
        return float(pooled(self.members[np.argsort(-cos)[:GRASP_TOP]]) @ q)


def _merge(spans: list[tuple[float, float]]) -> list[tuple[float, float]]:
    out: list[tuple[float, float]] = []
    for lo, hi in sorted(spans):
        if out and lo <= out[-1][1]:
            out[-1] = (out[-1][0], max(out[-1][1], hi))
        else:
            out.append((lo, hi))
    return out


#: neighbourhoods read by one scan (their filters OR-ed): one LanceDB query per round, not
#: one per stream; bounded so a filter stays a few KB
GRASP_SPANS_PER_SCAN = 64
#: what a neighbourhood's read needs of each row
_SPAN_COLUMNS = ["session", "sense", "source", "id", "t", "t_end", "vector", "facets"]

Stream = tuple[str, str, str]  # (session, sense, source)


@dataclass
class _Span:
    """A stream's neighbourhood [lo, hi] to cut into grasps around ``cands``."""

    key: Stream
    lo: float
    hi: float
    cands: list[Evidence]

    def where(self) -> str:
        session, sense, source = self.key
        sql = Where().session(session).sense(sense).source(source).overlaps(self.lo, self.hi)
        return str(sql.sql())


def find_grasps(
    store: Store, dim: int, candidates: Sequence[Evidence], rule: GraspRule = GraspRule()
) -> list[GraspRows]:
    """The grasps that contain ``candidates`` (stored items, e.g. a search's hits), one per
    grasp, each with every member (not only the candidates); order: first candidate's rank.

    Every neighbourhood is read by one scan per round (a few rounds at most, while a grasp
    touches the edge of what was read): a search's candidates in 16 streams cost one LanceDB
    query, not 16-32, which on a store of many fresh fragments was 35 ms each (1.2 s a search
    beside a fleet's writes, benchmarks/capacity.py)."""
    by_stream: dict[Stream, list[Evidence]] = {}
    for e in candidates:
        by_stream.setdefault((e.session, e.sense, e.source or ""), []).append(e)
    pending = [
        _Span(key, lo, hi, [c for c in cands if c.t_end >= lo and c.t <= hi])
        for key, cands in by_stream.items()
        for lo, hi in _merge([(c.t - GRASP_READ_S, c.t_end + GRASP_READ_S) for c in cands])
    ]
    found: dict[str, GraspRows] = {}  # first member id -> grasp
    for round_ in range(GRASP_MAX_ROUNDS):  # bounded by rounds as well as by width
        if not pending:
            break
        last = round_ == GRASP_MAX_ROUNDS - 1
        wider: list[_Span] = []
        for i in range(0, len(pending), GRASP_SPANS_PER_SCAN):
            batch = pending[i : i + GRASP_SPANS_PER_SCAN]
            rows = _read(store, dim, batch)
            for span in batch:
                grasps = _grasps_in(span, rows, rule, last)
                if grasps is None:  # a grasp reaches an edge of what was read: read wider
                    grow = min(span.hi - span.lo, GRASP_MAX_S - (span.hi - span.lo)) / 2
                    lo, hi = span.lo - grow, span.hi + grow
                    if (lo, hi) == (span.lo, span.hi):  # no wider in float64: cut it here
                        grasps = _grasps_in(span, rows, rule, True)
                    else:
                        wider.append(_Span(span.key, lo, hi, span.cands))
                        continue
                assert grasps is not None  # final: never None
                for g in grasps:
                    have = found.get(g.ids[0])
                    if have is None:
                        found[g.ids[0]] = g
                    else:
                        known = {c.id for c in have.candidates}
                        have.candidates += [c for c in g.candidates if c.id not in known]
        pending = wider
    rank = {c.id: i for i, c in enumerate(candidates)}
    return sorted(found.values(), key=lambda g: min(rank[c.id] for c in g.candidates))


@dataclass
class _Rows:
    """One scan's rows, in stream and time order ``(stream, t, id)``."""

    streams: dict[Stream, int]  # a stream -> its code in ``code``
    code: np.ndarray  # (N,) int64: each row's stream
    ids: list[str]
    t: np.ndarray  # (N,) float64
    t_end: np.ndarray  # (N,) float64
    vecs: np.ndarray  # (N, D) float32 unit rows
    facets: list[str | None]  # (N,) each row's facets JSON (None: none stored)


def _read(store: Store, dim: int, spans: list[_Span]) -> _Rows:
    """The rows of every span in ``spans``: one scan, its filter the spans' filters OR-ed."""
    tbl = store.scan(" OR ".join(f"({s.where()})" for s in spans), _SPAN_COLUMNS)
    cols = [tbl.column(c).to_pylist() for c in ("session", "sense", "source")]
    streams: dict[Stream, int] = {}
    code = np.array(
        [streams.setdefault(key, len(streams)) for key in zip(*cols, strict=True)], np.int64
    )
    ids = tbl.column("id").to_pylist()
    t = tbl.column("t").to_numpy()
    facets = tbl.column("facets").to_pylist() if "facets" in tbl.column_names else [None] * len(ids)
    order = np.lexsort((np.array(ids, dtype=object), t, code))
    return _Rows(
        streams=streams,
        code=code[order],
        ids=[ids[i] for i in order],
        t=t[order],
        t_end=tbl.column("t_end").to_numpy()[order],
        vecs=vector_column(tbl, dim)[order],
        facets=[facets[i] for i in order],
    )


def _grasps_in(
    span: _Span, rows: _Rows, rule: GraspRule, final: bool = False
) -> list[GraspRows] | None:
    """Cut the stream's rows in [lo, hi] into grasps around the span's candidates; None when
    one of them reaches an edge of the span (it may go on outside) and the span can still
    grow (up to GRASP_MAX_S, and not ``final``: the last round, or a span float64 cannot
    widen)."""
    session, sense, source = span.key
    mine = rows.code == rows.streams.get(span.key, -1)
    sel = np.flatnonzero(mine & (rows.t_end >= span.lo) & (rows.t <= span.hi))
    ids = [rows.ids[i] for i in sel]
    t, t_end, vecs = rows.t[sel], rows.t_end[sel], rows.vecs[sel]
    labels = grasp_labels(t, t_end, vecs, rule)
    pos = {i: n for n, i in enumerate(ids)}
    runs = sorted({int(labels[pos[c.id]]) for c in span.cands if c.id in pos})
    for lab in runs:
        members = np.flatnonzero(labels == lab)
        starts_in = t[members[0]] - span.lo > rule.max_gap
        ends_in = span.hi - t_end[members].max() > rule.max_gap
        if not (starts_in and ends_in) and span.hi - span.lo < GRASP_MAX_S and not final:
            return None
    out = []
    for lab in runs:
        members = np.flatnonzero(labels == lab)
        member_ids = [ids[i] for i in members]
        mine = set(member_ids)
        out.append(
            GraspRows(
                session=session,
                sense=sense,
                source=source,
                ids=member_ids,
                t=float(t[members].min()),
                t_end=float(t_end[members].max()),
                vector=pooled(vecs[members]),
                members=vecs[members],
                candidates=[c for c in span.cands if c.id in mine],
                facets=[rows.facets[sel[i]] for i in members],
                spans=(t[members], t_end[members]),
            )
        )
    return out


def pool_grasps(
    ranker: Ranker, q: np.ndarray, sense: str, hits: Sequence[Evidence], rule: GraspRule
) -> list[Grasp]:
    """One sense's candidate evidence -> the grasps holding it, scored (``rule.pool``; default
    the pooled vector) against the sense's transformed query ``q`` (1, D), calibrated like any
    hit of the sense, or by its caption score when higher: its best member window's caption
    or its own (:meth:`tactus_memory.search.captions.Captions.grasp_score`); best first.
    Times: the grasp's span, aligned by its stream's clock offset."""
    qs = ranker.query_for(q, sense)[0]
    calib = ranker.registry.calibration(sense)
    reached = ranker.captions.scores(q)  # the captions the words reach (search.captions)
    out = []
    for g in find_grasps(ranker.store, ranker.space.dim, hits, rule):
        best = max(g.candidates, key=lambda e: (e.score, -e.t, e.id))
        cos = g.cosine(qs, rule.pool)
        score = float(calib.score(cos))
        facets = g.grasp_facets(ranker.captions.taxels_of(g.sense))
        captioned = ranker.captions.grasp_score(q, reached, g.facets, facets, g.sense)
        if captioned is not None and captioned[0] > score:  # its caption answers: its cosine
            score, cos = captioned
        off = best.t_aligned - best.t
        fields = best.model_dump(exclude={"t", "t_end", "t_aligned", "t_end_aligned", "score"})
        fields.update(cosine=cos, match=False, n=len(g.ids), ids=g.ids, facets=facets)
        out.append(
            Grasp(
                **fields,
                t=g.t,
                t_end=g.t_end,
                t_aligned=g.t + off,
                t_end_aligned=g.t_end + off,
                score=score,
                window_score=best.score,
            )
        )
    out.sort(key=lambda g: (-g.score, g.t_aligned, g.id))
    return out
