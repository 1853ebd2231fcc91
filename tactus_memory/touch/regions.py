"""Hand regions of a sensor: which taxels belong to the thumb, each finger, the palm, or to a
robot hand's named pads. :mod:`tactus_memory.touch.facets` splits a grasp's load over them and
names its grip from the regions that carry it.

A :class:`RegionMap` is an (H, W) int array of region indices (-1: no region) and the regions'
names. Two sources:

* **a profile's pads** (:func:`regions_of`): every pad of a sensor profile is one region, named
  as the pad (a robot hand's ``thumb``, ``index``, ``palm``, ...);
* **the STAG glove** (:data:`STAG_REGIONS`), which has no pads: its map is derived below.

**How the STAG glove's map was derived.** The glove's 548 taxels are the crossings of conductive
threads read as a 32x32 matrix; the public coordinates of those taxels (``sensor_coords.pickle``
of the MIT-licensed repository sri-sensors/ini_estim, ``sensor_coords.json`` beside the data)
occupy exactly these blocks (``tests/touch/test_regions.py`` checks the equality on the file):

* rows 0-17 x columns 14-31: an 18 x 18 block, the only block with row threads between the
  finger groups (rows 3-5, 9, 13, 14 exist only here): the **palm**, 324 taxels;
* rows 0-2, 6-8, 10-12, 15-17 x columns 0-13: four 3 x 14 strips, the row threads of the palm
  continued along four fingers (42 taxels each);
* rows 18-31 x columns 25-28: a 14 x 4 strip beyond the palm's last row, sharing the palm's
  column threads 25-28: the **thumb**, 56 taxels.

Fingers are named from the anatomy of the layout: the thumb strip leaves the palm past row 17,
so rows 15-17 are the finger next to the thumb, the **index**; then **middle** (10-12),
**ring** (6-8) and **little** (0-2). Columns 0 and 31 are the fingertips' and the wrist's ends:
the thumb joins the palm at columns 25-28, near the wrist, as a thumb does, and the fingertips'
columns (0-4) and the thumb's last rows (28-31) carry the load when the fingertips hold
something round (the STAG weights subset's cat and mug grasps; measured in the test). The
order of the four fingers is the layout's reading, not a measurement: on the blindfolded
recordings the thumb's load correlates with rows 15-17 (0.39) and rows 6-8 (0.42) alike, so a
data check cannot tell index from ring; the test checks what the data can (the partition,
fingertip and thumb-tip loading, and a palm-held object loading the palm).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from tactus_memory.errors import InvalidInputError
from tactus_memory.touch.profile import FRAME_SHAPE, STAG_GLOVE, SensorProfile

#: region names of a hand, in drawing order
THUMB, INDEX, MIDDLE, RING, LITTLE, PALM = "thumb", "index", "middle", "ring", "little", "palm"
HAND_REGIONS = (THUMB, INDEX, MIDDLE, RING, LITTLE, PALM)

#: the STAG glove's regions as (name, rows [lo, hi), cols [lo, hi)) blocks of its 32x32 grid,
#: derived from the 548 public taxel coordinates (module docstring)
STAG_BLOCKS: tuple[tuple[str, tuple[int, int], tuple[int, int]], ...] = (
    (THUMB, (18, 32), (25, 29)),
    (INDEX, (15, 18), (0, 14)),
    (MIDDLE, (10, 13), (0, 14)),
    (RING, (6, 9), (0, 14)),
    (LITTLE, (0, 3), (0, 14)),
    (PALM, (0, 18), (14, 32)),
)
#: taxels of the STAG glove (sensor_coords.json: 548 coordinates)
STAG_TAXELS = 548


@dataclass(frozen=True, eq=False)
class RegionMap:
    """``index`` (H, W) int16: each taxel's region (an index into ``names``, -1: none)."""

    names: tuple[str, ...]
    index: np.ndarray

    def __post_init__(self) -> None:
        idx = np.asarray(self.index)
        if idx.ndim != 2 or not np.issubdtype(idx.dtype, np.integer):
            raise InvalidInputError(f"a region map is an (H, W) int array, got {idx.shape}")
        if idx.size and (idx.min() < -1 or idx.max() >= len(self.names)):
            raise InvalidInputError("region map indices must lie in [-1, len(names))")
        if len(set(self.names)) != len(self.names):
            raise InvalidInputError(f"region names must be unique, got {self.names}")
        object.__setattr__(self, "names", tuple(self.names))
        object.__setattr__(self, "index", idx.astype(np.int16))

    @property
    def shape(self) -> tuple[int, int]:
        return (int(self.index.shape[0]), int(self.index.shape[1]))

    def onehot(self) -> np.ndarray:
        """(H*W, R) float32: 1 where a taxel belongs to region r (for one matmul per frame)."""
        flat = self.index.reshape(-1)
        out = np.zeros((flat.size, len(self.names)), np.float32)
        inside = flat >= 0
        out[np.flatnonzero(inside), flat[inside]] = 1.0
        return out

    def taxels(self, name: str) -> np.ndarray:
        """(H, W) bool: the taxels of region ``name``."""
        if name not in self.names:
            raise InvalidInputError(f"unknown region {name!r}; known: {list(self.names)}")
        return self.index == self.names.index(name)

    @classmethod
    def from_blocks(
        cls,
        blocks: Sequence[tuple[str, tuple[int, int], tuple[int, int]]],
        shape: tuple[int, int],
    ) -> RegionMap:
        """Named blocks ``(name, (row0, row1), (col0, col1))`` (half-open) -> a map; a taxel
        two blocks claim raises InvalidInputError."""
        idx = np.full(shape, -1, np.int16)
        for i, (name, (r0, r1), (c0, c1)) in enumerate(blocks):
            if (idx[r0:r1, c0:c1] >= 0).any():
                raise InvalidInputError(f"region {name!r} overlaps another region")
            idx[r0:r1, c0:c1] = i
        return cls(tuple(b[0] for b in blocks), idx)


STAG_REGIONS = RegionMap.from_blocks(STAG_BLOCKS, FRAME_SHAPE)


def regions_of(profile: SensorProfile) -> RegionMap | None:
    """The hand regions of ``profile``: its pads when it has some, the derived map for the
    STAG glove, else None (a skin with no named parts: facets without regions or grip)."""
    if profile.pads:
        blocks = [(p.name, (p.top, p.bottom), (p.left, p.right)) for p in profile.pads]
        return RegionMap.from_blocks(blocks, profile.shape)
    if profile.name == STAG_GLOVE.name and tuple(profile.shape) == FRAME_SHAPE:
        return STAG_REGIONS
    return None
