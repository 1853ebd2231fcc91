"""Property tests (Hypothesis, issue 16).

1. The filter builder (``Where``) run through REAL LanceDB against a Python reference filter,
   with random sessions / senses / sources / time ranges, and deletes and upserts between
   queries, on the flat path and on the indexed path (ANN index + the ``flat_max`` exact
   scan, thresholds lowered here): no row outside the filter ever comes back, and recall@k
   against brute-force cosine is >= 0.9.
2. Invariants of moment grouping (``group_moments``) and episode segmentation
   (``episodes.segment``).

Example counts are modest (the file runs in well under a minute)."""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from tactus_memory.adapters.vectors import VectorSense
from tactus_memory.matching import group_moments
from tactus_memory.memory.main import Memory
from tactus_memory.results import Evidence
from tactus_memory.storage.tables import IndexConfig
from tactus_memory.temporal.episodes import segment
from tactus_memory.where import Where
from tests.helpers.fakes import HashingSpace

DIM = 32
SESSIONS = ["s0", "s1", "s2", "s3"]
SENSES = ["a", "b", "c"]
SOURCES = ["", "left", "right"]
N0 = 360  # rows before the first query: past the lowered index threshold below
K = 10
RECALL_MIN = 0.9

# flat: never indexed; indexed: ANN index from 200 rows, exact scan only for <= 25 allowed
CONFIGS = {
    "flat": IndexConfig(threshold=10**9, scalar_threshold=10**9),
    "indexed": IndexConfig(
        threshold=200, scalar_threshold=100, rows_per_partition=40, flat_max=25, compact_every=8
    ),
}


@dataclass
class Row:
    session: str
    sense: str
    source: str
    t: float
    t_end: float
    vec: np.ndarray


class Mirror:
    """A memory and its Python mirror (id -> Row), kept in step through adds, upserts and
    deletes."""

    def __init__(self, path: str, cfg: IndexConfig, seed: int) -> None:
        self.mem = Memory.open(path, space=HashingSpace(dim=DIM), index=cfg, background=False)
        for s in SENSES:
            self.mem.add_sense(VectorSense(s, dim=DIM))
        self.rng = np.random.default_rng(seed)
        self.rows: dict[str, Row] = {}
        self.serial = 0
        self.add(N0)

    def _new_row(self) -> Row:
        r = self.rng
        t = float(r.integers(0, 100))
        return Row(
            session=str(r.choice(SESSIONS)),
            sense=str(r.choice(SENSES)),
            source=str(r.choice(SOURCES)),
            t=t,
            t_end=t + float(r.integers(0, 5)),
            vec=r.standard_normal(DIM).astype(np.float32),
        )

    def put(self, rows: dict[str, Row]) -> None:
        """Write rows grouped by (session, sense, source), with explicit ids (upsert)."""
        groups: dict[tuple[str, str, str], list[tuple[str, Row]]] = {}
        for i, row in rows.items():
            groups.setdefault((row.session, row.sense, row.source), []).append((i, row))
        for (session, sense, source), members in groups.items():
            self.mem.add_many(
                session,
                sense,
                [row.vec for _, row in members],
                t=[row.t for _, row in members],
                t_end=[row.t_end for _, row in members],
                ids=[i for i, _ in members],
                source=source,
            )
        self.rows.update(rows)

    def add(self, n: int) -> None:
        rows = {}
        for _ in range(n):
            self.serial += 1
            rows[f"r{self.serial:05d}"] = self._new_row()
        self.put(rows)

    def upsert(self, n: int) -> None:
        ids = self.rng.choice(sorted(self.rows), size=min(n, len(self.rows)), replace=False)
        # same id, new time, source and vector; an id stays in its session and sense (an
        # upsert that would move it is an IdConflictError: issue 12's tenant isolation)
        self.put(
            {
                str(i): replace(
                    self._new_row(), session=self.rows[i].session, sense=self.rows[i].sense
                )
                for i in ids
            }
        )

    def delete(self, n: int) -> None:
        ids = [str(i) for i in self.rng.choice(sorted(self.rows), size=n, replace=False)]
        assert self.mem.delete(ids) == n
        for i in ids:
            del self.rows[i]


