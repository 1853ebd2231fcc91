"""Temporal operators on the real path: real MiniLM, real LanceDB files, and touch either as a
VectorSense stand-in (MiniLM embeddings of what each grasp feels like) or, when the shipped
checkpoint is present, the real ``TactusEncoder`` on real STAG windows (never copied here).

Ground truth: the kitchen session of tests/helpers/kitchen.py (mug grasps at 10, 40, 70 s, a
screwdriver at 55 s, an empty hand in between), its notes 1.5 s after each grasp starts, and
two unrelated notes at 100 and 110 s.
"""

from __future__ import annotations

import numpy as np
import pytest

from tactus_memory.adapters.vectors import VectorSense
from tactus_memory.matching import MATCH_Z
from tactus_memory.memory.main import Memory
from tests.helpers.kitchen import IDLE, MUG_GRASPS, SCREW_GRASP, S, kitchen_notes, near_caption

pytestmark = pytest.mark.slow

NOTES = [
    *kitchen_notes(delay=1.5),
    ("charging the battery", 100.0),
    ("folded a towel", 110.0),
]
FEEL = {
    "mug": "grasping a ceramic coffee mug",
    "screwdriver": "grasping a screwdriver handle",
    "empty": "an empty open hand",
}
IRRELEVANT = [
    "a giraffe in the savanna",
    "quantum chromodynamics lecture",
    "the weather in paris",
    "stock market prices fell",
]
#: one touch window lasts this long (8 STAG frames at ~7.3 Hz)
WINDOW_S = 1.1


def stand_in(space, kind: str, n: int, seed: int) -> list[np.ndarray]:
    return near_caption(space, FEEL[kind], n, seed, noise=0.05)


def add_notes(mem: Memory) -> list[str]:
    return mem.add_many(S, "text", [n for n, _ in NOTES], t=[t for _, t in NOTES])


def add_touch(mem: Memory, windows: dict[str, list]) -> dict[str, list[str]]:
    """windows: kind -> items (mug: 3, screwdriver: 1, empty: len(IDLE))."""
    ids = {}
    for kind, times in (("mug", MUG_GRASPS), ("screwdriver", [SCREW_GRASP]), ("empty", IDLE)):
        ids[kind] = mem.add_many(
            S, "touch", windows[kind], t=times, t_end=[t + WINDOW_S for t in times]
        )
    return ids


@pytest.fixture(scope="module")
def real(tmp_path_factory, minilm_space) -> tuple[Memory, dict[str, list[str]]]:
    mem = Memory.open(str(tmp_path_factory.mktemp("tr") / "m"), space=minilm_space)
    mem.add_sense(VectorSense("touch", dim=384))
    add_notes(mem)
    ids = add_touch(
        mem,
        {
            "mug": stand_in(minilm_space, "mug", 3, 0),
            "screwdriver": stand_in(minilm_space, "screwdriver", 1, 1),
            "empty": stand_in(minilm_space, "empty", len(IDLE), 2),
        },
    )
    return mem, ids


def test_real_count_last_first(real) -> None:
    mem, ids = real
    occ = mem.occurrences("picked up the mug", session=S)
    assert occ.count == 3
    assert [m.t for m in occ.moments] == MUG_GRASPS
    assert all(m.senses == ["text", "touch"] for m in occ.moments)
    assert mem.count("picked up the mug", senses=["text"]) == 3
    assert mem.count("picked up the mug", senses=["touch"]) == 3
    assert mem.count("the screwdriver") == 1
    assert mem.count("dropped the can") == 1
    assert mem.last("picked up the mug").t == 70.0
    assert mem.first("picked up the mug").t == 10.0
    assert mem.last("holding a coffee cup", senses=["touch"]).hits[0].id == ids["mug"][2]


def test_real_threshold_means_something_for_text_and_touch(real) -> None:
    mem, ids = real
    for q in IRRELEVANT:
        for sense in ("text", "touch"):
            assert mem.count(q, senses=[sense]) == 0, (q, sense)
        assert mem.last(q) is None and mem.before(q) is None
    # a paraphrase still matches the notes (and only them)
    para = mem.matches("holding a coffee cup", senses=["text"])
    assert [e.text for e in para] == ["picked up the mug"] * 3
    # the near miss that shares words with the query clears the bar: with the shipped text
    # prior it scores 3.6 against the real notes' 8.8 (0.41 of the best: just past the
    # default relative gate, 0.4; matching.py), the answer rule leaves it out ...
    text = mem.matches("picked up the mug", senses=["text"])
    assert min(text, key=lambda e: e.score).text == "picked up the screwdriver"
    assert mem.count("picked up the mug", senses=["text"], session=S) == 3
    # ... and a stricter relative gate drops it ...
    strict = mem.matches("picked up the mug", senses=["text"], relative=0.5)
    assert [e.text for e in strict] == ["picked up the mug"] * 3
    # ... which the absolute bar alone does not (its score clears MATCH_Z["text"])
    loose = mem.matches("picked up the mug", senses=["text"], relative=0.0, threshold=2.0)
    assert "picked up the screwdriver" in [e.text for e in loose]
    touch = mem.matches("picked up the mug", senses=["touch"])
    assert {e.id for e in touch} == set(ids["mug"])
    assert all(e.score >= MATCH_Z["touch"] for e in touch)


