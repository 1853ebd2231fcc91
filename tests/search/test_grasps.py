"""Grasps (issue 22): a stream's contiguous windows grouped into grasps and ranked by their
pooled embedding, in ``search(group="grasp")``, moments, ``last``/``count`` and over HTTP.

Fast part: real LanceDB, HashingSpace at the space seam and a VectorSense touch stand-in
whose windows lie around the embedding of what each grasp feels like. One session "day":
mug grasps at 10 s and 30 s, a screwdriver at 20 s (3 s each, a window every 0.13 s spanning
0.27 s, as the 30 Hz stream cuts them), a 90 s sponge grasp at 100 s (longer than the first
neighbourhood read), and at 200 s a mug handed straight to a screwdriver with no release (a
change point without an idle gap).
"""

from __future__ import annotations

import numpy as np
import pytest
from fastapi.testclient import TestClient

from tactus_memory.adapters.vectors import VectorSense
from tactus_memory.errors import InvalidInputError
from tactus_memory.memory.main import Memory
from tactus_memory.query import embed_query
from tactus_memory.results import Evidence, Grasp
from tactus_memory.search.grasps import GRASP_READ_S, GraspRule, find_grasps, grasp_labels, pooled
from tactus_memory.where import Where
from tests.helpers.fakes import HashingSpace
from tests.helpers.kitchen import kitchen_memory, near_caption

S = "day"
STEP, SPAN = 4 / 30, 8 / 30  # a new 8-frame window every 4 frames at 30 Hz
#: no word shared between two objects (HashingSpace: shared words are shared directions)
FEEL = {
    "mug": "ceramic coffee mug",
    "screwdriver": "screwdriver handle",
    "sponge": "squeezing wet kitchen sponge",
}
#: (object, start s, seconds)
GRASPS = [("mug", 10.0, 3.0), ("screwdriver", 20.0, 3.0), ("mug", 30.0, 3.0)]
GRASPS += [("sponge", 100.0, 90.0), ("mug", 200.0, 3.0), ("screwdriver", 203.0 + STEP, 3.0)]


def _windows(secs: float) -> int:
    return int(round(secs / STEP))


def _fill(mem) -> dict[int, list[str]]:
    """Write every grasp's windows (noisy: a single window is a poor witness); grasp index ->
    its window ids."""
    out = {}
    for n, (obj, start, secs) in enumerate(GRASPS):
        count = _windows(secs)
        t = [start + i * STEP for i in range(count)]
        vecs = near_caption(mem.space, FEEL[obj], count, seed=n, noise=1.2)
        out[n] = mem.add_many(S, "touch", vecs, t=t, t_end=[x + SPAN for x in t])
    return out


@pytest.fixture(scope="module")
def day(tmp_path_factory):
    mem = kitchen_memory(tmp_path_factory.mktemp("grasps") / "mem")
    return mem, _fill(mem)


def test_labels_split_at_gaps_and_change_points_only() -> None:
    t = np.array([0.0, 0.13, 0.27, 1.5, 1.63])  # a 1.2 s hole after the third window
    ends = t + SPAN
    v = np.tile(np.eye(4, dtype=np.float32)[0], (5, 1))
    assert grasp_labels(t, ends, v).tolist() == [0, 0, 0, 1, 1]
    v[4] = np.eye(4, dtype=np.float32)[1]  # an orthogonal last window: a change point
    assert grasp_labels(t, ends, v).tolist() == [0, 0, 0, 1, 2]
    assert grasp_labels(t, ends, v, GraspRule(max_gap=5.0, min_cos=-1.0)).tolist() == [0] * 5
    with pytest.raises(InvalidInputError):
        GraspRule(max_gap=-1.0)