@dataclass
class Filter:
    sessions: list[str] | None
    senses: list[str] | None
    source: str | None
    after: float | None
    before: float | None

    def where(self) -> Where:
        return (
            Where()
            .sessions(self.sessions)
            .senses(self.senses)
            .source(self.source)
            .overlaps(self.after, self.before)
        )

    def ok(self, r: Row) -> bool:  # the Python reference of the documented semantics
        return (
            (self.sessions is None or r.session in self.sessions)
            and (self.senses is None or r.sense in self.senses)
            and (self.source is None or r.source == self.source)
            and (self.after is None or r.t_end >= self.after)  # overlaps: ends inclusive
            and (self.before is None or r.t <= self.before)
        )


@st.composite
def filters(draw: Any) -> Filter:
    def subset(values: list[str]) -> list[str] | None:
        return draw(st.none() | st.lists(st.sampled_from(values), min_size=1, unique=True))

    after = draw(st.none() | st.integers(0, 100).map(float))
    before = draw(st.none() | st.integers(0, 100).map(float))
    if after is not None and before is not None and after > before:
        after, before = before, after
    return Filter(
        sessions=subset(SESSIONS),
        senses=subset(SENSES),
        source=draw(st.none() | st.sampled_from(SOURCES)),
        after=after,
        before=before,
    )


_MIRRORS: dict[str, Mirror] = {}


@pytest.fixture(scope="module", params=sorted(CONFIGS))
def mirror(request, tmp_path_factory) -> Mirror:
    name = request.param
    m = Mirror(str(tmp_path_factory.mktemp(name) / "mem"), CONFIGS[name], seed=len(name))
    assert m.mem.store.has_vector_index() == (name == "indexed")
    return m


PROPERTY = settings(
    max_examples=30,
    deadline=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture],
)


@PROPERTY
@given(
    f=filters(),
    op=st.sampled_from(["none", "add", "upsert", "delete"]),
    seed=st.integers(0, 2**31 - 1),
)
def test_filtered_search_never_leaks_and_finds_the_top_k(mirror: Mirror, f, op, seed) -> None:
    # a write between queries: appends land in the unindexed tail, upserts and deletes
    # change rows the index already covers
    if op == "add":
        mirror.add(7)
    elif op == "upsert":
        mirror.upsert(5)
    elif op == "delete":
        mirror.delete(5)
    q = np.random.default_rng(seed).standard_normal(DIM).astype(np.float32)
    q /= np.linalg.norm(q)

    allowed = {i: r for i, r in mirror.rows.items() if f.ok(r)}
    sql = f.where().sql()
    store = mirror.mem.store
    assert store.count(sql) == len(allowed)  # the filter selects exactly the reference rows
    got = store.vector_search(q, K, sql, allowed=len(allowed), total=store.count())
    ids = got.column("id").to_pylist()
    assert set(ids) <= set(allowed), "a row outside the filter came back"
    assert len(ids) == len(set(ids)) == min(K, len(allowed))
    if not allowed:
        return
    vecs = np.stack([r.vec for r in allowed.values()])
    cos = vecs @ q / np.linalg.norm(vecs, axis=1)
    truth = [list(allowed)[j] for j in np.argsort(-cos)[:K]]
    recall = len(set(ids) & set(truth)) / len(truth)
    assert recall >= RECALL_MIN, (recall, len(allowed))


@PROPERTY
@given(
    session=st.none() | st.sampled_from(SESSIONS),
    senses=st.none() | st.lists(st.sampled_from(SENSES), min_size=1, unique=True),
    after=st.none() | st.integers(0, 50).map(float),
    span=st.integers(0, 50),
    seed=st.integers(0, 2**31 - 1),
)
def test_memory_search_respects_every_filter(mirror, session, senses, after, span, seed):
    """The public path (``Memory.search_vector``: per-sense groups, calibration, merge)."""
    before = None if after is None else after + span
    f = Filter(None if session is None else [session], senses, None, after, before)
    q = np.random.default_rng(seed).standard_normal(DIM).astype(np.float32)
    hits = mirror.mem.search_vector(
        q, K, senses=senses, session=session, after=after, before=before
    )
    allowed = {i for i, r in mirror.rows.items() if f.ok(r)}
    assert {h.id for h in hits} <= allowed
    assert len(hits) == min(K, len(allowed))


