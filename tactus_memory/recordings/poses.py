"""ROS 2 pose messages -> a session trajectory (``tactus ingest --topic /odom=pose``).

A topic mapped to :data:`POSE` becomes poses of the session (``Memory.add_poses``), read
before the items so that every note, touch window and image of the recording is placed as it
is written:

* ``nav_msgs/msg/Odometry``: ``pose.pose`` in ``header.frame_id`` (e.g. ``odom``);
* ``geometry_msgs/msg/PoseStamped``: ``pose`` in ``header.frame_id``;
* ``tf2_msgs/msg/TFMessage`` (``/tf``): the transforms of one chosen parent -> child pair
  (``tf=("map", "base_link")``; the child's origin in the parent frame), frame = the parent.

Times are the header stamps (log time when unset) on the same clock as the items. Messages
with equal stamps keep the first; an all-zero quaternion (an unset orientation) drops the
topic's orientations (positions are kept). The poses of one topic are one ``add_poses``
call with ``source`` = the topic as an id; a topic whose poses are already stored (a second
ingest of the same file) is not written again.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from tactus_memory.errors import RecordingError
from tactus_memory.recordings.reader import Recording
from tactus_memory.where import DEFAULT_FRAME, validate_frame

#: the pseudo-sense a topic maps to when it carries the session's trajectory
POSE = "pose"
ODOMETRY = "nav_msgs/msg/Odometry"
POSE_STAMPED = "geometry_msgs/msg/PoseStamped"
TF = "tf2_msgs/msg/TFMessage"
POSE_TYPES = (ODOMETRY, POSE_STAMPED, TF)
#: the transform read from a TFMessage topic unless another pair is chosen (REP 105)
DEFAULT_TF = (DEFAULT_FRAME, "base_link")
NS = 1_000_000_000


@dataclass
class PoseTrack:
    """The poses read from one topic (times in ns, before the session clock is applied)."""

    topic: str
    frame: str = ""
    ns: list[int] = field(default_factory=list)
    position: list[tuple[float, float, float]] = field(default_factory=list)
    orientation: list[tuple[float, float, float, float]] = field(default_factory=list)

    def arrays(self, t0_ns: int | None) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        """(t ``(N,)`` seconds, position ``(N, 3)``, orientation ``(N, 4)`` or None), sorted,
        one pose per stamp; ``t0_ns`` None: unix seconds."""
        ns = np.asarray(self.ns, dtype=np.int64)
        order = np.argsort(ns, kind="stable")
        ns = ns[order]
        keep = np.concatenate([[True], np.diff(ns) > 0]) if ns.size else np.zeros(0, bool)
        idx = order[keep]
        t = (ns[keep] - (t0_ns or 0)) / NS
        pos = np.asarray(self.position, dtype=np.float64).reshape(-1, 3)[idx]
        ori = np.asarray(self.orientation, dtype=np.float64).reshape(-1, 4)[idx]
        norms = np.linalg.norm(ori, axis=1)
        if ori.size == 0 or (norms < 1e-6).any():
            return t, pos, None
        return t, pos, ori / norms[:, None]


def stamp_or_log(msg: Any, log_ns: int) -> int:
    header = getattr(msg, "header", None)
    stamp = getattr(header, "stamp", None)
    if stamp is not None:
        ns = int(stamp.sec) * NS + int(stamp.nanosec)
        if ns > 0:
            return ns
    return log_ns


def tf_ns(msg: Any, log_ns: int) -> int:
    """The earliest stamp of a TFMessage's transforms (log time when it has none)."""
    return min((stamp_or_log(x, log_ns) for x in msg.transforms), default=log_ns)


def _xyz(v: Any) -> tuple[float, float, float]:
    return float(v.x), float(v.y), float(v.z)


def _xyzw(q: Any) -> tuple[float, float, float, float]:
    return float(q.x), float(q.y), float(q.z), float(q.w)


def check_pose_topic(topic: str, msgtype: str) -> None:
    if msgtype not in POSE_TYPES:
        raise RecordingError(
            f"topic {topic!r} has type {msgtype!r}, which cannot become poses "
            f"(supported for {POSE}: {', '.join(POSE_TYPES)})"
        )


def already_stored(memory: Any, session: str, frame: str, t: np.ndarray) -> bool:
    """Whether every pose time ``t: (N,)`` is already in the session's ``frame`` trajectory
    (a second ingest of the same file)."""
    for tr in memory.trajectory(session, frame):
        return bool(np.isin(t, np.asarray(tr.t)).all())
    return False


def read_poses(
    recordings: Sequence[Recording], topics: Sequence[str], tf: tuple[str, str] = DEFAULT_TF
) -> list[PoseTrack]:
    """Every pose of ``topics`` in ``recordings`` (all files), one track per topic."""
    parent, child = (validate_frame(f) for f in tf)
    tracks = {t: PoseTrack(t) for t in topics}
    for rec in recordings:
        for m in rec.messages(sorted(topics)):
            tr = tracks[m.topic]
            check_pose_topic(m.topic, m.msgtype)
            if m.msgtype == TF:
                for tx in m.msg.transforms:
                    pair = (str(tx.header.frame_id).lstrip("/"), str(tx.child_frame_id).lstrip("/"))
                    if pair != (parent, child):
                        continue
                    _append(tr, parent, stamp_or_log(tx, m.log_time_ns),
                            tx.transform.translation, tx.transform.rotation)  # fmt: skip
                continue
            pose = m.msg.pose.pose if m.msgtype == ODOMETRY else m.msg.pose
            frame = str(m.msg.header.frame_id).lstrip("/") or DEFAULT_FRAME
            _append(tr, frame, stamp_or_log(m.msg, m.log_time_ns), pose.position, pose.orientation)
    return [tr for tr in tracks.values() if tr.ns]


def _append(tr: PoseTrack, frame: str, ns: int, position: Any, orientation: Any) -> None:
    frame = validate_frame(frame)
    if tr.frame and frame != tr.frame:
        raise RecordingError(
            f"topic {tr.topic!r} switches frame from {tr.frame!r} to {frame!r}; "
            "a trajectory topic must stay in one frame"
        )
    tr.frame = frame
    tr.ns.append(ns)
    tr.position.append(_xyz(position))
    tr.orientation.append(_xyzw(orientation))
