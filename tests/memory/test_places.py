"""Places (issue 23): trajectories in, items placed on them, questions by place.

Fast tests use the hashing space; ``test_real_*`` run real MiniLM on real LanceDB files."""

from __future__ import annotations

import numpy as np
import pyarrow as pa
import pytest
from scipy.spatial.transform import Rotation

from tactus_memory.errors import InvalidIdError, InvalidInputError
from tactus_memory.memory.main import Memory
from tactus_memory.memory.places import Places
from tactus_memory.storage.places import POSE_TOLERANCE, Trajectory, check_poses
from tactus_memory.storage.tables import items_schema, place_fields

# a 20 s straight walk along x at 1 m/s, poses at 10 Hz, yaw turning 0 -> 90 degrees
T = np.round(np.arange(0.0, 20.0 + 1e-9, 0.1), 6)
POS = np.column_stack([T, np.zeros_like(T), np.full_like(T, 0.5)])
YAW = Rotation.from_euler("z", np.linspace(0, 90, T.size)[:, None], degrees=True).as_quat()


@pytest.fixture
def mem(tmp_path, hashing_space) -> Memory:
    return Memory.open(str(tmp_path / "mem"), hashing_space, background=False)


# --------------------------------------------------------------------------- poses in
@pytest.mark.parametrize(
    ("t", "pos", "ori", "needle"),
    [
        ([0.0, np.nan], [[0, 0, 0]] * 2, None, "t has a NaN"),
        ([0.0, 1.0], [[0, 0, 0], [np.inf, 0, 0]], None, "position has a NaN or infinite"),
        ([0.0, 2.0, 1.0], [[0, 0, 0]] * 3, None, "unsorted time 1.0 at index 2"),
        ([0.0, 1.0, 1.0], [[0, 0, 0]] * 3, None, "duplicate time 1.0 at index 2"),
        ([0.0, 1.0], [[0, 0, 0]] * 3, None, "position has 3 rows for 2 times"),
        ([0.0, 1.0], [[0, 0]] * 2, None, "position must be (N, 3)"),
        ([0.0, 1.0], [[0, 0, 0]] * 2, [[0, 0, 0, 1]], "orientation has 1 rows for 2 times"),
        ([0.0, 1.0], [[0, 0, 0]] * 2, [[0, 0, 0, 1], [0, 0, 0, 2]], "orientation 1 is not a unit"),
        ([0.0, 1.0], [[0, 0, 0]] * 2, [[0, 0, 0, 1], [0, 0, np.nan, 1]], "orientation has a NaN"),
        ([], np.zeros((0, 3)), None, "non-empty"),
        (["a", "b"], [[0, 0, 0]] * 2, None, "t must be numbers"),
    ],
)
def test_bad_poses_are_typed_errors_and_write_nothing(mem, t, pos, ori, needle) -> None:
    with pytest.raises(InvalidInputError, match=needle.replace("(", r"\(").replace(")", r"\)")):
        mem.add_poses("s1", t, pos, ori)
    assert mem.places.poses.rows("s1").num_rows == 0
    assert mem.trajectory("s1") == []


def test_bad_session_and_frame_are_rejected(mem) -> None:
    with pytest.raises(InvalidIdError):
        mem.add_poses("bad id!", [0.0], [[0, 0, 0]])
    with pytest.raises(InvalidIdError, match="frame"):
        mem.add_poses("s1", [0.0], [[0, 0, 0]], frame="map' OR 1=1 --")


def test_check_poses_normalises_nearly_unit_quaternions() -> None:
    _, _, ori = check_poses([0.0], [[0, 0, 0]], [[0, 0, 0, 1.0005]])
    assert ori is not None
    assert np.linalg.norm(ori[0]) == pytest.approx(1.0)


