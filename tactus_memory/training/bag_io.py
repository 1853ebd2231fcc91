"""Training data straight from a recording: tactile frames of one topic of a ROS 2 bag or an
MCAP file, labelled by a ``std_msgs/String`` topic saying what was held, turned into the
``.npz`` array format (:mod:`tactus_memory.training.npz_io`).

The label topic (one ``std_msgs/msg/String`` per change, at the log time it applies from):

    "mug"              from this message on, the hand holds a mug (until the next label)
    "" or "none"       from this message on, nothing is held
    "mug 12.0 15.5"    the hand held a mug from 12.0 s to 15.5 s after the recording's first
                       message (a span; it does not change the running label)

Frames are read with the recordings' touch decoding (``sensor_msgs/Image`` mono8/mono16/16UC1/
32FC1, ``std_msgs/{Int16,UInt16,Float32}MultiArray`` of H*W values) at their log time. Every
stretch of one label is one recording (``BAG#N``); frames holding nothing are one more
(``BAG#none``) that MAE pretraining reads and the classifier does not.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from tactus_memory.adapters.decode import STRING, touch_frame
from tactus_memory.errors import DataFormatError
from tactus_memory.recordings.reader import open_recording
from tactus_memory.touch.profile import SensorProfile
from tactus_memory.training.data import StagData
from tactus_memory.training.npz_io import NOTHING_HELD, from_arrays

NS = 1_000_000_000  # nanoseconds per second (ROS 2 log times are ns)


@dataclass(frozen=True)
class LabelSpan:
    """``label`` held over [start_ns, end_ns) of log time ("" = nothing held)."""

    label: str
    start_ns: int
    end_ns: int | None  # None: until the next running label


def parse_label(text: str, log_ns: int, origin_ns: int) -> LabelSpan:
    """One label message -> a span (``end_ns`` None for a running label). A message whose last
    two words are numbers is an explicit span in seconds from ``origin_ns``."""
    words = text.strip().split()
    if len(words) >= 3:
        try:
            t0, t1 = float(words[-2]), float(words[-1])
        except ValueError:
            pass
        else:
            if t1 <= t0:
                raise DataFormatError(f"label {text!r}: the span ends ({t1}) before it starts")
            name = " ".join(words[:-2])
            return LabelSpan(name, origin_ns + int(t0 * NS), origin_ns + int(t1 * NS))
    name = " ".join(words)
    return LabelSpan("" if name.lower() in NOTHING_HELD else name, log_ns, None)


def label_frames(times_ns: np.ndarray, spans: list[LabelSpan]) -> np.ndarray:
    """(N,) frame log times + label spans -> (N,) object array of labels ("" = none). Running
    labels apply from their time to the next running label; explicit spans override them."""
    out = np.full(times_ns.shape, "", dtype=object)
    running = sorted((s for s in spans if s.end_ns is None), key=lambda s: s.start_ns)
    for i, s in enumerate(running):
        end = running[i + 1].start_ns if i + 1 < len(running) else None
        m = times_ns >= s.start_ns
        if end is not None:
            m &= times_ns < end
        out[m] = s.label
    for s in spans:
        if s.end_ns is not None:
            out[(times_ns >= s.start_ns) & (times_ns < s.end_ns)] = s.label
    return out


def stretches(labels: np.ndarray) -> np.ndarray:
    """(N,) labels -> (N,) int64 stretch number: consecutive frames of one label share one."""
    if labels.size == 0:
        return np.zeros(0, np.int64)
    change = np.r_[True, labels[1:] != labels[:-1]]
    return np.cumsum(change).astype(np.int64) - 1


def read_bag_arrays(
    path: str | Path, topic: str, labels_topic: str, profile: SensorProfile
) -> dict[str, np.ndarray]:
    """A recording -> the array format: pressure (N, H, W), label (N,), recording (N,), t (N,)
    seconds from the first message. Raises :class:`DataFormatError` naming a missing topic or
    a wrong type."""
    rec = open_recording(path)
    found = {t.topic: t.msgtype for t in rec.topics()}
    for name, what in ((topic, "tactile"), (labels_topic, "label")):
        if name not in found:
            raise DataFormatError(f"{path}: no {what} topic {name!r}; topics: {sorted(found)}")
    if found[labels_topic] != STRING:
        raise DataFormatError(
            f"{path}: the label topic {labels_topic!r} is {found[labels_topic]}, not {STRING}"
        )
    frames: list[np.ndarray] = []
    times: list[int] = []
    texts: list[tuple[str, int]] = []
    for m in rec.messages([topic, labels_topic]):
        if m.topic == labels_topic:
            texts.append((str(m.msg.data), m.log_time_ns))
        else:
            frames.append(touch_frame(m.msg, m.msgtype, profile.shape, f"{path}:{topic}"))
            times.append(m.log_time_ns)
    if not frames:
        raise DataFormatError(f"{path}: the tactile topic {topic!r} has no messages")
    t_ns = np.asarray(times, np.int64)
    origin = int(min(t_ns.min(), *(ns for _, ns in texts))) if texts else int(t_ns.min())
    spans = [parse_label(text, ns, origin) for text, ns in texts]
    label = label_frames(t_ns, spans)
    part = stretches(label)
    stem = Path(path).name
    recording = np.array(
        [f"{stem}#{p}" if lab else f"{stem}#none" for p, lab in zip(part, label, strict=True)]
    )
    return {
        "pressure": np.stack(frames),
        "label": label.astype(str),
        "recording": recording,
        "t": (t_ns - origin) / NS,
    }


def load_bags(paths: list[Path], topic: str, labels_topic: str, profile: SensorProfile) -> StagData:
    """Recordings -> one :class:`StagData` (their frames concatenated, recordings apart)."""
    parts = [read_bag_arrays(p, topic, labels_topic, profile) for p in paths]
    cat = {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}
    return from_arrays(
        cat["pressure"], cat["label"], cat["recording"], t=cat["t"],
        source=",".join(str(p) for p in paths), profile=profile,
    )  # fmt: skip
