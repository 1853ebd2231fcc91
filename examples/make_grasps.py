"""Write a small labelled-grasps file to try `tactus adapt` on: 3 grasps of each of 3 objects.

    python examples/make_grasps.py grasps.npz

The documented own-sensor format (docs "Training on your own sensor"): `pressure` (N, 32, 32)
raw glove readings (rest ~512, the shipped encoder's calibration reads (raw - 500) / 150),
`label` (N,) the object held, `recording` (N,) one grasp each, `t` (N,) seconds at 30 Hz.
Each object presses its own few spots (a fixed pattern per object, seed 0); each grasp
presses them at its own strength, with the spots drifting a pixel and sensor noise, so no two
grasps are the same frames.
"""

import sys

import numpy as np

OBJECTS = ("sponge", "drill", "ladle")
GRASPS = 3  # per object
FRAMES = 24  # per grasp (0.8 s at 30 Hz)
HZ = 30.0


def grasp(spots: np.ndarray, strength: float, rng: np.random.Generator) -> np.ndarray:
    """(FRAMES, 32, 32) raw frames: the glove at rest (~512) with ``spots`` (S, 2) pressed."""
    yy, xx = np.mgrid[0:32, 0:32]
    frames = np.empty((FRAMES, 32, 32), np.int16)
    for i in range(FRAMES):
        p = np.zeros((32, 32))
        for cy, cx in spots + rng.normal(0, 0.7, spots.shape):
            p += np.exp(-((yy - cy) ** 2 + (xx - cx) ** 2) / 6.0)
        frames[i] = (512 + strength * p + rng.normal(0, 2, (32, 32))).clip(500, 1000)
    return frames


def main(path: str) -> None:
    rng = np.random.default_rng(0)
    pressure, label, recording = [], [], []
    for obj in OBJECTS:
        spots = rng.uniform(4, 28, size=(4, 2))  # the object's own contact places
        for g in range(GRASPS):
            pressure.append(grasp(spots, rng.uniform(150, 300), rng))
            label += [obj] * FRAMES
            recording += [f"{obj}-{g + 1}"] * FRAMES
    frames = np.concatenate(pressure)
    np.savez(
        path,
        pressure=frames,
        label=np.array(label),
        recording=np.array(recording),
        t=np.arange(len(frames)) / HZ,
    )
    print(f"wrote {path}: {len(OBJECTS)} objects x {GRASPS} grasps, {len(frames)} frames")


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else "grasps.npz")