# --------------------------------------------------------------------------- placing
def test_trajectory_interpolates_linearly_and_slerps() -> None:
    tr = Trajectory.from_rows("map", [0.0, 2.0], [[0, 0, 0], [2, 4, 0]], [[0, 0, 0, 1], YAW[-1]])
    placed, pos, ori = tr.place(np.array([0.5, 1.0, 2.0 + POSE_TOLERANCE + 0.01]))
    assert placed.tolist() == [True, True, False]
    np.testing.assert_allclose(pos[0], [0.5, 1.0, 0.0])
    yaw = Rotation.from_quat(ori[1]).as_euler("zyx", degrees=True)[0]
    assert yaw == pytest.approx(45.0)  # halfway between 0 and 90 degrees
    assert np.isnan(pos[2]).all()


def test_gap_in_the_trajectory_leaves_items_unplaced() -> None:
    tr = Trajectory.from_rows("map", [0.0, 10.0], [[0, 0, 0], [10, 0, 0]], np.full((2, 4), np.nan))
    placed, _, ori = tr.place(np.array([0.9, 5.0, 9.5]))
    assert placed.tolist() == [True, False, True]
    assert np.isnan(ori).all()  # the poses had no orientation


def test_items_written_after_poses_are_placed(mem) -> None:
    mem.add_poses("s1", T, POS, YAW, frame="map", source="odom")
    i = mem.add("s1", "text", "grabbed the drill", t=4.0, t_end=6.0)  # middle: 5.0
    item = mem.get_item(i)
    assert item.position == pytest.approx((5.0, 0.0, 0.5))
    assert item.frame == "map"
    assert Rotation.from_quat(item.orientation).as_euler("zyx", degrees=True)[0] == pytest.approx(
        22.5, abs=0.01
    )
    far = mem.add("s1", "text", "long after", t=20.0 + POSE_TOLERANCE + 0.5)
    assert mem.get_item(far).position is None


def test_poses_arriving_later_backfill_items(mem) -> None:
    ids = mem.add_many("s1", "text", ["a drill", "a mug", "a door"], t=[2.0, 12.0, 60.0])
    given = mem.add("s1", "text", "a shelf", t=3.0, position=(7, 8, 9), frame="map")
    assert all(mem.get_item(i).position is None for i in ids)
    mem.add_poses("s1", T[:101], POS[:101])  # 0..10 s
    assert mem.get_item(ids[0]).position == pytest.approx((2.0, 0.0, 0.5))
    assert mem.get_item(ids[1]).position is None  # 12 s is beyond 10 s + tolerance
    mem.add_poses("s1", T[101:], POS[101:])  # 10.1..20 s arrives later still
    assert mem.get_item(ids[1]).position == pytest.approx((12.0, 0.0, 0.5))
    assert mem.get_item(ids[2]).position is None
    assert mem.get_item(given).position == (7.0, 8.0, 9.0)  # a given place is never moved
    assert mem.place_items("s1") == 0  # already placed: nothing changes


def test_clock_offset_places_by_aligned_time(mem) -> None:
    mem.set_clock_offset("s1", "text", 3.0, source="cam")
    mem.add_poses("s1", T, POS)
    i = mem.add("s1", "text", "seen by the camera", t=4.0, source="cam")
    assert mem.get_item(i).position == pytest.approx((7.0, 0.0, 0.5))


def test_several_frames_prefer_map(mem) -> None:
    mem.add_poses("s1", T, POS + 100.0, frame="odom")
    mem.add_poses("s1", T[:50], POS[:50], frame="map")
    a = mem.add("s1", "text", "early", t=1.0)
    b = mem.add("s1", "text", "late", t=15.0)
    assert (mem.get_item(a).frame, mem.get_item(a).position[0]) == ("map", pytest.approx(1.0))
    assert (mem.get_item(b).frame, mem.get_item(b).position[0]) == ("odom", pytest.approx(115.0))
    assert [tr.frame for tr in mem.trajectory("s1")] == ["map", "odom"]