def test_neighbourhood_reads_find_the_same_grasps_as_the_whole_stream(day) -> None:
    mem, ids = day
    tbl = mem.store.scan(f"session = '{S}'", ["id", "t", "t_end", "vector"])
    order = np.argsort(tbl.column("t").to_numpy(), kind="stable")
    t = tbl.column("t").to_numpy()[order]
    all_ids = [tbl.column("id").to_pylist()[i] for i in order]
    vecs = np.stack(tbl.column("vector").to_numpy(zero_copy_only=False))[order]
    labels = grasp_labels(t, t + SPAN, vecs)
    whole = {frozenset(np.array(all_ids)[labels == lab]) for lab in np.unique(labels)}
    assert len(whole) == len(GRASPS)  # the rule finds exactly the grasps that were written
    assert whole == {frozenset(v) for v in ids.values()}
    # one candidate per grasp, the sponge's from its middle (the first read is too short)
    cands = []
    for members in ids.values():
        row = mem.get_item(members[len(members) // 2])
        cands.append(
            Evidence(**row.model_dump(exclude={"raw", "created", "vector"}),
                     t_aligned=row.t, t_end_aligned=row.t_end, score=1.0, cosine=0.1)
        )  # fmt: skip
    assert GRASPS[3][2] > 2 * GRASP_READ_S
    found = find_grasps(mem.store, mem.space.dim, cands)
    assert [frozenset(g.ids) for g in found] == [frozenset(ids[n]) for n in ids]
    sponge = found[3]
    assert sponge.t == pytest.approx(100.0) and sponge.t_end > 189.0
    assert np.allclose(sponge.vector, pooled(vecs[np.isin(all_ids, ids[3])]), atol=1e-6)


def test_search_by_grasp_returns_one_hit_per_grasp_with_its_span(day) -> None:
    mem, ids = day
    q = FEEL["mug"]
    grasps = mem.search(q, k=3, senses=["touch"], session=S, group="grasp")
    assert all(isinstance(g, Grasp) for g in grasps)
    mugs = {n for n, (obj, _, _) in enumerate(GRASPS) if obj == "mug"}
    top = {n for g in grasps for n in ids if set(g.ids) == set(ids[n])}
    assert top == mugs  # the three mug grasps, whole, before anything else
    for g in grasps:
        n = next(n for n in ids if set(g.ids) == set(ids[n]))
        start, secs = GRASPS[n][1], GRASPS[n][2]
        end = start + (_windows(secs) - 1) * STEP + SPAN
        assert g.t == pytest.approx(start) and g.t_end == pytest.approx(end)
        assert g.n == len(ids[n]) and g.id in ids[n]
        # the pooled score: the renormalised mean of the stored unit vectors vs the query
        vecs = np.stack([mem.get_item(i, vector=True).vector for i in g.ids])
        qv = mem.space.embed_texts([q], query=True)[0]
        assert g.cosine == pytest.approx(float(pooled(vecs) @ qv), abs=1e-5)
        assert g.score == pytest.approx(float(mem.calibration("touch").score(g.cosine)))
    scores = [g.score for g in grasps]
    assert scores == sorted(scores, reverse=True)
    # pooling helps: the best single mug window scores below its grasp's pooled score
    assert all(g.score > g.window_score for g in grasps)
    # the other pools: its best window, the mean of its 3 windows closest to the query
    best = mem.search(q, k=1, senses=["touch"], session=S, group="grasp", pool="max")[0]
    assert best.score == pytest.approx(best.window_score)
    top = mem.search(q, k=1, senses=["touch"], session=S, group="grasp", pool="top")[0]
    vecs = np.stack([mem.get_item(i, vector=True).vector for i in top.ids])
    qv = mem.space.embed_texts([q], query=True)[0]
    assert top.cosine == pytest.approx(float(pooled(vecs[np.argsort(-(vecs @ qv))[:3]]) @ qv))
    with pytest.raises(InvalidInputError, match="grasp"):
        mem.search(q, group="episode")
    with pytest.raises(InvalidInputError, match="pool"):
        mem.search(q, group="grasp", pool="median")


def test_last_count_and_moments_by_grasp(day) -> None:
    mem, ids = day
    q = FEEL["screwdriver"]
    occ = mem.occurrences(q, session=S, senses=["touch"], group="grasp")
    assert occ.count == 2
    last = mem.last(q, session=S, senses=["touch"], group="grasp")
    assert last is not None and last.t == pytest.approx(203.0 + STEP)
    assert isinstance(last.hits[0], Grasp) and set(last.hits[0].ids) == set(ids[5])
    moments = mem.search_moments(q, k=2, session=S, senses=["touch"], group="grasp")
    assert {round(m.t, 2) for m in moments} == {20.0, round(203.0 + STEP, 2)}
    with pytest.raises(InvalidInputError):
        mem.count(q, session=S, group="moment")


def test_grasps_over_http(day) -> None:
    from tactus_memory.service.app import create_app
    from tactus_memory.settings import Settings

    mem, ids = day
    with TestClient(create_app(Settings(), memory=mem)) as c:
        params = {"q": FEEL["sponge"], "sense": "touch", "session": S, "k": 2}
        r = c.get("/search", params={**params, "group": "grasp"})
        assert r.status_code == 200, r.text
        body = r.json()
        first = body["grasps"][0]
        assert set(first["ids"]) == set(ids[3]) and first["n"] == len(ids[3])
        assert body["hits"][0]["id"] == first["id"] and body["hits"][0]["t"] == first["t"]
        assert first["t_end"] - first["t"] > 89.0
        r = c.get("/count", params={"q": FEEL["mug"], "session": S, "group": "grasp"})
        assert r.status_code == 200 and r.json()["count"] == 3  # at 10, 30 and 200 s
        r = c.get("/moments", params={**params, "group": "grasp"})
        assert r.status_code == 200 and r.json()["moments"][0]["t"] == pytest.approx(100.0)
        r = c.get("/search", params={**params, "group": "bogus"})
        assert r.status_code == 422
        r = c.get("/search", params={**params, "group": "grasp", "pool": "max"})
        assert r.status_code == 200 and set(r.json()["grasps"][0]["ids"]) == set(ids[3])


class TouchStandIn(VectorSense):
    """A touch stream stand-in with controlled vectors: modality ``touch``, so the default
    grouping (``auto``) answers it with grasps."""

    modality = "touch"


@pytest.fixture(scope="module")
def touch_day(tmp_path_factory):
    mem = Memory.open(
        str(tmp_path_factory.mktemp("auto") / "mem"), space=HashingSpace(dim=384), background=False
    )
    mem.add_sense(TouchStandIn("touch", dim=384))
    ids = _fill(mem)
    note = mem.add(S, "text", FEEL["sponge"], t=150.0)
    return mem, ids, note


def test_touch_answers_are_grasps_by_default_and_windows_one_flag_away(touch_day) -> None:
    mem, ids, note = touch_day
    hits = mem.search(FEEL["sponge"], k=3, session=S)
    touch = [h for h in hits if h.sense == "touch"]
    # the 90 s sponge grasp is one answer, spanning the grasp, its windows in ids
    assert touch[0].n == len(ids[3]) and set(touch[0].ids) == set(ids[3])
    assert touch[0].id in ids[3] and touch[0].t_end - touch[0].t > 89.0
    assert touch[0].window_score is not None
    # a note stays one item beside it
    text = [h for h in hits if h.sense == "text"]
    assert text and text[0].id == note and text[0].n is None and text[0].ids is None
    # windows: one hit per stored window, the best ones all inside the sponge grasp
    wins = mem.search(FEEL["sponge"], k=3, session=S, senses=["touch"], group="window")
    assert len(wins) == 3 and all(h.n is None and h.id in ids[3] for h in wins)
    # last / count ask of grasps by default: the mug was held three times (10, 30, 200 s)
    assert mem.count(FEEL["mug"], session=S, senses=["touch"]) == 3
    last = mem.last(FEEL["mug"], session=S, senses=["touch"])
    assert last is not None and last.t == pytest.approx(200.0)
    # per window, the same question counts windows merged by time, not grasps: the mug at
    # 200 s and the screwdriver handed on without a release become one occurrence or more,
    # never fewer than the grasp answer's distinct times
    assert mem.count(FEEL["mug"], session=S, senses=["touch"], group="window") >= 1


def test_touch_grasps_by_default_over_http(touch_day) -> None:
    from tactus_memory.service.app import create_app
    from tactus_memory.settings import Settings

    mem, ids, _ = touch_day
    with TestClient(create_app(Settings(), memory=mem)) as c:
        params = {"q": FEEL["sponge"], "sense": "touch", "session": S, "k": 2}
        hit = c.get("/search", params=params).json()["hits"][0]
        assert hit["n"] == len(ids[3]) and set(hit["ids"]) == set(ids[3])
        win = c.get("/search", params={**params, "group": "window"}).json()["hits"][0]
        assert win["n"] is None and win["ids"] is None and win["id"] in ids[3]
        r = c.get("/count", params={"q": FEEL["mug"], "session": S, "sense": "touch"})
        assert r.status_code == 200 and r.json()["count"] == 3


def test_each_question_ranks_every_sense_in_one_ranker_pass(touch_day, monkeypatch) -> None:
    """Issue 49 (one search path): ``group="auto"`` and ``group="window"``, the other groups and
    every question that ranks make exactly one Ranker call covering every sense in scope;
    grasps are grouped after it (``search.evidence``), not by asking the Ranker again."""
    mem, ids, note = touch_day
    calls: list[tuple[list[str], bool]] = []
    rank = mem.ranker.rank

    def spy(q, k, senses, base, **kw):
        calls.append((list(senses), bool(kw.get("each", False))))
        return rank(q, k, senses, base, **kw)

    monkeypatch.setattr(mem.ranker, "rank", spy)  # memory.temporal asks the same Ranker
    mug, sponge = FEEL["mug"], FEEL["sponge"]
    asks = {
        "auto": lambda: mem.search(sponge, k=3, session=S),
        "window": lambda: mem.search(sponge, k=3, session=S, group="window"),
        "grasp": lambda: mem.search(sponge, k=3, session=S, group="grasp"),
        "moment": lambda: mem.search(sponge, k=3, session=S, group="moment"),
        "last": lambda: mem.last(mug, session=S),
        "first": lambda: mem.first(mug, session=S),
        "count": lambda: mem.count(mug, session=S),
        "after": lambda: mem.after(mug, 5.0, session=S),
        "where": lambda: mem.where(mug, session=S),
    }
    answers = {}
    for name, ask in asks.items():
        calls.clear()
        answers[name] = ask()
        # the merged top k for window; every sense's own candidates otherwise
        assert calls == [(["text", "touch"], name != "window")], name
    # one pass answered both senses: the sponge grasp (whole) and the note beside it
    auto = answers["auto"]
    assert {h.sense for h in auto} == {"text", "touch"}
    grasp = next(h for h in auto if h.sense == "touch")
    assert set(grasp.ids) == set(ids[3]) and note in {h.id for h in auto}
    assert answers["count"] >= 3 and answers["last"] is not None


def test_one_pass_gives_each_sense_the_top_k_it_had_alone(touch_day) -> None:
    """``Ranker.rank(each=True)``: each sense's hits, scores and order are those of ranking
    that sense alone (what the temporal questions asked before, one sense after another);
    their merge's first k is the merged top k (``group="window"``)."""
    mem, _, _ = touch_day
    q = embed_query(mem.space, FEEL["mug"])
    base = Where().session(S)
    each = mem.ranker.rank(q, 5, ["text", "touch"], base, transform=True, each=True)
    for name, n in (("text", 1), ("touch", 5)):
        alone = mem.ranker.rank(q, 5, [name], base, transform=True)
        mine = [(h.id, h.score, h.cosine) for h in each if h.sense == name]
        assert mine == [(h.id, h.score, h.cosine) for h in alone] and len(mine) == n
    merged = mem.ranker.rank(q, 5, ["text", "touch"], base, transform=True)
    assert [h.id for h in merged] == [h.id for h in each[:5]]


def test_every_neighbourhood_of_a_question_is_read_by_one_scan(tmp_path, monkeypatch) -> None:
    """Candidates in 12 streams (sessions) cost one store scan, not one per stream: the scans
    over a fleet's fresh fragments were 35 ms each (benchmarks/capacity.py's search beside
    writes); every grasp is still found whole, and no other stream's rows join it."""
    mem = kitchen_memory(tmp_path / "mem")
    written, cands = {}, []
    for n in range(12):
        t = [5.0 + i * STEP for i in range(_windows(2.0))]
        vecs = near_caption(mem.space, FEEL["mug"], len(t), seed=n, noise=1.2)
        written[n] = mem.add_many(f"s{n}", "touch", vecs, t=t, t_end=[x + SPAN for x in t])
        row = mem.get_item(written[n][3])
        cands.append(
            Evidence(**row.model_dump(exclude={"raw", "created", "vector"}),
                     t_aligned=row.t, t_end_aligned=row.t_end, score=1.0, cosine=0.1)
        )  # fmt: skip
    scans = []
    real_scan = mem.store.scan
    monkeypatch.setattr(mem.store, "scan", lambda *a, **k: scans.append(a) or real_scan(*a, **k))
    found = find_grasps(mem.store, mem.space.dim, cands)
    assert len(scans) == 1
    assert [frozenset(g.ids) for g in found] == [frozenset(written[n]) for n in range(12)]
    assert [g.session for g in found] == [f"s{n}" for n in range(12)]