# ---------------------------------------------------------------------------- moments


@st.composite
def evidence_lists(draw: Any) -> list[Evidence]:
    n = draw(st.integers(0, 25))
    out = []
    for i in range(n):
        t = draw(st.integers(0, 60).map(float))
        dur = draw(st.integers(0, 4).map(float))
        out.append(
            Evidence(
                id=f"e{i}",
                session=draw(st.sampled_from(["k", "m"])),
                sense=draw(st.sampled_from(["text", "touch"])),
                source=draw(st.sampled_from(["", "l"])),
                t=t,
                t_end=t + dur,
                t_aligned=t,
                t_end_aligned=t + dur,
                score=draw(st.floats(-3, 10, allow_nan=False)),
                cosine=0.5,
                match=draw(st.booleans()),
            )
        )
    return out


@settings(max_examples=150, deadline=None)
@given(ev=evidence_lists(), gap=st.integers(0, 6).map(float), per_stream=st.booleans())
def test_group_moments_invariants(ev, gap, per_stream) -> None:
    moments = group_moments(ev, gap, per_stream=per_stream)
    members = [h.id for m in moments for h in m.hits]
    assert sorted(members) == sorted(e.id for e in ev)  # every item in exactly one moment
    assert [(m.t, m.t_end, m.session) for m in moments] == sorted(
        (m.t, m.t_end, m.session) for m in moments
    )
    key = (lambda h: (h.session, h.sense, h.source)) if per_stream else (lambda h: (h.session,))
    by_key: dict[tuple[str, ...], list[Any]] = {}
    for m in moments:
        ks = {key(h) for h in m.hits}
        assert len(ks) == 1  # one session (one stream) per moment
        assert m.t == min(h.t_aligned for h in m.hits)
        assert m.t_end == max(h.t_end_aligned for h in m.hits)
        assert m.best in {h.id for h in m.hits}
        assert m.score >= max(h.score for h in m.hits)
        assert m.senses == sorted({h.sense for h in m.hits})
        # members chain: sorted by start, each starts within gap of the running end
        hs = sorted(m.hits, key=lambda h: h.t_aligned)
        end = hs[0].t_end_aligned
        for h in hs[1:]:
            assert h.t_aligned <= end + gap
            end = max(end, h.t_end_aligned)
        by_key.setdefault(ks.pop(), []).append(m)
    for ms in by_key.values():  # moments of one key are separated by more than gap
        ms.sort(key=lambda m: m.t)
        for a, b in zip(ms, ms[1:], strict=False):
            assert b.t > a.t_end + gap


# ---------------------------------------------------------------------------- episodes


@st.composite
def streams(draw: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    n = draw(st.integers(1, 30))
    starts = np.cumsum(draw(st.lists(st.integers(0, 8), min_size=n, max_size=n))).astype(float)
    dur = np.array(draw(st.lists(st.integers(0, 3), min_size=n, max_size=n)), dtype=float)
    seed = draw(st.integers(0, 2**31 - 1))
    rng = np.random.default_rng(seed)
    base = rng.standard_normal((3, 8))
    which = rng.integers(0, 3, n)
    v = base[which] + 0.2 * rng.standard_normal((n, 8))
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    return starts, starts + dur, v


@settings(max_examples=150, deadline=None)
@given(s=streams(), max_gap=st.integers(0, 10).map(float))
def test_segment_invariants(s, max_gap) -> None:
    t, t_end, v = s
    labels = segment(t, t_end, v, max_gap=max_gap)
    assert labels.shape == (len(t),) and labels[0] == 0
    steps = np.diff(labels)
    assert set(steps.tolist()) <= {0, 1}  # 0, 1, 2, ... without skips
    # a time gap past max_gap always starts a new episode
    latest = t_end[0]
    for i in range(1, len(t)):
        if labels[i] == labels[i - 1]:
            assert t[i] - latest <= max_gap
            assert float(v[i] @ v[i - 1]) >= 0.7  # EPISODE_MIN_COS
            latest = max(latest, t_end[i])
        else:
            latest = t_end[i]
    # a looser rule never makes more episodes (vector rule off, no time limit: one episode)
    loose = segment(t, t_end, v, min_cos=-1.0, mean_cos=-1.0, max_gap=math.inf)
    assert loose.max() == 0