def test_bad_explicit_positions(mem) -> None:
    with pytest.raises(InvalidInputError, match="position 0 coordinate must be finite"):
        mem.add("s1", "text", "x", t=1.0, position=(0, np.nan, 0))
    with pytest.raises(InvalidInputError, match="three numbers"):
        mem.add("s1", "text", "x", t=1.0, position=(0, 0))
    with pytest.raises(InvalidInputError, match="2 entries for 3 items"):
        mem.add_many("s1", "text", ["a", "b", "c"], t=1.0, position=[(0, 0, 0), (1, 1, 1)])
    assert len(mem) == 0


def test_per_item_positions(mem) -> None:
    ids = mem.add_many("s1", "text", ["a", "b"], t=[1.0, 2.0], position=[(1, 2, 3), None])
    assert mem.get_item(ids[0]).position == (1.0, 2.0, 3.0)
    assert mem.get_item(ids[1]).position is None


# --------------------------------------------------------------------------- asking by place
@pytest.fixture
def walk(mem) -> Memory:
    mem.add_poses("s1", T, POS, YAW)
    notes = ["picked up the red drill", "the red drill again", "put the mug on the shelf"]
    mem.add_many("s1", "text", notes, t=[2.0, 17.0, 10.0])
    mem.add("s2", "text", "the red drill in another room", t=2.0, position=(2, 0, 0.5))
    return mem


def test_search_near_keeps_only_hits_in_the_sphere(walk) -> None:
    hits = walk.search("red drill", k=10, near=((2.0, 0.0, 0.5), 1.0))
    assert sorted(h.session for h in hits) == ["s1", "s2"]
    assert all(np.linalg.norm(np.subtract(h.position, (2, 0, 0.5))) <= 1.0 for h in hits)
    assert [h.text for h in walk.search("drill", near=((17, 0, 0.5), 0.5))] == [
        "the red drill again"
    ]
    # the box holds (17.9, 0.9, 0.5)-ish corners but the sphere does not
    assert walk.search("drill", near=((17.8, 0.8, 0.5), 1.0)) == []
    assert [h.session for h in walk.search("drill", session="s1", near=((2, 0, 0.5), 1))] == ["s1"]


def test_frame_filter(walk) -> None:
    walk.add("s3", "text", "red drill in odom", t=1.0, position=(2, 0, 0.5), frame="odom")
    hits = walk.search("red drill", near=((2, 0, 0.5), 1.0), frame="odom")
    assert [h.frame for h in hits] == ["odom"]


def test_bad_near_is_a_typed_error(walk) -> None:
    for near in [((0, 0, 0), 0), ((0, 0, 0), -1), ((0, 0), 1), ((0, 0, np.nan), 1), "1,2,3,4"]:
        with pytest.raises(InvalidInputError, match="near"):
            walk.search("drill", near=near)


def test_temporal_operators_and_timeline_take_near(walk) -> None:
    there = ((17.0, 0.0, 0.5), 1.0)
    assert walk.count("red drill", session="s1", threshold=0.5) == 2
    assert walk.count("red drill", session="s1", threshold=0.5, near=there) == 1
    last = walk.last("red drill", session="s1", near=((2, 0, 0.5), 1))
    assert last is not None and last.position == pytest.approx((2.0, 0.0, 0.5))
    moments = walk.search_moments("red drill", near=there)
    assert [m.position for m in moments] == [pytest.approx((17.0, 0.0, 0.5))]
    assert moments[0].frame == "map"
    items = walk.timeline("s1", near=((10, 0, 0.5), 0.5))
    assert [it.text for it in items] == ["put the mug on the shelf"]
    with pytest.raises(InvalidInputError, match="episodes"):
        walk.timeline("s1", episodes=True, near=there)
    ctx = walk.after("red drill", window=100.0, session="s1", near=((2, 0, 0.5), 1))
    assert ctx is not None and ctx.anchor.t == 2.0


