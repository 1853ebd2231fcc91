"""The STAG dataset: :class:`StagData` built from a ``metadata.mat`` (read by
:mod:`tactus_memory.training.stag_io`, calibrated and gated by
:mod:`tactus_memory.touch.profile`,
), masks, and :func:`combine`.

Spec: ``../shared/stag-format.md``. Every subset is calibrated with the sensor's own affine
``clip((raw - 500) / 150, 0, 1)`` (the STAG reference code; the paper, Sec. Method "Data path"),
identically for every subset. Per-file max scaling is the defect of the paper's forensics
section (Sec. "Anatomy of a Silent Data Defect"); :func:`check_dynamic_range` makes it loud.

Mask semantics (spec, "Reference sampling"):

- ``StagData.valid`` is ``hasValidLabel`` (the grasp filter). The ``weights`` subset has no
  ``hasValidLabel``; its ``graspValid`` is its valid mask. ``isTransition`` / ``isGrasp`` are
  sparse analysis markers, never the grasp filter; they stay in ``StagData.extra``.
- training/test frames: ``valid & split_mask(name)`` (:meth:`StagData.valid_mask`);
  anchors: that and ``isBalanced`` (:meth:`StagData.anchor_mask`). A file without splits
  (``weights``) has ``split_id == -1``: its frames are in neither 'train' nor 'test'.

Formats: MATLAB 5 files (as shipped) through ``scipy.io.loadmat``; MATLAB v7.3 (HDF5) through
h5py, whose arrays come back with MATLAB's axes reversed (``pressure`` is (32, 32, N) there)
and are transposed back, and whose cell arrays of strings are object references to uint16
``char`` datasets. Per-frame ids are cast to int64 whatever their stored type (uint8 in the
shipped files, float64 when written by ``savemat``).
"""

from __future__ import annotations

import hashlib
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from tactus_memory.errors import DataFormatError, DynamicRangeError, InvalidInputError
from tactus_memory.touch.profile import (
    FRAME_SHAPE,
    MIN_LEVELS,
    STAG_GLOVE,
    SensorProfile,
    check_dynamic_range,
)
from tactus_memory.training.stag_io import _resolve, read_mat_fields

PER_FRAME_FIELDS = (
    "pressure",
    "objectId",
    "recordingId",
    "batchId",
    "splitId",
    "frame",
    "ts",
    "hasValidLabel",
    "isBalanced",
)
LIST_FIELDS = ("objects", "recordings", "batches", "splits")
REQUIRED_FIELDS = ("pressure", "objectId", "recordingId", "frame", "ts", "objects", "recordings")
VALID_FIELDS = ("hasValidLabel", "graspValid")  # first present wins; graspValid: weights subset


# --------------------------------------------------------------------------- the dataset


class UnknownSplitError(DataFormatError, LookupError):
    """A split name the data does not have."""


