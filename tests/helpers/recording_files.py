"""The recording tests' sample session: a glove stream and notes (the writers:
:mod:`tactus_memory.recordings.samples`)."""

import numpy as np

from tactus_memory.recordings.samples import NS, Msg, glove, note, rgb8, synthetic_grasp, vector3

N_FRAMES = 100  # 3.3 s at 30 Hz -> 12 windows of 8, 4 frames left over


def _messages(frames: np.ndarray | None = None) -> list[Msg]:
    frames = synthetic_grasp(N_FRAMES) if frames is None else frames
    msgs = glove("/glove/pressure", frames, start_ns=START + NS // 2)
    msgs += [note("/notes", START + (i + 1) * NS, t) for i, t in enumerate(NOTES)]
    msgs += [vector3("/imu", START + k * NS // 10) for k in range(5)]
    msgs += [rgb8("/camera", START + NS, np.full((6, 8, 3), 90, np.uint8))]
    return msgs


TOPICS = {"/notes": "text", "/glove/pressure": "touch"}


NOTES = ["picked up the red mug", "put the mug on the shelf", "opened the fridge"]


START = 1_700_000_000 * NS  # unix 1.7e9 s