def test_where_and_at(walk) -> None:
    places = walk.where("red drill", session="s1")
    assert [p.position for p in places][:2] == [
        pytest.approx((2.0, 0.0, 0.5)),
        pytest.approx((17.0, 0.0, 0.5)),
    ] or [p.position for p in places][:2] == [
        pytest.approx((17.0, 0.0, 0.5)),
        pytest.approx((2.0, 0.0, 0.5)),
    ]
    assert all(places[i].score >= places[i + 1].score for i in range(len(places) - 1))
    assert all(p.frame == "map" and p.evidence for p in places)
    near_start = walk.at((2.0, 0.0, 0.5), 1.0)
    assert [(it.session, it.t) for it in near_start] == [("s1", 2.0), ("s2", 2.0)]
    assert [it.session for it in walk.at((2.0, 0.0, 0.5), 1.0, session="s2")] == ["s2"]
    assert walk.at((2.0, 0.0, 0.5), 1.0, after=5.0) == []
    assert [it.t for it in walk.at((0, 0, 0.5), 50.0, session="s1")] == [2.0, 10.0, 17.0]


def test_place_questions_have_one_home(walk) -> None:
    """``memory.where`` / ``at`` / ``add_poses`` are the very methods of ``memory.places``
    (no second implementation), and a Places built from its parts alone answers the same."""
    assert walk.where.__func__ is Places.where and walk.at.__self__ is walk.places
    assert walk.add_poses.__func__ is Places.add_poses
    alone = Places(walk.store, walk.lock, walk.registry, walk.space, walk.temporal)
    assert alone.at((2.0, 0.0, 0.5), 1.0) == walk.at((2.0, 0.0, 0.5), 1.0)
    assert [p.position for p in alone.where("red drill", session="s1")] == [
        p.position for p in walk.where("red drill", session="s1")
    ]


def test_delete_session_deletes_its_poses(walk) -> None:
    walk.delete_session("s1")
    assert walk.trajectory("s1") == []
    assert walk.places.poses.rows("s1").num_rows == 0


def _old_store(path, space) -> list[str]:
    """A store whose items table has the schema from before places (no place columns)."""
    import lancedb

    old = pa.schema([f for f in items_schema(space.dim) if f.name not in
                     {p.name for p in place_fields()}])  # fmt: skip
    mem = Memory.open(str(path), space, background=False)
    ids = mem.add_many("s1", "text", ["old drill note", "old mug note"], t=[1.0, 3.0])
    rows = mem.store.scan(None, old.names).select(old.names).cast(old)
    db = lancedb.connect(str(path))
    db.drop_table("items")
    db.create_table("items", rows, schema=old)
    assert "x" not in db.open_table("items").schema.names
    return ids


def test_old_store_that_cannot_be_written_reads_as_unplaced(
    tmp_path, hashing_space, monkeypatch
) -> None:
    from lancedb.table import LanceTable

    ids = _old_store(tmp_path / "old", hashing_space)

    def refuse(*_a, **_k):
        raise OSError("read-only file system")

    monkeypatch.setattr(LanceTable, "add_columns", refuse)
    mem = Memory.open(str(tmp_path / "old"), hashing_space, background=False)
    assert "x" not in mem.store.schema.names
    assert [h.id for h in mem.search("old drill note", k=1)] == [ids[0]]
    assert mem.get_item(ids[0]).position is None
    assert [it.position for it in mem.timeline("s1")] == [None, None]


def test_store_made_before_places_opens_and_is_backfilled(tmp_path, hashing_space) -> None:
    path = tmp_path / "old"
    ids = _old_store(path, hashing_space)

    reopened = Memory.open(str(path), hashing_space, background=False)
    assert {"x", "y", "z", "frame", "placed"} <= set(reopened.store.schema.names)
    assert reopened.get_item(ids[0]).position is None
    reopened.add_poses("s1", T, POS)
    assert reopened.get_item(ids[1]).position == pytest.approx((3.0, 0.0, 0.5))
    assert [h.text for h in reopened.search("drill", near=((1, 0, 0.5), 0.5))] == ["old drill note"]


