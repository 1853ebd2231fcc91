"""Write real MCAP files and ROS 2 bags: sample recordings for the examples, the benchmarks
and the tests (needs the ``recordings`` extra, like the readers).

MCAP through ``mcap-ros2-support``'s writer (CDR, message definitions from the rosbags type
store), ROS 2 bags through ``rosbags``' writer (sqlite3 or mcap storage) with its type store's
CDR serialisation. Messages are described once as :class:`Msg` (plain dict fields, the
layout of the ROS 2 message) and written by either.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

STRING = "std_msgs/msg/String"
IMAGE = "sensor_msgs/msg/Image"
COMPRESSED = "sensor_msgs/msg/CompressedImage"
INT16_ARRAY = "std_msgs/msg/Int16MultiArray"
FLOAT32_ARRAY = "std_msgs/msg/Float32MultiArray"
VECTOR3 = "geometry_msgs/msg/Vector3"  # a type no sense takes
ODOMETRY = "nav_msgs/msg/Odometry"
POSE_STAMPED = "geometry_msgs/msg/PoseStamped"
TF = "tf2_msgs/msg/TFMessage"
NS = 1_000_000_000
GLOVE_HZ = 30.0  # glove / taxel-array rate the README assumes ("~30 Hz")


@dataclass(frozen=True)
class Msg:
    topic: str
    msgtype: str
    log_ns: int
    fields: dict[str, Any]


def _typestore() -> Any:
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(getattr(Stores, "LATEST", Stores.ROS2_HUMBLE))


def _header(stamp_ns: int | None, frame_id: str = "glove") -> dict[str, Any]:
    ns = stamp_ns or 0
    return {"stamp": {"sec": ns // NS, "nanosec": ns % NS}, "frame_id": frame_id}


def _pose(position: Sequence[float], quat: Sequence[float]) -> dict[str, Any]:
    return {
        "position": dict(zip("xyz", map(float, position), strict=True)),
        "orientation": dict(zip("xyzw", map(float, quat), strict=True)),
    }


def odometry(topic: str, log_ns: int, position: Sequence[float], quat: Sequence[float],
             frame_id: str = "odom") -> Msg:  # fmt: skip
    """A ``nav_msgs/Odometry`` (stamp = log time) with the pose in ``frame_id``."""
    zero3 = {"x": 0.0, "y": 0.0, "z": 0.0}
    return Msg(topic, ODOMETRY, log_ns, {
        "header": _header(log_ns, frame_id), "child_frame_id": "base_link",
        "pose": {"pose": _pose(position, quat), "covariance": [0.0] * 36},
        "twist": {"twist": {"linear": zero3, "angular": dict(zero3)}, "covariance": [0.0] * 36},
    })  # fmt: skip


def pose_stamped(topic: str, log_ns: int, position: Sequence[float], quat: Sequence[float],
                 frame_id: str = "map") -> Msg:  # fmt: skip
    return Msg(topic, POSE_STAMPED, log_ns,
               {"header": _header(log_ns, frame_id), "pose": _pose(position, quat)})  # fmt: skip


def tf(topic: str, log_ns: int, transforms: Sequence[tuple[str, str, Sequence[float]]]) -> Msg:
    """A ``tf2_msgs/TFMessage`` of (parent, child, (x, y, z)) transforms, identity rotation."""
    return Msg(topic, TF, log_ns, {"transforms": [
        {"header": _header(log_ns, parent), "child_frame_id": child,
         "transform": {"translation": dict(zip("xyz", map(float, xyz), strict=True)),
                       "rotation": {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0}}}
        for parent, child, xyz in transforms
    ]})  # fmt: skip


def note(topic: str, log_ns: int, text: str) -> Msg:
    return Msg(topic, STRING, log_ns, {"data": text})


def mono16(topic: str, log_ns: int, frame: np.ndarray, stamp_ns: int | None = None) -> Msg:
    """A (H, W) raw frame as a ``mono16`` little-endian Image (header stamp when given)."""
    f = np.ascontiguousarray(frame, dtype="<u2")
    h, w = f.shape
    return Msg(topic, IMAGE, log_ns, {
        "header": _header(stamp_ns), "height": h, "width": w, "encoding": "mono16",
        "is_bigendian": 0, "step": 2 * w, "data": f.tobytes(),
    })  # fmt: skip


def rgb8(topic: str, log_ns: int, image: np.ndarray) -> Msg:
    im = np.ascontiguousarray(image, dtype=np.uint8)
    h, w, _ = im.shape
    return Msg(topic, IMAGE, log_ns, {
        "header": _header(None), "height": h, "width": w, "encoding": "rgb8",
        "is_bigendian": 0, "step": 3 * w, "data": im.tobytes(),
    })  # fmt: skip


def _multi_array(topic: str, log_ns: int, frame: np.ndarray, msgtype: str, dtype: type) -> Msg:
    h, w = frame.shape
    layout = {"dim": [{"label": "rows", "size": h, "stride": h * w},
                      {"label": "cols", "size": w, "stride": w}], "data_offset": 0}  # fmt: skip
    values: list[Any] = np.asarray(frame, dtype).reshape(-1).tolist()  # Python ints / floats
    return Msg(topic, msgtype, log_ns, {"layout": layout, "data": values})


def int16_array(topic: str, log_ns: int, frame: np.ndarray) -> Msg:
    return _multi_array(topic, log_ns, frame, INT16_ARRAY, np.int16)


def float32_array(topic: str, log_ns: int, frame: np.ndarray) -> Msg:
    return _multi_array(topic, log_ns, frame, FLOAT32_ARRAY, np.float32)


def vector3(topic: str, log_ns: int) -> Msg:
    return Msg(topic, VECTOR3, log_ns, {"x": 1.0, "y": 2.0, "z": 3.0})


def glove(topic: str, frames: np.ndarray, *, start_ns: int, hz: float = GLOVE_HZ,
          stamped: bool = True) -> list[Msg]:  # fmt: skip
    """(N, 32, 32) raw frames -> N mono16 Images at ``hz`` (header stamps = log times)."""
    out = []
    for i, f in enumerate(frames):
        ns = start_ns + round(i * NS / hz)
        out.append(mono16(topic, ns, f, ns if stamped else None))
    return out


def write_mcap(path: str | Path, messages: Iterable[Msg]) -> Path:
    """A real MCAP file (ROS 2 CDR) via mcap-ros2-support's writer."""
    from mcap_ros2.writer import Writer

    ts = _typestore()
    p = Path(path)
    with p.open("wb") as fh:
        w = Writer(fh)
        schemas: dict[str, Any] = {}
        for m in sorted(messages, key=lambda m: m.log_ns):
            if m.msgtype not in schemas:
                text, _ = ts.generate_msgdef(m.msgtype, ros_version=2)
                schemas[m.msgtype] = w.register_msgdef(m.msgtype, text)
            w.write_message(m.topic, schemas[m.msgtype], m.fields, log_time=m.log_ns,
                            publish_time=m.log_ns)  # fmt: skip
        w.finish()
    return p


