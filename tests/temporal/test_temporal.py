"""Temporal operators, moments, episodes and clock offsets, fast: HashingSpace at the space seam,
a VectorSense "touch" stand-in with controlled vectors, real LanceDB files in tmp_path.

Ground truth (tests/helpers/kitchen.py; session "kitchen", seconds): three mug grasps at 10, 40 and
70
(two 1 s touch windows each), a screwdriver grasp at 55, an empty hand in between; notes
"picked up the mug" 2.5 s after each mug grasp starts, "picked up the screwdriver" at 57.5,
"dropped the can" at 90.
"""

from __future__ import annotations

import numpy as np
import pytest

from tactus_memory.errors import InvalidIdError, InvalidInputError, NotFoundError
from tactus_memory.matching import (
    MATCH_Z,
    Match,
    group_moments,
    match_flags,
    resolve_thresholds,
)
from tactus_memory.memory.main import Memory
from tactus_memory.query import Scope
from tactus_memory.results import Evidence, Moment
from tactus_memory.temporal.episodes import representative, segment
from tactus_memory.temporal.operators import Temporal
from tests.helpers.fakes import HashingSpace
from tests.helpers.kitchen import (
    IDLE,
    MUG_GRASPS,
    NOTES,
    S,
    fill_kitchen,
    kitchen_memory,
    touch_vectors,
)


@pytest.fixture
def mem(tmp_path) -> Memory:
    return kitchen_memory(tmp_path / "mem")


@pytest.fixture
def kitchen(mem: Memory) -> tuple[Memory, dict[str, list]]:
    return mem, fill_kitchen(mem)


# --------------------------------------------------------------------------- pure helpers
def test_match_flags_need_absolute_and_relative_bar() -> None:
    assert match_flags([8.0, 5.0, 4.0, 1.0], threshold=3.0, relative=0.6) == [
        True, True, False, False,
    ]  # fmt: skip
    # an irrelevant query: the best is under the absolute bar, so nothing matches
    assert match_flags([2.0, 1.9, 1.0], threshold=3.0, relative=0.6) == [False] * 3
    assert match_flags([8.0, 4.0], threshold=3.0, relative=0.0) == [True, True]
    assert match_flags([], threshold=3.0, relative=0.6) == []


def test_thresholds_default_per_sense_and_override() -> None:
    assert resolve_thresholds(None, ["text", "touch"]) == {
        "text": MATCH_Z["text"], "touch": MATCH_Z["touch"],
    }  # fmt: skip
    assert resolve_thresholds(1.5, ["text", "touch"]) == {"text": 1.5, "touch": 1.5}
    assert resolve_thresholds({"touch": 9.0}, ["text", "touch"])["touch"] == 9.0
    with pytest.raises(InvalidInputError):
        resolve_thresholds(float("nan"), ["text"])
    with pytest.raises(InvalidIdError):
        resolve_thresholds({"Bad Sense": 1.0}, ["text"])


def _ev(i: str, t: float, t_end: float, sense: str = "touch", score: float = 5.0, **kw) -> Evidence:
    return Evidence(
        id=i, session=kw.get("session", "s"), sense=sense, t=t, t_end=t_end, t_aligned=t,
        t_end_aligned=t_end, score=score, cosine=0.5, match=kw.get("match", True),
    )  # fmt: skip


def test_group_moments_merges_overlap_and_gap_and_scores_corroboration() -> None:
    ev = [
        _ev("a", 10, 11), _ev("b", 11.5, 12), _ev("n", 12.5, 12.5, "text", 4.0),
        _ev("c", 20, 21), _ev("x", 20.5, 20.5, "text", 1.0, match=False),
        _ev("o", 10, 11, session="other"),
    ]  # fmt: skip
    ms = group_moments(ev, gap=1.0)
    assert [(m.session, m.t, m.t_end) for m in ms] == [
        ("other", 10, 11), ("s", 10, 12.5), ("s", 20, 21),
    ]  # fmt: skip
    first = ms[1]
    assert first.senses == ["text", "touch"] and [h.id for h in first.hits] == ["a", "b", "n"]
    assert first.best == "a" and first.score == pytest.approx(5.0 + 0.5)  # corroborated by text
    # a non-matching note nearby is evidence, but earns no corroboration bonus
    assert ms[2].senses == ["text", "touch"] and ms[2].score == pytest.approx(5.0)
    assert len(group_moments(ev, gap=0.0)) == 5  # 10-11 / 11.5-12 / 12.5 no longer touch