def test_real_before_after_moments_episodes(real) -> None:
    mem, ids = real
    ctx = mem.before("dropped the can", window=25.0, senses=["text"])
    assert ctx.anchor.t == 90.0 and [i.text for i in ctx.items] == ["picked up the mug"]
    ctx = mem.after("tightening with a screwdriver", window=20.0, anchor_senses=["touch"])
    assert ctx.anchor.id == ids["screwdriver"][0]
    assert [i.t for i in ctx.items] == [56.5, 60.0, 70.0, 71.5]
    moments = mem.search("picked up the mug", k=3, group="moment")
    assert sorted(m.t for m in moments) == MUG_GRASPS
    assert all(m.senses == ["text", "touch"] for m in moments)
    eps = mem.timeline(S, senses=["touch"], episodes=True)
    assert [e.t for e in eps] == [0.0, 10.0, 20.0, 40.0, 50.0, 55.0, 60.0, 70.0, 80.0, 95.0]


#: idle stretches of the encoder test: one valid empty-hand grasp each (the subset has six)
IDLE_REAL = [0.0, 20.0, 30.0, 50.0, 80.0, 95.0]


def _stag_grasps(stag_dir, k: int) -> dict[str, list[list[np.ndarray]]]:
    """Real raw STAG windows (weights subset, never copied here): for each of the first valid
    grasps of an object, its first and its last k valid frames (two windows of one grasp)."""
    from tactus_memory.training.data import load_stag

    d = load_stag(stag_dir / "weights_lite" / "metadata.mat")
    grasp = d.extra["graspIndex"]

    def grasps(obj: str, n: int) -> list[list[np.ndarray]]:
        idx = np.flatnonzero((d.object_id == d.objects.index(obj)) & d.valid)
        out = []
        for gi in np.unique(grasp[idx]):
            sel = idx[grasp[idx] == gi]
            if len(sel) >= k:
                out.append([d.pressure[sel[:k]], d.pressure[sel[-k:]]])
        assert len(out) >= n, (obj, len(out))
        return out[:n]

    return {
        "mug": grasps("mug", len(MUG_GRASPS)),
        "screwdriver": grasps("screw_driver", 1),
        "empty": grasps("empty_hand", len(IDLE_REAL)),
    }


def test_real_touch_encoder_on_stag_windows(tmp_path, minilm_space, stag_dir) -> None:
    """The shipped TactusEncoder on real STAG grasps: two windows per grasp (t0, t0 + 1.1 s),
    mug grasps at 10/40/70 s, a screwdriver at 55 s, six empty-hand grasps in between."""
    from tactus_memory.adapters.touch import TactusEncoder

    enc = TactusEncoder()  # the checkpoint ships with the package: missing is a failure
    mem = Memory.open(str(tmp_path / "m"), space=minilm_space)
    mem.add_sense(enc)
    add_notes(mem)
    real = _stag_grasps(stag_dir, enc.frames)
    ids: dict[str, list[str]] = {"mug": [], "screwdriver": [], "empty": []}
    for kind, times in (("mug", MUG_GRASPS), ("screwdriver", [SCREW_GRASP]), ("empty", IDLE_REAL)):
        for t0, pair in zip(times, real[kind], strict=True):
            ids[kind] += mem.add_many(
                S, "touch", pair, t=[t0, t0 + WINDOW_S], t_end=[t0 + WINDOW_S, t0 + 2 * WINDOW_S]
            )
    # a touch answer is a grasp by default: the two windows of one hold, one hit
    top = mem.search("a mug", k=3, senses=["touch"])
    assert top[0].n == 2 and set(top[0].ids) <= set(ids["mug"]) and top[0].t in MUG_GRASPS
    assert top[0].t_end == pytest.approx(top[0].t + 2 * WINDOW_S)
    windows = mem.search("a mug", k=3, senses=["touch"], group="window")
    assert all(h.n is None for h in windows) and windows[0].id in ids["mug"]
    # touch alone: the three mug grasps match object words, as three occurrences
    for q in ["a mug", "holding a coffee mug"]:
        occ = mem.occurrences(q, senses=["touch"])
        assert [m.t for m in occ.moments] == MUG_GRASPS, q
        assert {h.id for m in occ.moments for h in m.hits} <= set(ids["mug"])
    assert [m.t for m in mem.occurrences("a screwdriver", senses=["touch"]).moments] == [
        SCREW_GRASP
    ]
    assert mem.count("an empty hand", senses=["touch"]) == len(IDLE_REAL)
    # irrelevant queries match no touch window (and no note)
    for q in IRRELEVANT:
        assert mem.count(q, senses=["touch"]) == 0, q
        assert mem.count(q) == 0, q
    # a real touch window and the note written about it form one moment / one occurrence
    moments = mem.search("picked up the mug", k=3, group="moment")
    assert sorted(m.t for m in moments) == MUG_GRASPS
    assert all(m.senses == ["text", "touch"] for m in moments)
    assert mem.count("picked up the mug") == 3
    last = mem.last("picked up the mug")  # the third grasp, by its window or its note
    assert 70.0 <= last.t <= 71.5 and "text" in last.senses
    ctx = mem.before("dropped the can", window=25.0, senses=["touch"])
    assert [i.t for i in ctx.items] == [70.0, 71.1, 80.0, 81.1]
    # episodes: each grasp's two windows are one episode, the gaps split the rest
    eps = mem.timeline(S, senses=["touch"], episodes=True)
    assert [(e.t, e.n) for e in eps] == [
        (t, 2) for t in sorted(MUG_GRASPS + [SCREW_GRASP] + IDLE_REAL)
    ]
