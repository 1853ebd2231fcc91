"""A synthetic five-pad robot hand for the own-sensor training tests: four 4x4 fingertip pads
and an 8x8 palm (layout from a TOML profile), 12-bit raw readings, and objects whose grasps
press distinct pads in distinct patterns (a pen: two fingertips; a mug: every finger and the
palm's edge; ...), with per-grasp jitter, gain and sensor noise.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

#: the five-pad hand's profile, shared with the docs (guides/own-sensor-training.md)
HAND_TOML = Path(__file__).resolve().parents[2] / "examples" / "sensors" / "five-pad-hand.toml"
HAND_SHAPE = (12, 16)  # the pads' extent
FINGERS = ("thumb", "index", "middle", "ring")

#: object -> (fingertips pressed, palm pattern, pressure level 0..1)
OBJECTS: dict[str, tuple[tuple[str, ...], str, float]] = {
    "pen": (("thumb", "index"), "none", 0.5),
    "mug": (FINGERS, "ring", 0.6),
    "ball": (FINGERS, "centre", 0.4),
    "phone": (("thumb", "index", "middle"), "flat", 0.35),
    "scissors": (("thumb", "ring"), "none", 0.8),
}


def write_toml(folder: Path) -> Path:
    """The example profile, copied into ``folder`` (as a user would keep it beside the data)."""
    path = folder / "hand.toml"
    path.write_text(HAND_TOML.read_text())
    return path


def _palm(kind: str, rng: np.random.Generator) -> np.ndarray:
    yy, xx = np.mgrid[0:8, 0:8]
    cy, cx = 3.5 + rng.normal(0, 0.4), 3.5 + rng.normal(0, 0.4)
    r = np.hypot(yy - cy, xx - cx)
    if kind == "centre":
        return np.exp(-(r**2) / 4.0)
    if kind == "ring":
        return np.exp(-((r - 3.2) ** 2) / 1.0)
    if kind == "flat":
        return np.full((8, 8), 0.6)
    return np.zeros((8, 8))


def _tip(rng: np.random.Generator) -> np.ndarray:
    yy, xx = np.mgrid[0:4, 0:4]
    cy, cx = 1.5 + rng.normal(0, 0.5), 1.5 + rng.normal(0, 0.5)
    return np.exp(-((yy - cy) ** 2 + (xx - cx) ** 2) / 2.5)


def grasp(obj: str, n: int, rng: np.random.Generator, profile) -> dict[str, np.ndarray]:
    """One grasp of ``obj``: n frames per pad, {pad: (n, rows, cols)} raw readings between the
    profile's rest and saturation levels."""
    tips, palm, level = OBJECTS[obj]
    rest, top = profile.rest_raw, profile.saturation_raw
    gain = level * rng.uniform(0.8, 1.2)
    ramp = np.clip(np.sin(np.linspace(0.2, np.pi - 0.2, n)) * 1.3, 0, 1)[:, None, None]
    span = top - rest
    out: dict[str, np.ndarray] = {}
    for pad in FINGERS:
        shape = _tip(rng) if pad in tips else np.zeros((4, 4))
        out[pad] = rest + span * gain * ramp * shape + rng.normal(0, 6, (n, 4, 4))
    out["palm"] = rest + span * gain * ramp * _palm(palm, rng) + rng.normal(0, 6, (n, 8, 8))
    return {k: np.clip(np.rint(v), 0, top).astype(np.int16) for k, v in out.items()}


def recordings(
    profile, per_object: int = 4, frames: int = 48, seed: int = 0
) -> list[tuple[str, np.ndarray]]:
    """``per_object`` grasps of every object: [(object, (frames, 12, 16) raw frames)]."""
    rng = np.random.default_rng(seed)
    return [
        (obj, profile.assemble(grasp(obj, frames, rng, profile)))
        for _ in range(per_object)
        for obj in OBJECTS
    ]


def as_arrays(recs: list[tuple[str, np.ndarray]]) -> dict[str, np.ndarray]:
    """Recordings -> the training .npz arrays (pressure, label, recording, t)."""
    pressure = np.concatenate([f for _, f in recs])
    label = np.concatenate([[obj] * len(f) for obj, f in recs])
    rec = np.concatenate([[f"grasp{i:02d}"] * len(f) for i, (_, f) in enumerate(recs)])
    t = np.arange(len(pressure), dtype=np.float64) / 30.0
    return {"pressure": pressure, "label": label, "recording": rec, "t": t}
