"""The kitchen session shared by tests/temporal/test_temporal.py (HashingSpace, fast) and
tests/temporal/test_temporal_real.py (real MiniLM): when each grasp happens, the notes written after
them, and touch stand-ins whose vectors lie near the embedding of what a grasp feels like.

Ground truth (session "kitchen", seconds): three mug grasps at 10, 40 and 70, a screwdriver
grasp at 55, an empty hand in between; a note "picked up the mug" ``delay`` s after each mug
grasp starts, "picked up the screwdriver" ``delay`` s after 55, "dropped the can" at 90.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from tactus_memory.adapters.vectors import VectorSense
from tactus_memory.memory.main import Memory
from tactus_memory.spaces.base import Space
from tests.helpers.fakes import HashingSpace

S = "kitchen"
MUG_GRASPS = [10.0, 40.0, 70.0]
SCREW_GRASP = 55.0
#: an empty hand (one window each)
IDLE = [0.0, 5.0, 20.0, 25.0, 30.0, 50.0, 60.0, 80.0, 85.0, 95.0]


def kitchen_memory(path: Path | str) -> Memory:
    """A fast memory for the kitchen scenario: HashingSpace (384-d) at the space seam, no
    background work, and a VectorSense "touch" stand-in for controlled vectors."""
    mem = Memory.open(str(path), space=HashingSpace(dim=384), background=False)
    mem.add_sense(VectorSense("touch", dim=384))
    return mem


def kitchen_notes(delay: float) -> list[tuple[str, float]]:
    """(note, t) in time order; each grasp's note ``delay`` s after the grasp starts."""
    notes = [
        ("the operator said hello", 2.0),
        ("wiped the table with a sponge", 30.0),
        ("picked up the screwdriver", SCREW_GRASP + delay),
        ("dropped the can", 90.0),
    ]
    notes += [("picked up the mug", t + delay) for t in MUG_GRASPS]
    return sorted(notes, key=lambda note: note[1])


def near_caption(space: Space, caption: str, n: int, seed: int, noise: float) -> list[np.ndarray]:
    """n unit vectors, each (dim,) float32, at distance ``noise`` (before normalising) around
    the embedding of ``caption`` (seeded)."""
    rng = np.random.default_rng(seed)
    base = space.embed_texts([caption])[0]
    out = []
    for _ in range(n):
        g = rng.standard_normal(space.dim)
        v = base + noise * g / np.linalg.norm(g)
        out.append((v / np.linalg.norm(v)).astype(np.float32))
    return out


NOTES = kitchen_notes(delay=2.5)


def fill_kitchen(mem: Memory, session: str = S, *, notes_clock: float = 0.0) -> dict[str, list]:
    """The ground-truth session; returns the ids per kind. Notes are written at
    ``t + notes_clock`` (a second clock)."""
    space = mem.space
    ids: dict[str, list] = {"mug": [], "screwdriver": [], "empty": [], "notes": []}
    for i, t0 in enumerate(MUG_GRASPS):
        ids["mug"] += mem.add_many(
            session, "touch", touch_vectors(space, "mug", 2, seed=i), t=[t0, t0 + 1],
            t_end=[t0 + 1, t0 + 2],
        )  # fmt: skip
    ids["screwdriver"] = mem.add_many(
        session, "touch", touch_vectors(space, "screwdriver", 2, seed=10),
        t=[SCREW_GRASP, SCREW_GRASP + 1], t_end=[SCREW_GRASP + 1, SCREW_GRASP + 2],
    )  # fmt: skip
    ids["empty"] = mem.add_many(
        session, "touch", touch_vectors(space, "empty", len(IDLE), seed=20), t=IDLE,
        t_end=[t + 1 for t in IDLE],
    )  # fmt: skip
    ids["notes"] = mem.add_many(
        session, "text", [n for n, _ in NOTES], t=[t + notes_clock for _, t in NOTES]
    )
    return ids


def touch_vectors(space: HashingSpace, kind: str, n: int, seed: int) -> list[np.ndarray]:
    """n unit vectors near the caption of ``kind`` (noise of norm 0.1, seeded)."""
    return near_caption(space, FEEL[kind], n, seed, noise=0.1)


#: what each stand-in touch window "feels like": its vector is this caption's embedding + noise
FEEL = {"mug": "mug ceramic handle", "screwdriver": "screwdriver grip", "empty": "empty open hand"}