def _ros(ts: Any, msgtype: str, f: dict[str, Any]) -> Any:
    """Plain dict fields -> a rosbags message object of ``msgtype``."""
    T = ts.types

    def header(h: dict[str, Any]) -> Any:
        stamp = T["builtin_interfaces/msg/Time"](
            sec=h["stamp"]["sec"], nanosec=h["stamp"]["nanosec"]
        )
        return T["std_msgs/msg/Header"](stamp=stamp, frame_id=h["frame_id"])

    if msgtype == STRING:
        return T[STRING](data=f["data"])
    if msgtype == IMAGE:
        return T[IMAGE](header=header(f["header"]), height=f["height"], width=f["width"],
                        encoding=f["encoding"], is_bigendian=f["is_bigendian"], step=f["step"],
                        data=np.frombuffer(f["data"], np.uint8))  # fmt: skip
    if msgtype in (INT16_ARRAY, FLOAT32_ARRAY):
        dims = [T["std_msgs/msg/MultiArrayDimension"](**d) for d in f["layout"]["dim"]]
        layout = T["std_msgs/msg/MultiArrayLayout"](dim=dims, data_offset=0)
        dtype = np.int16 if msgtype == INT16_ARRAY else np.float32
        return T[msgtype](layout=layout, data=np.asarray(f["data"], dtype))
    if msgtype == VECTOR3:
        return T[VECTOR3](**f)

    def pose(p: dict[str, Any]) -> Any:
        return T["geometry_msgs/msg/Pose"](
            position=T["geometry_msgs/msg/Point"](**p["position"]),
            orientation=T["geometry_msgs/msg/Quaternion"](**p["orientation"]),
        )

    if msgtype == ODOMETRY:
        v3 = T["geometry_msgs/msg/Vector3"]
        twist = T["geometry_msgs/msg/Twist"](linear=v3(x=0.0, y=0.0, z=0.0),
                                             angular=v3(x=0.0, y=0.0, z=0.0))  # fmt: skip
        cov = np.zeros(36, np.float64)
        return T[ODOMETRY](
            header=header(f["header"]), child_frame_id=f["child_frame_id"],
            pose=T["geometry_msgs/msg/PoseWithCovariance"](pose=pose(f["pose"]["pose"]),
                                                           covariance=cov),
            twist=T["geometry_msgs/msg/TwistWithCovariance"](twist=twist, covariance=cov),
        )  # fmt: skip
    if msgtype == POSE_STAMPED:
        return T[POSE_STAMPED](header=header(f["header"]), pose=pose(f["pose"]))
    if msgtype == TF:
        return T[TF](transforms=[
            T["geometry_msgs/msg/TransformStamped"](
                header=header(x["header"]), child_frame_id=x["child_frame_id"],
                transform=T["geometry_msgs/msg/Transform"](
                    translation=T["geometry_msgs/msg/Vector3"](**x["transform"]["translation"]),
                    rotation=T["geometry_msgs/msg/Quaternion"](**x["transform"]["rotation"]),
                ),
            ) for x in f["transforms"]
        ])  # fmt: skip
    raise ValueError(f"no rosbags conversion for {msgtype}")