# --------------------------------------------------------------------------- real path
@pytest.mark.slow
def test_real_where_was_i_holding_the_drill(tmp_path, minilm_space) -> None:
    mem = Memory.open(str(tmp_path / "real"), space=minilm_space, background=False)
    notes = [
        "picked up the cordless drill from the workbench",
        "put the coffee mug on the kitchen shelf",
        "opened the fridge door",
        "drilled a hole in the wooden plank",
    ]
    mem.add_many("s1", "text", notes, t=[2.0, 8.0, 12.0, 18.0])
    mem.add_poses("s1", T, POS, YAW, source="odom")  # poses after the notes: backfill
    places = mem.where("where was I holding the drill?", session="s1", k=2)
    assert places, "no place for the drill"
    assert places[0].position[0] in (pytest.approx(2.0), pytest.approx(18.0))
    assert any("drill" in (e.text or "") for e in places[0].evidence)
    at_kitchen = mem.at((8.0, 0.0, 0.5), 0.5)
    assert [it.text for it in at_kitchen] == ["put the coffee mug on the kitchen shelf"]
    hits = mem.search("coffee mug", k=4, near=((10.0, 0.0, 0.5), 3.0))
    assert [h.text for h in hits][0] == "put the coffee mug on the kitchen shelf"
    assert all(abs(h.position[0] - 10.0) <= 3.0 for h in hits)


def test_many_small_pose_batches_are_compacted(tmp_path, hashing_space) -> None:
    from tactus_memory.storage.tables import IndexConfig

    mem = Memory.open(str(tmp_path / "m"), hashing_space, background=False,
                      index=IndexConfig(compact_every=4))  # fmt: skip
    for i in range(4):  # four appends: the fourth compacts them into one fragment
        mem.add_poses("s1", T[i * 10 : (i + 1) * 10], POS[i * 10 : (i + 1) * 10])
    table = mem.places.poses._table
    assert len(table.to_lance().get_fragments()) == 1
    assert len(mem.trajectory("s1")[0].t) == 40


def test_coordinates_are_bounded(mem) -> None:
    with pytest.raises(InvalidInputError, match="beyond"):
        mem.add_poses("s1", [0.0], [[2e9, 0, 0]])
    with pytest.raises(InvalidInputError, match="beyond"):
        mem.add("s1", "text", "x", t=1.0, position=(0, 0, -2e9))
    with pytest.raises(InvalidInputError, match="near radius"):
        mem.search("x", near=((0, 0, 0), 1e200))  # r * r would not be a finite number


def test_near_on_an_indexed_store_matches_the_exact_answer(tmp_path, hashing_space) -> None:
    """With the ANN and x/y scalar indexes built, a place filter takes the prefiltered ANN
    path (its rows are scattered): the hits are the exact top k of the rows in the sphere."""
    from tactus_memory.adapters.vectors import VectorSense
    from tactus_memory.storage.tables import IndexConfig

    cfg = IndexConfig(threshold=400, scalar_threshold=400, rows_per_partition=100)
    mem = Memory.open(str(tmp_path / "ix"), hashing_space, background=False, index=cfg)
    mem.add_sense(VectorSense("motion", dim=hashing_space.dim))
    rng = np.random.default_rng(3)
    vecs = rng.standard_normal((600, hashing_space.dim)).astype(np.float32)
    vecs /= np.linalg.norm(vecs, axis=1, keepdims=True)
    pos = np.column_stack([rng.uniform(0, 50, 600), rng.uniform(0, 50, 600), np.zeros(600)])
    ids = mem.add_many("s1", "motion", list(vecs), t=np.arange(600.0).tolist(), position=pos)
    mem.optimize()
    assert mem.store.has_vector_index() and mem.store.has_scalar_indexes()
    centre, r = (25.0, 25.0, 0.0), 8.0
    inside = np.flatnonzero(np.linalg.norm(pos - centre, axis=1) <= r)
    for q in vecs[:5]:
        hits = mem.search_vector(q, k=5, near=(centre, r))
        want = inside[np.argsort(-(vecs[inside] @ q))[:5]]
        assert [h.id for h in hits] == [ids[i] for i in want]