@dataclass(eq=False)  # arrays: compare with fingerprint(), not ==
class StagData:
    """One STAG subset (or several, combined). Per-frame arrays all have length N.

    ``extra`` holds every other variable of the file (``graspIndex``, ``weights``,
    ``actionStartTS``, ``isTransition``, ...), (K, 1) vectors flattened to (K,), cell arrays
    as object arrays of str; ``frame_extra`` names the per-frame ones (sliced by
    :meth:`select`, carried by :func:`combine`).
    """

    pressure: np.ndarray  # (N, H, W) raw, C order: int16 (STAG: 32x32), float32 for float sensors
    object_id: np.ndarray  # (N,) int64
    recording_id: np.ndarray  # (N,) int64, globally unique across combined files
    batch_id: np.ndarray  # (N,) int64
    split_id: np.ndarray  # (N,) int64, -1 where the file has no split
    frame: np.ndarray  # (N,) int64
    ts: np.ndarray  # (N,) float64
    valid: np.ndarray  # (N,) bool: hasValidLabel, or graspValid for the weights subset
    balanced: np.ndarray  # (N,) bool: isBalanced, all True when absent
    objects: list[str]
    recordings: list[str]  # indexed by recording_id
    splits: list[str]
    batches: list[str]
    subset: np.ndarray  # (N,) int64 index into sources
    sources: list[str]
    extra: dict[str, np.ndarray] = field(default_factory=dict)
    frame_extra: frozenset[str] = frozenset()  # names in ``extra`` that are per-frame (N,)

    # ---- summary
    @property
    def n_frames(self) -> int:
        return int(self.pressure.shape[0])

    @property
    def n_recordings(self) -> int:
        """Distinct recordings that have frames here (``recordings`` may list more)."""
        return int(np.unique(self.recording_id).size)

    @property
    def valid_frames(self) -> int:
        return int(np.count_nonzero(self.valid))

    # ---- masks
    def split_mask(self, name: str) -> np.ndarray:
        """(N,) bool: frames whose ``splitId`` names ``name`` (looked up by name, not index).

        Frames of a file without splits (``weights``; ``split_id == -1``) belong to no split:
        they are False for ``'train'`` and ``'test'`` alike; select them with
        ``data.split_id == -1``, or use :meth:`valid_mask` with ``split=None``. An unknown
        name raises :class:`UnknownSplitError` (a ``LookupError``), except the standard names
        ``'train'``/``'test'``, which give an all-False mask when no file here has them.
        """
        if name in self.splits:
            return self.split_id == self.splits.index(name)
        if name in ("train", "test"):
            return np.zeros(self.n_frames, dtype=bool)
        raise UnknownSplitError(f"unknown split {name!r}; this data has splits {self.splits}")

    def valid_mask(self, split: str | None = None) -> np.ndarray:
        """``valid`` and, when asked, the split."""
        return self.valid if split is None else self.valid & self.split_mask(split)

    def anchor_mask(self, split: str | None = None) -> np.ndarray:
        """``valid`` and the split and ``isBalanced``: the frames that anchor tuples."""
        return self.valid_mask(split) & self.balanced

    # ---- transforms
    def select(self, mask: np.ndarray) -> StagData:
        """Frames where ``mask`` (bool (N,) or integer indices); lists and ids unchanged."""
        m = np.asarray(mask)
        if m.dtype == bool and m.shape != (self.n_frames,):
            raise InvalidInputError(f"mask must have shape ({self.n_frames},), got {m.shape}")
        idx = np.flatnonzero(m) if m.dtype == bool else m.astype(np.int64).reshape(-1)
        extra = {k: (v[idx] if k in self.frame_extra else v) for k, v in self.extra.items()}
        return replace(
            self,
            pressure=self.pressure[idx],
            object_id=self.object_id[idx],
            recording_id=self.recording_id[idx],
            batch_id=self.batch_id[idx],
            split_id=self.split_id[idx],
            frame=self.frame[idx],
            ts=self.ts[idx],
            valid=self.valid[idx],
            balanced=self.balanced[idx],
            subset=self.subset[idx],
            objects=list(self.objects),
            recordings=list(self.recordings),
            splits=list(self.splits),
            batches=list(self.batches),
            sources=list(self.sources),
            extra=extra,
        )

    def calibrated(self, profile: SensorProfile = STAG_GLOVE) -> np.ndarray:
        """(N, H, W) float32 calibrated pressure."""
        return profile.calibrate(self.pressure)

    def check_dynamic_range(
        self, profile: SensorProfile = STAG_GLOVE, *, min_levels: int | None = None
    ) -> dict[str, dict[str, Any]]:
        """The dynamic-range gate run on EACH source subset separately (a pooled check can
        be passed by a mis-scaled subset hiding among good ones). Returns reports by source;
        raises :class:`DynamicRangeError` naming the first failing source."""
        reports: dict[str, dict[str, Any]] = {}
        for i, source in enumerate(self.sources):
            frames = self.pressure[self.subset == i]
            if frames.shape[0] == 0:
                continue
            try:
                reports[source] = check_dynamic_range(
                    frames, profile, min_levels=MIN_LEVELS if min_levels is None else min_levels
                )
            except DynamicRangeError as exc:
                raise DynamicRangeError(f"{source}: {exc}") from exc
        return reports

    def fingerprint(self) -> str:
        """sha256 over pressure, labels, masks and the class list (for checkpoint metadata)."""
        h = hashlib.sha256()
        # raw counts as int16 (STAG, integer sensors); float readings (other sensors) as float32
        raw_dtype = "<f4" if np.issubdtype(self.pressure.dtype, np.floating) else "<i2"
        h.update(np.ascontiguousarray(self.pressure, dtype=raw_dtype).tobytes())
        for arr in (self.object_id, self.recording_id, self.split_id, self.frame):
            h.update(np.ascontiguousarray(arr, dtype="<i8").tobytes())
        for arr in (self.valid, self.balanced):
            h.update(np.ascontiguousarray(arr, dtype=np.uint8).tobytes())
        h.update("\x1f".join(self.objects).encode())
        h.update("\x1e".join(self.splits).encode())
        return h.hexdigest()