def test_segment_rule_jump_drift_and_gap() -> None:
    e = np.eye(4)
    t = np.arange(6, dtype=float)
    v = np.stack([e[0], e[0], e[1], e[1], e[1], e[0]])
    assert segment(t, t, v).tolist() == [0, 0, 1, 1, 1, 2]
    # a time gap alone splits identical vectors
    t2 = np.array([0.0, 1.0, 20.0, 21.0])
    assert segment(t2, t2, np.stack([e[0]] * 4), max_gap=5.0).tolist() == [0, 0, 1, 1]
    # slow drift: every step is close to the previous one, but the episode mean is left behind
    angles = np.linspace(0, np.pi / 2, 12)
    drift = np.stack([np.cos(angles), np.sin(angles), 0 * angles, 0 * angles], axis=1)
    t3 = np.arange(12, dtype=float)
    labels = segment(t3, t3, drift, min_cos=0.9, mean_cos=0.8)
    assert all(float(drift[i] @ drift[i - 1]) > 0.98 for i in range(1, 12))
    assert labels[0] == 0 and labels[-1] >= 1  # split by drift, not by a jump
    assert segment(t3, t3, drift, min_cos=0.9, mean_cos=-1.0).tolist() == [0] * 12
    assert representative(np.stack([e[0], e[0], e[1]])) == 0


# --------------------------------------------------------------------------- last/first/count
def test_count_mug_is_three_and_irrelevant_is_zero(kitchen) -> None:
    mem, _ = kitchen
    occ = mem.occurrences("the mug", session=S)
    assert occ.count == 3 and not occ.capped
    assert [(m.t, m.t_end) for m in occ.moments] == [(10, 12.5), (40, 42.5), (70, 72.5)]
    assert all(m.senses == ["text", "touch"] for m in occ.moments)
    assert mem.count("the screwdriver", session=S) == 1
    assert mem.count("dropped the can", session=S) == 1
    for irrelevant in ["giraffe savanna", "quantum chromodynamics lecture", "weather in paris"]:
        assert mem.count(irrelevant) == 0
        assert mem.last(irrelevant) is None and mem.first(irrelevant) is None


def test_threshold_means_something_per_sense(kitchen) -> None:
    mem, ids = kitchen
    # touch alone and text alone both find the three mug grasps, nothing else
    touch = mem.matches("the mug", senses=["touch"])
    assert {e.id for e in touch} == set(ids["mug"])
    text = mem.matches("the mug", senses=["text"])
    assert [e.t for e in text] == [12.5, 42.5, 72.5]
    assert mem.count("the mug", senses=["touch"]) == 3
    assert mem.count("the mug", senses=["text"]) == 3
    # adjacent windows of one stream merge only within merge_gap
    assert mem.count("the mug", senses=["touch"], merge_gap=0.0) == 3  # windows touch (t_end=t)
    # per stream: each grasp and each note is its own occurrence
    assert mem.count("the mug", per_stream=True) == 6
    # an absurd bar matches nothing; a bar of 0 matches only what clears the relative gate
    assert mem.count("the mug", threshold=50.0) == 0
    assert mem.count("the mug", threshold={"touch": 50.0}, senses=["touch"]) == 0
    with pytest.raises(InvalidInputError):
        mem.count("the mug", relative=1.5)


def test_last_and_first_with_filters(kitchen) -> None:
    mem, ids = kitchen
    last = mem.last("the mug")
    assert isinstance(last, Moment) and (last.t, last.t_end) == (70.0, 72.5)
    assert {h.id for h in last.hits if h.sense == "touch"} == set(ids["mug"][4:])
    first = mem.first("the mug")
    assert first is not None and first.t == 10.0
    assert mem.last("the mug", before=50.0).t == 40.0
    assert mem.first("the mug", after=20.0).t == 40.0
    assert mem.last("the mug", senses=["text"]).t == 72.5
    assert mem.last("the mug", session="elsewhere") is None
    with pytest.raises(InvalidInputError):
        mem.last("the mug", after=50.0, before=10.0)
    with pytest.raises(InvalidIdError):
        mem.last("the mug", session="x' OR 1=1 --")


