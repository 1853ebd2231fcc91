"""What ``tactus adapt`` learns from: a user's few labelled grasps as K-frame windows.

Two sources give the same :class:`Grasps`:

* **files** (:func:`grasps_from_data`): a ``.npz`` of your sensor (``npz_io.py``), a bag with a
  label topic (``bag_io.py``) or STAG files, read as ``tactus train`` reads them. Each
  recording (one object held) is one grasp; its labelled frames, in time order, are cut into
  windows of K consecutive frames every :data:`STRIDE_DIVISOR`-th of K (a grasp shorter than
  K is one window, its last frame repeated, as the model pads a short window);
* **a memory** (:func:`grasps_from_memory`): "train on what I taught". Every teaching of the
  sense (``memory.teach(label, session=..., after=..., before=...)``) is one grasp; its
  windows are the stored windows of the taught span (the calibrated frames the memory keeps
  in ``raw``), read back from the store, not re-cut.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from tactus_memory.errors import DataFormatError, InvalidInputError, TactusError

#: windows are cut every K // STRIDE_DIVISOR frames (half-overlapping, as the stream windows)
STRIDE_DIVISOR = 2
#: at most this many windows per grasp (a long recording would outweigh a short one)
MAX_WINDOWS_PER_GRASP = 64


@dataclass
class Grasps:
    """Labelled windows, each from one grasp."""

    windows: np.ndarray  # (W, K, H, W') float32 calibrated to [0, 1]
    labels: list[str]  # (W,) the object held in each window
    grasp: np.ndarray  # (W,) int64: which grasp (recording, teaching) a window comes from
    source: str  # what they were read from, for the checkpoint's record

    def __post_init__(self) -> None:
        if len(self.windows) == 0:
            raise InvalidInputError(f"{self.source}: no labelled grasp to adapt on")
        if len(self.labels) != len(self.windows) or len(self.grasp) != len(self.windows):
            raise InvalidInputError("windows, labels and grasp ids must pair up")

    @property
    def classes(self) -> list[str]:
        """The distinct labels, in order of first appearance."""
        return list(dict.fromkeys(self.labels))

    def fingerprint(self) -> str:
        """sha256 of the windows and their labels (the checkpoint's data fingerprint)."""
        h = hashlib.sha256(np.ascontiguousarray(self.windows, np.float32).tobytes())
        h.update("\n".join(self.labels).encode())
        return h.hexdigest()

    def summary(self) -> dict[str, Any]:
        return {
            "source": self.source,
            "windows": len(self.windows),
            "grasps": len(np.unique(self.grasp)),
            "labels": self.classes,
        }


def pad_window(frames: np.ndarray, k: int) -> np.ndarray:
    """(n, H, W) with 1 <= n <= k -> (k, H, W), the last frame repeated (the model's padding)."""
    if len(frames) >= k:
        return frames[:k]
    return np.concatenate([frames, np.repeat(frames[-1:], k - len(frames), axis=0)])


def cut_windows(frame_idx: np.ndarray, k: int) -> np.ndarray:
    """(n,) frame indices of one grasp, in time order -> (w, k) windows of consecutive
    indices every ``k // STRIDE_DIVISOR`` (one padded window when n < k)."""
    n = len(frame_idx)
    if n <= k:
        return pad_window(frame_idx[:, None, None], k)[None, :, 0, 0]
    stride = max(1, k // STRIDE_DIVISOR)
    starts = np.arange(0, n - k + 1, stride)
    if len(starts) > MAX_WINDOWS_PER_GRASP:  # evenly over the grasp
        starts = starts[np.linspace(0, len(starts) - 1, MAX_WINDOWS_PER_GRASP).astype(int)]
    return frame_idx[starts[:, None] + np.arange(k)[None, :]]


def grasps_from_data(data: Any, profile: Any, k: int, source: str) -> Grasps:
    """A loaded ``StagData`` (``.npz``, bag or STAG files) -> its labelled frames as windows.

    ``profile`` calibrates the frames (the base checkpoint's sensor); the dynamic-range gate
    of training applies (a file on another scale fails, naming it)."""
    data.check_dynamic_range(profile)  # raises DynamicRangeError naming the file
    cal = data.calibrated(profile)  # (N, H, W) float32
    order = np.lexsort((data.ts, data.recording_id))
    wins, labels, grasp = [], [], []
    for r in np.unique(data.recording_id[data.valid]):
        idx = order[(data.recording_id[order] == r) & data.valid[order]]
        cut = cut_windows(idx, k)  # (w, k)
        wins.append(cal[cut])  # (w, k, H, W)
        labels += [data.objects[int(data.object_id[idx[0]])]] * len(cut)
        grasp += [int(r)] * len(cut)
    if not wins:
        raise DataFormatError(f"{source}: no labelled frames (label '' or 'none' everywhere)")
    return Grasps(np.concatenate(wins), labels, np.asarray(grasp, np.int64), source)


def is_memory_folder(path: Path) -> bool:
    """A folder that holds a memory's store (its items table), not STAG files."""
    from tactus_memory.storage.store import ITEMS

    return path.is_dir() and (path / f"{ITEMS}.lance").is_dir()


def grasps_from_memory(
    path: Path, k: int, shape: tuple[int, ...], sense: str = "touch", space: Any = None
) -> tuple[Grasps, Any]:
    """Every teaching of ``sense`` in the memory at ``path`` -> (its stored windows as
    :class:`Grasps`, the memory's space). ``space``: the memory's, already loaded (default:
    the one the store records). Raises InvalidInputError when nothing is taught or the
    windows are not ``shape`` frames (a memory of another sensor)."""
    from tactus_memory.memory.main import Memory
    from tactus_memory.senses.base import bytes_to_array
    from tactus_memory.where import Where

    if not is_memory_folder(path):
        raise InvalidInputError(f"{path} is not a memory (no {path}/items.lance)")
    try:
        mem = Memory.open(str(path), space=space, background=False)
    except TactusError:
        raise
    except (ValueError, OSError) as exc:  # a folder that only looks like a memory
        raise InvalidInputError(f"{path}: not a readable memory: {exc}") from exc
    try:
        taught = mem.teachings.taught(sense)
        if not taught:
            raise InvalidInputError(
                f"{path}: nothing is taught to sense {sense!r}; teach grasps first "
                "(tactus teach LABEL --session S --after T0 --before T1)"
            )
        wins, labels, grasp = [], [], []
        for g, t in enumerate(taught):
            where = Where().session(t.session).sense(t.sense).overlaps(t.t, t.t_end)
            rows = mem.store.scan(where.sql(), ["raw", "t"]).to_pylist()
            for row in sorted(rows, key=lambda r: r["t"]):
                if row["raw"] is None:
                    continue  # a window stored without its frames cannot be trained on
                w = np.asarray(bytes_to_array(row["raw"]), np.float32)  # (k_i, H, W)
                if w.ndim != 3 or tuple(w.shape[1:]) != tuple(shape):
                    raise InvalidInputError(
                        f"{path}: session {t.session!r} holds {w.shape[1:]} frames, the base "
                        f"checkpoint reads {tuple(shape)}"
                    )
                wins.append(pad_window(w, k))
                labels.append(t.label)
                grasp.append(g)
        space = mem.space
    finally:
        mem.close()
    if not wins:
        raise InvalidInputError(f"{path}: the taught spans keep no stored frames to train on")
    return Grasps(np.stack(wins), labels, np.asarray(grasp, np.int64), str(path)), space
