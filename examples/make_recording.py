"""Write a small MCAP recording to try `tactus ingest` on: notes, a 3 s glove grasp, odometry.

    python examples/make_recording.py run1.mcap

Real ROS 2 messages (CDR) written with mcap-ros2-support (the `recordings` extra, which
`make run` installs): `/notes` (std_msgs/String), `/glove/pressure` (sensor_msgs/Image,
mono16 32x32 raw glove frames at 30 Hz) and `/odom` (nav_msgs/Odometry at 10 Hz, the robot
driving along x at 0.5 m/s in the `odom` frame).
"""

import sys

import numpy as np
from mcap_ros2.writer import Writer
from rosbags.typesys import Stores, get_typestore

NS = 1_000_000_000
TYPES = ["std_msgs/msg/String", "sensor_msgs/msg/Image", "nav_msgs/msg/Odometry"]


def stamp(ns: int, frame_id: str) -> dict:
    return {"stamp": {"sec": ns // NS, "nanosec": ns % NS}, "frame_id": frame_id}


def grasp(n: int) -> np.ndarray:
    """(n, 32, 32) raw frames: the glove at rest (~512) with a pressed blob that moves."""
    rng = np.random.default_rng(0)
    yy, xx = np.mgrid[0:32, 0:32]
    frames = np.empty((n, 32, 32), np.uint16)
    for i in range(n):
        cy, cx = 16 + 6 * np.sin(i / 20), 16 + 6 * np.cos(i / 25)
        blob = 300 * np.exp(-((yy - cy) ** 2 + (xx - cx) ** 2) / 30.0)
        frames[i] = (512 + blob + rng.normal(0, 2, (32, 32))).clip(500, 1000)
    return frames


def main(path: str) -> None:
    store = get_typestore(Stores.ROS2_HUMBLE)
    messages = []  # (log time ns, topic, type, fields)
    notes = [(1.0, "picked up the mug"), (4.0, "put it down")]
    for t, text in notes:
        messages.append((int(t * NS), "/notes", TYPES[0], {"data": text}))
    for i, frame in enumerate(grasp(90)):  # 3 s at 30 Hz
        ns = round(i * NS / 30)
        image = {
            "header": stamp(ns, "glove"),
            "height": 32,
            "width": 32,
            "encoding": "mono16",
            "is_bigendian": 0,
            "step": 64,
            "data": frame.astype("<u2").tobytes(),
        }
        messages.append((ns, "/glove/pressure", TYPES[1], image))
    zero = {"x": 0.0, "y": 0.0, "z": 0.0}
    for i in range(61):  # 6 s at 10 Hz
        ns, x = i * NS // 10, 0.05 * i
        pose = {
            "position": {"x": x, "y": 0.0, "z": 0.0},
            "orientation": {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0},
        }
        odom = {
            "header": stamp(ns, "odom"),
            "child_frame_id": "base_link",
            "pose": {"pose": pose, "covariance": [0.0] * 36},
            "twist": {"twist": {"linear": zero, "angular": zero}, "covariance": [0.0] * 36},
        }
        messages.append((ns, "/odom", TYPES[2], odom))
    with open(path, "wb") as fh:
        writer = Writer(fh)
        schemas = {}
        for name in TYPES:
            text, _ = store.generate_msgdef(name, ros_version=2)
            schemas[name] = writer.register_msgdef(name, text)
        for ns, topic, name, fields in sorted(messages, key=lambda m: m[0]):
            writer.write_message(topic, schemas[name], fields, log_time=ns, publish_time=ns)
        writer.finish()
    print(f"wrote {path}: {len(messages)} messages on /notes, /glove/pressure, /odom")


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else "run1.mcap")