# --------------------------------------------------------------------------- before / after
def test_before_and_after_the_anchor(kitchen) -> None:
    mem, ids = kitchen
    ctx = mem.before("dropped the can", window=25.0)
    assert ctx is not None and ctx.anchor.text == "dropped the can" and ctx.anchor.t == 90.0
    assert (ctx.t_from, ctx.t_to) == (65.0, 90.0)
    assert [i.t for i in ctx.items] == [70.0, 71.0, 72.5, 80.0, 85.0]
    assert all(i.session == S for i in ctx.items)
    only_text = mem.before("dropped the can", window=25.0, senses=["text"])
    assert [i.text for i in only_text.items] == ["picked up the mug"]
    ctx = mem.after("the screwdriver", window=20.0, senses=["text"], anchor_senses=["touch"])
    assert ctx.anchor.sense == "touch" and ctx.anchor.id in ids["screwdriver"]
    # anchor: the best-scoring screwdriver window; after = from its end, anchor excluded
    assert ctx.t_from == ctx.anchor.t_end
    assert [i.text for i in ctx.items] == ["picked up the screwdriver", "picked up the mug"]
    assert mem.before("giraffe savanna") is None and mem.after("giraffe savanna") is None
    with pytest.raises(InvalidInputError):
        mem.before("dropped the can", window=-1.0)


def test_before_stays_in_the_anchor_session(mem: Memory) -> None:
    fill_kitchen(mem, "kitchen")
    mem.add("garage", "text", "oiled the bicycle chain", t=85.0)
    ctx = mem.before("dropped the can", window=10.0)
    assert ctx.anchor.session == "kitchen"
    assert "oiled the bicycle chain" not in [i.text for i in ctx.items]


# --------------------------------------------------------------------------- timeline
def test_timeline_in_time_order_with_filters(kitchen) -> None:
    mem, _ = kitchen
    items = mem.timeline(S)
    assert len(items) == 8 + len(IDLE) + len(NOTES)
    keys = [(i.t_aligned, i.t_end_aligned) for i in items]
    assert keys == sorted(keys)
    notes = mem.timeline(S, senses=["text"], after=10.0, before=60.0)
    assert [i.t for i in notes] == [12.5, 30.0, 42.5, 57.5]
    assert len(mem.timeline(S, limit=3)) == 3
    # overlap semantics: a window [9.5?]: the 10-11 window overlaps [10.5, 10.6]
    assert [i.t for i in mem.timeline(S, after=10.5, before=10.6)] == [10.0]


# --------------------------------------------------------------------------- episodes
def test_episodes_segment_touch_by_content_and_gap(kitchen) -> None:
    mem, ids = kitchen
    n = mem.segment_episodes(S)
    eps = mem.timeline(S, senses=["touch"], episodes=True)
    spans = [(e.t, e.t_end, e.n) for e in eps]
    assert spans == [
        (0, 6, 2), (10, 12, 2), (20, 31, 3), (40, 42, 2), (50, 51, 1), (55, 57, 2),
        (60, 61, 1), (70, 72, 2), (80, 86, 2), (95, 96, 1),
    ]  # fmt: skip
    assert n == len(eps) + len(NOTES)  # every note is its own episode here
    mug = [e for e in eps if e.t in MUG_GRASPS]
    assert all(e.representative in ids["mug"] and e.sense == "touch" for e in mug)
    # stored: items carry their episode id, unique per session
    item = mem.get_item(ids["mug"][0])
    assert item.episode == next(e.episode for e in eps if e.t == 10.0)
    assert len({e.episode for e in mem.timeline(S, episodes=True)}) == n
    # idempotent
    assert mem.segment_episodes(S) == n
    assert mem.get_item(ids["mug"][0]).episode == item.episode


def test_timeline_episodes_segments_on_demand_and_after_new_rows(mem: Memory) -> None:
    fill_kitchen(mem)
    version = mem.store.version()
    eps = mem.timeline(S, senses=["touch"], episodes=True)  # no explicit segment call
    assert len(eps) == 10
    # a read: computed for the answer, nothing written (issue 26: GET without side effects)
    assert mem.store.version() == version
    assert all(h.episode is None for h in mem.search("mug", k=50, session=S))
    mem.add_many(S, "touch", touch_vectors(mem.space, "mug", 2, seed=99), t=[100.0, 101.0])
    eps = mem.timeline(S, senses=["touch"], episodes=True, after=99.0)
    assert [(e.t, e.n) for e in eps] == [(100.0, 2)]
    assert mem.segment_episodes() > 0  # every session