def write_bag(path: str | Path, messages: Sequence[Msg], *, storage: str = "sqlite3") -> Path:
    """A real ROS 2 bag folder via rosbags' writer (``storage``: sqlite3 or mcap)."""
    from rosbags.rosbag2 import StoragePlugin, Writer

    ts = _typestore()
    plugin = StoragePlugin.SQLITE3 if storage == "sqlite3" else StoragePlugin.MCAP
    p = Path(path)
    with Writer(p, version=9, storage_plugin=plugin) as w:
        conns: dict[str, Any] = {}
        for m in sorted(messages, key=lambda m: m.log_ns):
            if m.topic not in conns:
                conns[m.topic] = w.add_connection(m.topic, m.msgtype, typestore=ts)
            w.write(
                conns[m.topic], m.log_ns, ts.serialize_cdr(_ros(ts, m.msgtype, m.fields), m.msgtype)
            )
    return p


def synthetic_grasp(n: int, seed: int = 0) -> np.ndarray:
    """(n, 32, 32) int16 raw frames that look like a glove: rest ~512, a pressed blob."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:32, 0:32]
    frames = np.empty((n, 32, 32), np.int16)
    for i in range(n):
        cy, cx = 16 + 6 * np.sin(i / 20), 16 + 6 * np.cos(i / 25)
        blob = 300 * np.exp(-((yy - cy) ** 2 + (xx - cx) ** 2) / 30.0)
        frames[i] = (512 + blob + rng.normal(0, 2, (32, 32))).clip(500, 1000).astype(np.int16)
    return frames