def _as_int64(name: str, arr: np.ndarray) -> np.ndarray:
    a = np.asarray(arr)
    if a.dtype == bool:
        return a.astype(np.int64)
    if np.issubdtype(a.dtype, np.floating):
        if not np.all(np.isfinite(a)) or not np.all(a == np.round(a)):
            raise DataFormatError(f"{name}: expected integer ids, found non-integer values")
    elif not np.issubdtype(a.dtype, np.integer):
        raise DataFormatError(f"{name}: expected a numeric array, got dtype {a.dtype}")
    return a.astype(np.int64)


def _per_frame(fields: dict[str, Any], name: str, n: int) -> np.ndarray:
    a = fields[name]
    if not isinstance(a, np.ndarray):
        raise DataFormatError(f"{name}: expected a numeric array, got a list of strings")
    if a.size != n or (a.ndim > 1 and sorted(a.shape)[:-1] != [1] * (a.ndim - 1)):
        raise DataFormatError(f"{name}: expected one value per frame ({n},), got shape {a.shape}")
    return a.reshape(-1)


def _check_index(name: str, ids: np.ndarray, names: list[str], list_name: str) -> None:
    if ids.size and (ids.min() < 0 or ids.max() >= len(names)):
        raise DataFormatError(
            f"{name} out of range: values {ids.min()}..{ids.max()} but {list_name} has "
            f"{len(names)} entries"
        )


def _build(fields: dict[str, Any], source: str) -> StagData:
    missing = [f for f in REQUIRED_FIELDS if f not in fields]
    if missing:
        raise DataFormatError(f"{source}: missing required field(s) {missing}")
    valid_name = next((f for f in VALID_FIELDS if f in fields), None)
    if valid_name is None:
        raise DataFormatError(f"{source}: missing field: one of {list(VALID_FIELDS)} (valid mask)")
    for name in LIST_FIELDS:
        if name in fields and not isinstance(fields[name], list):
            raise DataFormatError(f"{source}: {name} must be a cell array of strings")

    pressure = fields["pressure"]
    if not isinstance(pressure, np.ndarray) or pressure.ndim != 3:
        shape = getattr(pressure, "shape", None)
        raise DataFormatError(f"{source}: pressure must be (N, 32, 32), got shape {shape}")
    if tuple(pressure.shape[1:]) != FRAME_SHAPE:
        raise DataFormatError(f"{source}: pressure must be (N, 32, 32), got {pressure.shape}")
    if np.issubdtype(pressure.dtype, np.floating):
        if not np.all(np.isfinite(pressure)) or not np.all(pressure == np.round(pressure)):
            raise DataFormatError(
                f"{source}: pressure must hold raw integer readings, found non-integer floats "
                "(already normalised data? load the raw files)"
            )
    elif not np.issubdtype(pressure.dtype, np.integer):
        raise DataFormatError(f"{source}: pressure dtype {pressure.dtype} is not numeric")
    if pressure.size and (pressure.min() < np.iinfo(np.int16).min or pressure.max() > 32767):
        raise DataFormatError(f"{source}: pressure values do not fit int16")
    pressure = np.ascontiguousarray(pressure, dtype=np.int16)
    n = pressure.shape[0]

    objects, recordings = fields["objects"], fields["recordings"]
    batches: list[str] = fields.get("batches", [""])
    object_id = _as_int64("objectId", _per_frame(fields, "objectId", n))
    recording_id = _as_int64("recordingId", _per_frame(fields, "recordingId", n))
    batch_id = (
        _as_int64("batchId", _per_frame(fields, "batchId", n))
        if "batchId" in fields
        else np.zeros(n, np.int64)
    )
    _check_index("objectId", object_id, objects, "objects")
    _check_index("recordingId", recording_id, recordings, "recordings")
    _check_index("batchId", batch_id, batches, "batches")

    if ("splitId" in fields) != ("splits" in fields):
        have, lack = ("splitId", "splits") if "splitId" in fields else ("splits", "splitId")
        raise DataFormatError(f"{source}: has {have} but missing field {lack}")
    if "splitId" in fields:
        splits = fields["splits"]
        split_id = _as_int64("splitId", _per_frame(fields, "splitId", n))
        _check_index("splitId", split_id, splits, "splits")
    else:
        splits, split_id = [], np.full(n, -1, np.int64)

    valid = _per_frame(fields, valid_name, n).astype(bool)
    balanced = (
        _per_frame(fields, "isBalanced", n).astype(bool)
        if "isBalanced" in fields
        else np.ones(n, bool)
    )
    frame = _as_int64("frame", _per_frame(fields, "frame", n))
    ts = _per_frame(fields, "ts", n).astype(np.float64)

    used = set(PER_FRAME_FIELDS) | set(LIST_FIELDS) | {valid_name}
    extra: dict[str, np.ndarray] = {}
    frame_extra: set[str] = set()
    for key, value in fields.items():
        if key in used:
            continue
        arr = np.asarray(value, dtype=object) if isinstance(value, list) else value
        if arr.ndim == 2 and 1 in arr.shape:
            arr = arr.reshape(-1)
        extra[key] = arr
        if arr.ndim == 1 and arr.shape[0] == n and not isinstance(value, list):
            frame_extra.add(key)

    return StagData(
        pressure=pressure,
        object_id=object_id,
        recording_id=recording_id,
        batch_id=batch_id,
        split_id=split_id,
        frame=frame,
        ts=ts,
        valid=valid,
        balanced=balanced,
        objects=list(objects),
        recordings=list(recordings),
        splits=list(splits),
        batches=list(batches),
        subset=np.zeros(n, np.int64),
        sources=[source],
        extra=extra,
        frame_extra=frozenset(frame_extra),
    )