@pytest.mark.parametrize(
    ("call", "error"),
    [
        (lambda mem: mem.timeline("nope"), NotFoundError),
        (lambda mem: mem.timeline("bad id!"), InvalidIdError),
        (lambda mem: mem.timeline(S, limit=0), InvalidInputError),
        (lambda mem: mem.segment_episodes("nope"), NotFoundError),
        (lambda mem: mem.segment_episodes(S, min_cos=2.0), InvalidInputError),
    ],
    ids=["timeline-unknown", "timeline-bad-id", "timeline-limit-0", "segment-unknown", "min-cos"],
)
def test_timeline_and_episodes_refuse_bad_input(kitchen, call, error) -> None:
    with pytest.raises(error):
        call(kitchen[0])


@pytest.mark.parametrize("episodes", [False, True])
def test_timeline_refuses_bad_bounds_with_and_without_episodes(kitchen, episodes) -> None:
    mem = kitchen[0]
    with pytest.raises(InvalidInputError, match=r"after \(50.0\) is later than before \(10.0\)"):
        mem.timeline(S, episodes=episodes, after=50.0, before=10.0)
    with pytest.raises(InvalidInputError, match="after must be a number"):
        mem.timeline(S, episodes=episodes, after="soon")  # type: ignore[arg-type]


# --------------------------------------------------------------------------- moments
def test_search_group_moment_joins_touch_and_note(kitchen) -> None:
    mem, ids = kitchen
    moments = mem.search("the mug", k=3, group="moment", gap=1.0)
    assert len(moments) == 3 and all(isinstance(m, Moment) for m in moments)
    for m in moments:
        assert m.senses == ["text", "touch"]
        assert m.t in MUG_GRASPS and m.t_end == m.t + 2.5
        assert [h.sense for h in m.hits].count("touch") == 2
        best = max(h.score for h in m.hits)
        assert m.score == pytest.approx(best + 0.5)  # one corroborating sense
    assert moments == mem.search_moments("the mug", k=3)
    # with no gap allowed the note (0.5 s after the last window) stands alone
    apart = mem.search_moments("the mug", k=10, gap=0.0)[:6]
    assert all(len(m.senses) == 1 and m.hits[0].match for m in apart)
    assert sorted(m.t for m in apart) == [10.0, 12.5, 40.0, 42.5, 70.0, 72.5]
    # weaker candidates (over MOMENT_MIN_Z but no match) rank below every mug moment
    rest = mem.search_moments("the mug", k=10)[3:]
    assert rest and all(not h.match for m in rest for h in m.hits)
    with pytest.raises(InvalidInputError):
        mem.search("the mug", group="cluster")
    with pytest.raises(InvalidInputError):
        mem.search_moments("the mug", gap=-1.0)
    # plain search is unchanged
    assert all(not isinstance(h, Moment) for h in mem.search("the mug", k=3))


# --------------------------------------------------------------------------- clock offsets
def test_clock_offset_aligns_streams_and_persists(tmp_path) -> None:
    path = str(tmp_path / "mem")
    mem = kitchen_memory(path)
    fill_kitchen(mem, notes_clock=-100.0)  # the note taker's clock runs 100 s behind
    # unaligned: notes (t = -87.5, ...) and grasps never meet
    assert all(len(m.senses) == 1 for m in mem.search_moments("the mug", k=10))
    assert mem.count("the mug") == 6
    mem.set_clock_offset(S, "text", 100.0)
    assert [o.offset for o in mem.clock_offsets(S)] == [100.0]
    moments = mem.search_moments("the mug", k=3)
    assert all(m.senses == ["text", "touch"] and m.t in MUG_GRASPS for m in moments)
    note = next(h for h in min(moments, key=lambda m: m.t).hits if h.sense == "text")
    assert (note.t, note.t_aligned) == (-87.5, 12.5)
    assert mem.count("the mug") == 3
    # after/before are on the aligned clock (the store bound is widened by the offset)
    assert [e.t_aligned for e in mem.matches("the mug", senses=["text"], after=40.0)] == [
        42.5, 72.5,
    ]  # fmt: skip
    assert [i.t_aligned for i in mem.timeline(S, senses=["text"], after=85.0)] == [90.0]
    ctx = mem.before("dropped the can", window=25.0, senses=["text"])
    assert ctx.anchor.t_aligned == 90.0 and [i.t_aligned for i in ctx.items] == [72.5]
    # persisted: a reopened memory aligns the same way
    again = Memory.open(path, space=HashingSpace(dim=384), background=False)
    assert again.clock_offsets() == mem.clock_offsets()
    assert again.count("the mug") == 3
    # offset 0 removes it
    mem.set_clock_offset(S, "text", 0.0)
    assert mem.clock_offsets() == []
    with pytest.raises(InvalidInputError):
        mem.set_clock_offset(S, "text", float("inf"))
    with pytest.raises(InvalidIdError):
        mem.set_clock_offset("bad id!", "text", 1.0)


