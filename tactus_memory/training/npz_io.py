"""Your own sensor's recordings as training data: a ``.npz`` of arrays (or the same arrays from
a ROS 2 bag, :mod:`tactus_memory.training.bag_io`) -> the :class:`StagData` the recipe
trains on, so ``tactus train|pretrain|distill|eval --data FILE.npz`` run the STAG pipeline.

The array format (``numpy.savez``; N frames of an H x W sensor):

    pressure   (N, H, W)  raw readings (integers or floats), calibrated by the sensor profile
    label      (N,)       str: the object held; "" or "none" = nothing held (not trained on)
    recording  (N,)       str or int: which recording a frame belongs to
    valid      (N,)       bool, optional: frames to train on (default: every labelled frame)
    t          (N,)       float seconds, optional: frame times (default: the frame index)

A recording whose frames hold several objects is split into one recording per object
(``REC/label``), because evaluation scores recordings as one object each. Classes are the
distinct labels, sorted. There are no splits: hold recordings out with ``--holdout``
(``one-per-object@`` holds out one recording of every object).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from tactus_memory.errors import DataFormatError
from tactus_memory.touch.profile import SensorProfile
from tactus_memory.training.data import StagData

REQUIRED = ("pressure", "label", "recording")
OPTIONAL = ("valid", "t")
NOTHING_HELD = frozenset({"", "none"})  # labels that mark frames where nothing is held
INT16 = np.iinfo(np.int16)


def _pressure(pressure: Any, source: str, profile: SensorProfile | None) -> np.ndarray:
    p = np.asarray(pressure)
    if p.ndim != 3:
        raise DataFormatError(f"{source}: pressure must be (N, H, W), got shape {p.shape}")
    if profile is not None and tuple(p.shape[1:]) != tuple(profile.shape):
        h, w = profile.shape
        raise DataFormatError(
            f"{source}: pressure frames are {p.shape[1]}x{p.shape[2]} but the sensor profile "
            f"{profile.name!r} reads {h}x{w} frames"
        )
    if not (np.issubdtype(p.dtype, np.integer) or np.issubdtype(p.dtype, np.floating)):
        raise DataFormatError(f"{source}: pressure dtype {p.dtype} is not numeric")
    if p.size and not np.all(np.isfinite(p)):
        raise DataFormatError(f"{source}: pressure contains NaN or inf")
    integral = np.issubdtype(p.dtype, np.integer) or (p.size and np.all(p == np.round(p)))
    if integral and (not p.size or (p.min() >= INT16.min and p.max() <= INT16.max)):
        return np.ascontiguousarray(p, dtype=np.int16)  # raw counts, as STAG's
    return np.ascontiguousarray(p, dtype=np.float32)


def _column(arrays: dict[str, Any], name: str, n: int, source: str) -> np.ndarray:
    a = np.asarray(arrays[name])
    if a.shape != (n,):
        raise DataFormatError(f"{source}: {name} must be ({n},) (one per frame), got {a.shape}")
    return a


def from_arrays(
    pressure: Any,
    label: Any,
    recording: Any,
    *,
    valid: Any = None,
    t: Any = None,
    source: str = "arrays",
    profile: SensorProfile | None = None,
) -> StagData:
    """The array format (module docstring) -> :class:`StagData` (one source, no splits).
    ``profile`` checks the frame shape. Raises :class:`DataFormatError` naming the array."""
    p = _pressure(pressure, source, profile)
    n = p.shape[0]
    cols: dict[str, Any] = {"label": label, "recording": recording, "valid": valid, "t": t}
    labels = np.array([str(v).strip() for v in _column(cols, "label", n, source)], dtype=object)
    recs = np.array([str(v) for v in _column(cols, "recording", n, source)], dtype=object)
    held = np.array([lab.lower() not in NOTHING_HELD for lab in labels], dtype=bool)
    ok = held if valid is None else held & _column(cols, "valid", n, source).astype(bool)
    if not ok.any():
        raise DataFormatError(f"{source}: no valid labelled frame to train on")
    ts = np.arange(n, dtype=np.float64) if t is None else _column(cols, "t", n, source)
    ts = np.asarray(ts, dtype=np.float64)
    objects = sorted({str(v) for v in labels[held]})
    object_id = np.zeros(n, np.int64)
    object_id[held] = [objects.index(v) for v in labels[held]]
    # one recording per (recording, object held); frames holding nothing keep their recording
    per_rec: dict[str, set[str]] = {}
    for r, lab in zip(recs[held], labels[held], strict=True):
        per_rec.setdefault(r, set()).add(lab)
    names = [
        f"{r}/{lab}" if held[i] and len(per_rec[r]) > 1 else r
        for i, (r, lab) in enumerate(zip(recs, labels, strict=True))
    ]
    recordings = list(dict.fromkeys(names))
    index = {name: i for i, name in enumerate(recordings)}
    recording_id = np.array([index[name] for name in names], np.int64)
    frame = np.zeros(n, np.int64)
    for r in range(len(recordings)):
        m = recording_id == r
        frame[m] = np.arange(int(m.sum()))
    return StagData(
        pressure=p,
        object_id=object_id,
        recording_id=recording_id,
        batch_id=np.zeros(n, np.int64),
        split_id=np.full(n, -1, np.int64),
        frame=frame,
        ts=ts,
        valid=ok,
        balanced=np.ones(n, bool),
        objects=objects,
        recordings=recordings,
        splits=[],
        batches=[""],
        subset=np.zeros(n, np.int64),
        sources=[source],
    )


def load_npz(path: str | Path, profile: SensorProfile | None = None) -> StagData:
    """Read the array format from a ``.npz`` file (module docstring)."""
    p = Path(path)
    if not p.is_file():
        raise DataFormatError(f"no .npz file at {p}")
    try:
        with np.load(p, allow_pickle=False) as z:
            arrays = {k: z[k] for k in z.files}
    except (OSError, ValueError) as exc:
        raise DataFormatError(f"cannot read {p} as .npz (strings must be unicode arrays, "
                              f"not objects): {exc}") from exc  # fmt: skip
    missing = [k for k in REQUIRED if k not in arrays]
    if missing:
        raise DataFormatError(
            f"{p}: missing array(s) {missing}; a training .npz holds pressure (N, H, W), "
            "label (N,), recording (N,) and optionally valid (N,), t (N,)"
        )
    return from_arrays(
        arrays["pressure"],
        arrays["label"],
        arrays["recording"],
        valid=arrays.get("valid"),
        t=arrays.get("t"),
        source=str(p),
        profile=profile,
    )
