"""Trajectories from recordings (issue 23): real MCAP files and ROS 2 bags written by the
recording libraries, with nav_msgs/Odometry, geometry_msgs/PoseStamped and tf2_msgs/TFMessage
topics mapped to ``pose``; the real MiniLM space, the shipped touch encoder on synthetic glove
frames; the CLI; the Rerun export read back."""

from __future__ import annotations

import json

import pytest
from scipy.spatial.transform import Rotation
from typer.testing import CliRunner

from tactus_memory.errors import RecordingError
from tactus_memory.memory.main import Memory
from tactus_memory.recordings import samples as rf
from tactus_memory.recordings.ingest import ingest_recording
from tactus_memory.recordings.rerun import export_rerun

pytestmark = pytest.mark.slow

START = 1_760_000_000 * rf.NS
HZ = 20  # odometry rate
SPEED = 0.5  # m/s along x
SECONDS = 12
NOTES = [(1.0, "picked up the cordless drill"), (9.0, "put the coffee mug on the shelf")]


def _odom(topic: str = "/odom") -> list[rf.Msg]:
    out = []
    for i in range(SECONDS * HZ + 1):
        t = i / HZ
        quat = Rotation.from_euler("z", 10.0 * t, degrees=True).as_quat()
        out.append(rf.odometry(topic, START + round(t * rf.NS), (SPEED * t, 1.0, 0.0), quat))
    return out


def _notes() -> list[rf.Msg]:
    return [rf.note("/notes", START + round(t * rf.NS), text) for t, text in NOTES]


@pytest.fixture
def memory(tmp_path, minilm_space) -> Memory:
    from tactus_memory.adapters.touch import TactusEncoder

    mem = Memory.open(str(tmp_path / "mem"), space=minilm_space, background=False)
    mem.add_sense(TactusEncoder())
    return mem


def test_real_mcap_odometry_places_notes_and_touch(tmp_path, memory) -> None:
    from rerun.chunk import RrdReader

    frames = rf.synthetic_grasp(64)  # (64, 32, 32) raw, ~2.1 s at 30 Hz from t = 4 s
    glove = rf.glove("/glove/pressure", frames, start_ns=START + 4 * rf.NS)
    path = rf.write_mcap(tmp_path / "run.mcap", [*_odom(), *_notes(), *glove])
    topics = {"/notes": "text", "/glove/pressure": "touch", "/odom": "pose"}
    s = ingest_recording(memory, path, session="run1", topics=topics)
    assert s.poses == {"/odom": SECONDS * HZ + 1}
    assert s.rows["text"] == 2 and s.rows.get("touch", 0) >= 1
    traj = memory.trajectory("run1")
    assert [(tr.frame, len(tr.t)) for tr in traj] == [("odom", SECONDS * HZ + 1)]
    for item in memory.timeline("run1"):
        mid = (item.t + item.t_end) / 2
        assert item.frame == "odom"
        assert item.position == pytest.approx((SPEED * mid, 1.0, 0.0), abs=1e-6)
    drill = memory.get_item(memory.search("drill", k=1, senses=["text"])[0].id)
    yaw = Rotation.from_quat(drill.orientation).as_euler("zyx", degrees=True)[0]
    assert yaw == pytest.approx(10.0, abs=1e-3)  # slerped at t = 1 s
    places = memory.where("where was I holding the drill?", session="run1", senses=["text"])
    assert places[0].position == pytest.approx((SPEED * 1.0, 1.0, 0.0))
    near_shelf = memory.at((SPEED * 9.0, 1.0, 0.0), 0.3)
    assert [it.text for it in near_shelf] == ["put the coffee mug on the shelf"]
    # a second ingest adds no poses and no items
    again = ingest_recording(memory, path, session="run1", topics=topics)
    assert again.poses == {"/odom": 0} and again.rows == {}
    assert len(memory.trajectory("run1")[0].t) == SECONDS * HZ + 1
    # Rerun: the trajectory, the robot on the timeline, the placed items and hits
    out = export_rerun(memory, "run1", tmp_path / "run1.rrd", query="the coffee mug")
    assert out.entities["places/robot/odom"] == SECONDS * HZ + 1
    assert out.entities["places/items"] == len(memory.timeline("run1"))
    assert out.entities.get("places/hits", 0) >= 1
    paths = {c.entity_path for c in RrdReader(out.path).stream().to_chunks()}
    want = {"/places/trajectory/odom", "/places/robot/odom", "/places/items", "/places/hits"}
    assert want <= paths


def test_real_bag_pose_stamped_and_tf_pair(tmp_path, memory) -> None:
    tf_msgs = []
    for i in range(41):  # 4 s at 10 Hz: map->base_link moves along y; odom->base_link is noise
        ns = START + round(i * rf.NS / 10)
        tf_msgs.append(rf.tf("/tf", ns, [("map", "base_link", (0.0, 0.25 * i, 0.0)),
                                         ("odom", "base_link", (99.0, 99.0, 99.0))]))  # fmt: skip
    notes = [rf.note("/notes", START + 2 * rf.NS, "opened the fridge door")]
    path = rf.write_bag(tmp_path / "bag", [*tf_msgs, *notes], storage="sqlite3")
    s = ingest_recording(memory, path, session="tf1", topics={"/notes": "text", "/tf": "pose"})
    assert s.poses == {"/tf": 41}
    item = memory.timeline("tf1")[0]
    assert (item.frame, item.position) == ("map", pytest.approx((0.0, 5.0, 0.0)))

    stamped = [rf.pose_stamped("/goal_pose", START + i * rf.NS, (i, -i, 0.5), (0, 0, 0, 1))
               for i in range(5)]  # fmt: skip
    bag2 = rf.write_bag(tmp_path / "bag2", [*stamped, *notes], storage="mcap")
    ingest_recording(memory, bag2, session="ps1", topics={"/notes": "text", "/goal_pose": "pose"})
    assert memory.timeline("ps1")[0].position == pytest.approx((2.0, -2.0, 0.5))

    with pytest.raises(RecordingError, match="cannot become poses"):
        ingest_recording(memory, bag2, session="bad", topics={"/notes": "pose"})
    assert memory.trajectory("bad") == []


def test_real_cli_ingest_with_pose_topic(tmp_path) -> None:
    from tactus_memory.cli.app import app

    path = rf.write_mcap(tmp_path / "run.mcap", [*_odom(), *_notes()])
    data = tmp_path / "mem"
    runner = CliRunner()
    listed = runner.invoke(app, ["ingest", str(path), "--list", "--json"])
    assert listed.exit_code == 0, listed.output
    senses = {r["topic"]: r["sense"] for r in json.loads(listed.output)}
    assert senses["/odom"] == "pose"
    cmd = ["ingest", str(path), "--session", "cli1", "--data", str(data), "--json"]
    res = runner.invoke(app, [*cmd, "--topic", "/notes=text", "--topic", "/odom=pose"])
    assert res.exit_code == 0, res.output
    assert json.loads(res.output)["poses"] == {"/odom": SECONDS * HZ + 1}
    bad = runner.invoke(app, [*cmd, "--topic", "/odom=pose", "--tf", "map"])
    assert bad.exit_code != 0 and "PARENT->CHILD" in bad.output
    mem = Memory.open(str(data), background=False)
    assert mem.timeline("cli1")[1].position == pytest.approx((SPEED * 9.0, 1.0, 0.0))