def test_delete_session_removes_its_clock_offsets(mem: Memory) -> None:
    """A deleted session leaves nothing behind, its clock offsets included (the library
    does it, not only the HTTP route), and other sessions keep theirs."""
    mem.add("gone", "text", "a note", t=1.0)
    mem.add("kept", "text", "another note", t=1.0)
    mem.set_clock_offset("gone", "text", 5.0)
    mem.set_clock_offset("gone", "touch", 2.0, source="glove-l")  # several: all removed
    mem.set_clock_offset("gone", "touch", 3.0, source="glove-r")
    mem.set_clock_offset("kept", "text", 7.0)
    assert len(mem.clock_offsets("gone")) == 3
    assert mem.delete_session("gone") == 1
    assert mem.clock_offsets("gone") == []
    assert [(o.session, o.offset) for o in mem.clock_offsets()] == [("kept", 7.0)]


def test_clock_offset_per_source(mem: Memory) -> None:
    space = mem.space
    left = touch_vectors(space, "mug", 1, seed=1)
    right = touch_vectors(space, "mug", 1, seed=2)
    mem.add("s", "touch", left[0], t=10.0, t_end=11.0, source="glove-l")
    mem.add("s", "touch", right[0], t=30.0, t_end=31.0, source="glove-r")
    assert mem.count("the mug") == 2
    mem.set_clock_offset("s", "touch", -20.0, source="glove-r")
    occ = mem.occurrences("the mug")
    assert occ.count == 1 and {h.source for h in occ.moments[0].hits} == {"glove-l", "glove-r"}
    assert mem.count("the mug", source="glove-r") == 1


def test_temporal_is_built_from_its_parts_and_memory_asks_it(kitchen) -> None:
    """One temporal API: a Temporal made from the store, registry, ranker, space and lock
    alone (no Memory) answers as ``memory.count`` does, and ``memory.count`` is the very
    method of ``memory.temporal`` (no second implementation); ``match=`` is one Match."""
    mem, _ = kitchen
    alone = Temporal(mem.store, mem.registry, mem.ranker, mem.space, mem.lock)
    assert alone.count("picked up the mug", session=S) == mem.count("picked up the mug", session=S)
    assert alone.count("picked up the mug", session=S) >= 1
    assert mem.count.__func__ is Temporal.count
    assert mem.last.__self__ is mem.temporal
    strict = Match(threshold=1e6)
    assert mem.count("picked up the mug", scope=Scope(session=S), match=strict) == 0


def test_clock_offsets_are_read_once_per_meta_version(tmp_path, monkeypatch) -> None:
    """Every question asks for the clock offsets; they are read from the store again only
    when the meta table moved on (here: another memory on the store set one)."""
    path = str(tmp_path / "mem")
    mem = Memory.open(path, space=HashingSpace(dim=384), read_consistency_interval=0)
    other = Memory.open(path, space=HashingSpace(dim=384), read_consistency_interval=0)
    mem.set_clock_offset(S, "text", 100.0)
    reads = []
    real = mem.store.meta_items
    monkeypatch.setattr(mem.store, "meta_items", lambda p: reads.append(p) or real(p))
    clocks = mem.temporal.clocks
    assert clocks.offsets() == {(S, "text", ""): 100.0} and len(reads) == 1
    clocks.offsets()[(S, "text", "")] = 5.0  # a caller's copy: the cache is not changed
    assert clocks.offsets() == {(S, "text", ""): 100.0} and len(reads) == 1
    other.set_clock_offset(S, "touch", -2.0)
    assert clocks.offsets() == {(S, "text", ""): 100.0, (S, "touch", ""): -2.0}
    assert len(reads) == 2