def load_stag(path: str | Path) -> StagData:
    """Load a STAG ``metadata.mat`` (or its folder). Raises :class:`DataFormatError`."""
    p = _resolve(path)
    return _build(read_mat_fields(p), str(p))


def combine(datasets: Sequence[StagData]) -> StagData:
    """Concatenate subsets (e.g. a train pool). ``objects`` must be identical; recording and
    batch ids are re-based so they stay unique; splits are unified by name. Per-frame extras
    are kept (filled with -1 / NaN / False where a subset lacks them); other extras are
    dropped (read them from the individual subsets)."""
    if not datasets:
        raise InvalidInputError("combine() needs at least one dataset")
    objects = datasets[0].objects
    for d in datasets[1:]:
        if d.objects != objects:
            raise DataFormatError(
                f"cannot combine subsets with different class lists: {objects} vs {d.objects}"
            )
    splits: list[str] = []
    for d in datasets:
        splits += [s for s in d.splits if s not in splits]

    rec_off = bat_off = src_off = 0
    parts: dict[str, list[np.ndarray]] = {k: [] for k in ("rec", "bat", "split", "sub")}
    recordings: list[str] = []
    batches: list[str] = []
    sources: list[str] = []
    for d in datasets:
        parts["rec"].append(d.recording_id + rec_off)
        parts["bat"].append(d.batch_id + bat_off)
        remap = np.array([splits.index(s) for s in d.splits] + [-1], np.int64)
        parts["split"].append(remap[d.split_id])  # -1 indexes the trailing -1
        parts["sub"].append(d.subset + src_off)
        recordings += d.recordings
        batches += d.batches
        sources += d.sources
        rec_off += len(d.recordings)
        bat_off += len(d.batches)
        src_off += len(d.sources)

    names = sorted(set().union(*(d.frame_extra for d in datasets)))
    extra: dict[str, np.ndarray] = {}
    for name in names:
        ref = next(d.extra[name] for d in datasets if name in d.frame_extra)
        if ref.dtype == bool:
            fill: Any = False
        elif np.issubdtype(ref.dtype, np.integer):
            fill, ref = -1, ref.astype(np.int64)
        else:
            fill = np.nan
        cols = [
            d.extra[name].astype(ref.dtype)
            if name in d.frame_extra
            else np.full(d.n_frames, fill, dtype=ref.dtype if fill is not np.nan else float)
            for d in datasets
        ]
        extra[name] = np.concatenate(cols)

    def cat(attr: str) -> np.ndarray:
        return np.concatenate([getattr(d, attr) for d in datasets])

    return StagData(
        pressure=np.ascontiguousarray(cat("pressure")),
        object_id=cat("object_id"),
        recording_id=np.concatenate(parts["rec"]),
        batch_id=np.concatenate(parts["bat"]),
        split_id=np.concatenate(parts["split"]),
        frame=cat("frame"),
        ts=cat("ts"),
        valid=cat("valid"),
        balanced=cat("balanced"),
        objects=list(objects),
        recordings=recordings,
        splits=splits,
        batches=batches,
        subset=np.concatenate(parts["sub"]),
        sources=sources,
        extra=extra,
        frame_extra=frozenset(names),
    )
