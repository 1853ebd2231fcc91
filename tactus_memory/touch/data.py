"""The STAG data path: read ``metadata.mat`` (MATLAB v5 or v7.3), calibrate, check dynamic range.

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

import h5py
import numpy as np
import scipy.io

from tactus_memory.errors import DataFormatError, DynamicRangeError, InvalidInputError

RAW_OFFSET = 500  # STAG reference code / paper Sec. Method "Data path": clip((raw-500)/150, 0, 1)
RAW_SPAN = 150  # same source: the informative band ends near raw 650
REST_RAW = 512.0  # stag-format.md "The sensor": resting pedestal about 510-516 raw
SATURATION_RAW = 1000.0  # stag-format.md "The sensor": saturation near 1000 raw
FRAME_SHAPE = (32, 32)  # stag-format.md: 548 taxels rasterised into 32x32

LEVELS = 255  # intensity levels of an 8-bit cache; the paper's forensics counts 1/255 steps
LEVEL_LOW_PCT = 1.0  # "levels used" = span of 1/255 levels between these taxel percentiles
LEVEL_HIGH_PCT = 99.9  # (real files: weights 64, blindfolded 39; the max-scaling defect 6-15)
# gate: calibrated data must span at least this many levels (paper: 30-60 after the fix, ~8
# under the defect)
MIN_LEVELS = 20
MAX_CALIBRATED_MEDIAN = 0.35  # gate: calibrated rest sits near 0.07-0.10 (spec); a median above
# this means the pedestal was kept, i.e. the data was max-scaled rather than calibrated

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


# --------------------------------------------------------------------------- calibration


@dataclass(frozen=True)
class SensorProfile:
    """A named sensor calibration: ``clip((raw - offset) / span, 0, 1)`` in float32.

    Other gloves get their own profile (register it in :data:`PROFILES`).
    """

    name: str
    offset: float
    span: float
    shape: tuple[int, int] = FRAME_SHAPE
    rest_raw: float | None = None  # typical untouched reading, for diagnostics
    saturation_raw: float | None = None  # reading where the sensor saturates, for diagnostics

    def __post_init__(self) -> None:
        if not np.isfinite(self.offset) or not np.isfinite(self.span) or self.span <= 0:
            raise InvalidInputError(
                f"profile {self.name!r}: offset must be finite and span > 0, "
                f"got offset={self.offset}, span={self.span}"
            )

    def calibrate(self, raw: np.ndarray) -> np.ndarray:
        """``raw``: (..., H, W) raw readings -> float32 in [0, 1], same shape."""
        arr = np.asarray(raw)
        if arr.ndim < 2 or tuple(arr.shape[-2:]) != tuple(self.shape):
            raise InvalidInputError(
                f"profile {self.name!r} expects (..., {self.shape[0]}, {self.shape[1]}) frames, "
                f"got shape {arr.shape}"
            )
        if not (np.issubdtype(arr.dtype, np.integer) or np.issubdtype(arr.dtype, np.floating)):
            raise InvalidInputError(f"raw pressure must be numeric, got dtype {arr.dtype}")
        out = (arr.astype(np.float32) - np.float32(self.offset)) / np.float32(self.span)
        if not np.all(np.isfinite(out)):
            raise InvalidInputError("raw pressure contains NaN or inf")
        return np.clip(out, 0.0, 1.0, out=out)

    def to_dict(self) -> dict[str, Any]:
        return {
            "name": self.name,
            "offset": float(self.offset),
            "span": float(self.span),
            "shape": list(self.shape),
            "rest_raw": self.rest_raw,
            "saturation_raw": self.saturation_raw,
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> SensorProfile:
        try:
            return cls(
                name=str(d["name"]),
                offset=float(d["offset"]),
                span=float(d["span"]),
                shape=tuple(int(v) for v in d.get("shape", FRAME_SHAPE)),  # type: ignore[arg-type]
                rest_raw=None if d.get("rest_raw") is None else float(d["rest_raw"]),
                saturation_raw=(
                    None if d.get("saturation_raw") is None else float(d["saturation_raw"])
                ),
            )
        except (KeyError, TypeError, ValueError) as exc:
            raise InvalidInputError(f"bad sensor profile dict {d!r}: {exc}") from exc


STAG_GLOVE = SensorProfile(
    "stag-glove",
    RAW_OFFSET,
    RAW_SPAN,
    FRAME_SHAPE,
    rest_raw=REST_RAW,
    saturation_raw=SATURATION_RAW,
)
PROFILES: dict[str, SensorProfile] = {STAG_GLOVE.name: STAG_GLOVE}


def get_profile(name: str) -> SensorProfile:
    try:
        return PROFILES[name]
    except KeyError:
        raise InvalidInputError(
            f"unknown sensor profile {name!r}; known: {sorted(PROFILES)}"
        ) from None


def calibrate(raw: np.ndarray, profile: SensorProfile = STAG_GLOVE) -> np.ndarray:
    """(..., 32, 32) raw -> float32 ``clip((raw - offset) / span, 0, 1)``."""
    return profile.calibrate(raw)


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

    pressure: np.ndarray  # (N, 32, 32) int16 raw, C order as loaded
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
        """(N, 32, 32) float32 calibrated pressure."""
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
        h.update(np.ascontiguousarray(self.pressure, dtype="<i2").tobytes())
        for arr in (self.object_id, self.recording_id, self.split_id, self.frame):
            h.update(np.ascontiguousarray(arr, dtype="<i8").tobytes())
        for arr in (self.valid, self.balanced):
            h.update(np.ascontiguousarray(arr, dtype=np.uint8).tobytes())
        h.update("\x1f".join(self.objects).encode())
        h.update("\x1e".join(self.splits).encode())
        return h.hexdigest()


# --------------------------------------------------------------------------- MAT readers


def _resolve(path: str | Path) -> Path:
    p = Path(path)
    if p.is_dir():
        p = p / "metadata.mat"
    if not p.is_file():
        raise DataFormatError(f"no STAG metadata file at {p}")
    return p


def _strings_from_v5(value: np.ndarray) -> list[str]:
    """A v5 cell array of strings (object array) or char matrix -> list of str."""
    arr = np.asarray(value)
    if arr.dtype.kind == "U":  # char matrix: one string per row
        return (
            [str(s).rstrip() for s in arr.reshape(-1)]
            if arr.ndim <= 1
            else ["".join(row).rstrip() for row in arr.reshape(arr.shape[0], -1)]
        )
    if arr.dtype != object:
        raise DataFormatError(f"expected a cell array of strings, got dtype {arr.dtype}")
    out: list[str] = []
    for item in arr.reshape(-1, order="F"):
        el = np.asarray(item)
        if el.size == 0:
            out.append("")
        elif el.dtype.kind == "U":
            out.append("".join(str(s) for s in el.reshape(-1)))
        else:
            raise DataFormatError(f"cell element is not a string: dtype {el.dtype}")
    return out


def _read_v5(path: Path) -> dict[str, Any]:
    try:
        raw = scipy.io.loadmat(str(path), squeeze_me=False, chars_as_strings=True)
    except Exception as exc:  # scipy raises several types for corrupt files
        raise DataFormatError(f"cannot read {path} as a MATLAB file: {exc}") from exc
    out: dict[str, Any] = {}
    for key, value in raw.items():
        if key.startswith("__"):
            continue
        if isinstance(value, np.ndarray) and (value.dtype == object or value.dtype.kind == "U"):
            out[key] = _strings_from_v5(value)
        else:
            out[key] = np.asarray(value)
    return out


def _h5_class(obj: h5py.Dataset) -> str:
    cls = obj.attrs.get("MATLAB_class", b"")
    return cls.decode() if isinstance(cls, bytes) else str(cls)


def _h5_string(f: h5py.File, ds: h5py.Dataset) -> str:
    if ds.attrs.get("MATLAB_empty", 0) or ds.size == 0:
        return ""
    codes = np.atleast_2d(np.asarray(ds[()]).T)  # h5 (len, rows) -> MATLAB (rows, len)
    # MATLAB_int_decode = 2: the codes are UTF-16 code units
    rows = [row.astype("<u2").tobytes().decode("utf-16-le", errors="replace") for row in codes]
    return "\n".join(r.rstrip("\x00") for r in rows)


def _read_v73(path: Path) -> dict[str, Any]:
    """MATLAB v7.3 (HDF5). h5py sees MATLAB arrays with axes reversed; restore them (``.T``).

    Cell arrays are datasets of object references into ``#refs#``; each string is a uint16
    char array (``MATLAB_class='char'``) stored transposed, i.e. (len, 1) for a 1 x len row.
    """
    out: dict[str, Any] = {}
    try:
        f = h5py.File(path, "r")
    except OSError as exc:
        raise DataFormatError(f"cannot read {path} as HDF5 (MATLAB v7.3): {exc}") from exc
    with f:
        for key, obj in f.items():
            if key.startswith("#") or not isinstance(obj, h5py.Dataset):
                continue
            cls = _h5_class(obj)
            if cls == "cell" or obj.dtype == h5py.ref_dtype or obj.dtype.kind == "O":
                refs = np.asarray(obj[()]).reshape(-1)  # C order over h5 == MATLAB column-major
                strings = []
                for ref in refs:
                    target = f[ref]
                    if not isinstance(target, h5py.Dataset):
                        raise DataFormatError(f"{key}: cell element is not a dataset")
                    tcls = _h5_class(target)
                    if tcls not in ("char", "") or target.dtype.kind not in "ui":
                        raise DataFormatError(f"{key}: cell element is {tcls or target.dtype}")
                    strings.append(_h5_string(f, target))
                out[key] = strings
            elif cls == "char":
                out[key] = _h5_string(f, obj).split("\n")
            elif obj.attrs.get("MATLAB_empty", 0):
                out[key] = np.zeros((0, 0))
            else:
                arr = np.asarray(obj[()])
                arr = np.ascontiguousarray(arr.T)  # restore MATLAB's axis order
                if cls == "logical":
                    arr = arr.astype(bool)
                out[key] = arr
    return out


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


def read_mat_fields(path: str | Path) -> dict[str, Any]:
    """All variables of a v5 or v7.3 MAT file: numeric arrays in MATLAB's axis order,
    cell arrays of strings as ``list[str]``."""
    p = _resolve(path)
    return _read_v73(p) if h5py.is_hdf5(p) else _read_v5(p)


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


# --------------------------------------------------------------------------- dynamic range


def taxel_mask_from_spec() -> np.ndarray:
    """(32, 32) bool, the 548 real taxels as stag-format.md describes them."""
    m = np.zeros(FRAME_SHAPE, dtype=bool)
    for r0, r1 in ((0, 2), (6, 8), (10, 12), (15, 17)):  # full rows
        m[r0 : r1 + 1, :] = True
    for r in (3, 4, 5, 9, 13, 14):  # columns 14-31 only
        m[r, 14:32] = True
    m[18:32, 25:29] = True  # the thumb: columns 25-28 in rows 18-31
    return m


def taxel_mask_from_data(raw: np.ndarray) -> np.ndarray:
    """(H, W) bool: pixels whose value varies over the frames of ``raw`` (..., H, W)."""
    arr = np.asarray(raw)
    if arr.ndim < 2:
        raise InvalidInputError(f"expected (..., H, W) frames, got shape {arr.shape}")
    flat = arr.reshape((-1, *arr.shape[-2:]))
    if flat.shape[0] == 0:
        return np.zeros(arr.shape[-2:], dtype=bool)
    return flat.max(axis=0) != flat.min(axis=0)


_CHUNK_FRAMES = 8192  # frames per pass: statistics are histograms, memory stays ~32 MB


def _frames(arr: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    a = np.asarray(arr)
    if a.ndim < 2 or tuple(a.shape[-2:]) != tuple(shape):
        raise InvalidInputError(f"expected (..., {shape[0]}, {shape[1]}) frames, got {a.shape}")
    return a.reshape((-1, *a.shape[-2:]))


def _hist_pct(counts: np.ndarray, pct: float) -> int:
    """Nearest-rank percentile of the values whose histogram is ``counts`` (bin = value)."""
    cum = np.cumsum(counts)
    rank = int(round(pct / 100.0 * (int(cum[-1]) - 1)))
    return int(np.searchsorted(cum, rank, side="right"))


def _level_counts(calibrated_taxels: np.ndarray) -> np.ndarray:
    q = np.rint(np.asarray(calibrated_taxels, dtype=np.float32) * LEVELS).astype(np.int64)
    return np.bincount(np.clip(q, 0, LEVELS).reshape(-1), minlength=LEVELS + 1)


def _level_stats(counts: np.ndarray) -> dict[str, Any]:
    """Level statistics from a (256,) histogram of calibrated values on the 1/255 grid."""
    if counts.sum() == 0:
        return {"levels_used": 0, "levels_distinct": 0}
    lo, hi = _hist_pct(counts, LEVEL_LOW_PCT), _hist_pct(counts, LEVEL_HIGH_PCT)
    return {
        "levels_used": hi - lo + 1,
        "levels_distinct": int(np.count_nonzero(counts)),
        "level_p1": lo,
        "level_p50": _hist_pct(counts, 50),
        "level_p95": _hist_pct(counts, 95),
        "level_p999": hi,
    }


def dynamic_range_report(
    raw: np.ndarray, profile: SensorProfile = STAG_GLOVE, mask: np.ndarray | None = None
) -> dict[str, Any]:
    """Diagnostics of raw (..., 32, 32) readings under ``profile``.

    ``mask`` (32, 32) bool selects the taxels the statistics use; by default the pixels that
    vary in ``raw`` (falling back to the spec's 548-taxel layout when nothing varies). Level
    counts are on the 1/255 grid: ``levels_used`` is the span of levels between the 1st and
    99.9th taxel percentiles (the paper's "usable intensity levels"), ``levels_distinct``
    the number of levels that occur at all. Percentiles are nearest-rank, computed from
    histograms in chunks (memory stays small on the 135k-frame classification subset).
    """
    frames = _frames(raw, profile.shape)
    spec = taxel_mask_from_spec() if tuple(profile.shape) == FRAME_SHAPE else None
    data_mask = taxel_mask_from_data(frames)
    if mask is None:
        mask = data_mask if data_mask.any() or spec is None else spec
    mask = np.asarray(mask, dtype=bool)
    if mask.shape != tuple(profile.shape):
        raise InvalidInputError(f"taxel mask must have shape {profile.shape}, got {mask.shape}")
    report: dict[str, Any] = {
        "profile": profile.name,
        "frames": int(frames.shape[0]),
        "raw_min": None,
        "raw_max": None,
        "taxels_used": int(mask.sum()),
    }
    n_values = frames.shape[0] * int(mask.sum())
    if n_values:
        raw_min, raw_max = frames.min(), frames.max()
        integral = np.issubdtype(frames.dtype, np.integer)
        report["raw_min"] = int(raw_min) if integral else float(raw_min)
        report["raw_max"] = int(raw_max) if integral else float(raw_max)
        levels = np.zeros(LEVELS + 1, np.int64)
        raw_counts = np.zeros(int(raw_max) - int(raw_min) + 1, np.int64) if integral else None
        for s in range(0, frames.shape[0], _CHUNK_FRAMES):
            chunk = frames[s : s + _CHUNK_FRAMES]
            levels += _level_counts(profile.calibrate(chunk)[:, mask])
            if raw_counts is not None:
                shifted = chunk[:, mask].astype(np.int64).reshape(-1) - int(raw_min)
                raw_counts += np.bincount(shifted, minlength=raw_counts.size)
        for p in (1, 5, 50, 95, 99):
            if raw_counts is not None:
                report[f"raw_p{p}"] = _hist_pct(raw_counts, p) + int(raw_min)
            else:  # float readings: a strided sample of at most ~2M taxel values
                step = max(1, frames.shape[0] * int(mask.sum()) // 2_000_000)
                report[f"raw_p{p}"] = float(np.percentile(frames[::step][:, mask], p))
        report["frac_saturated"] = float(levels[LEVELS] / n_values)
        report["frac_zero"] = float(levels[0] / n_values)
        report.update(_level_stats(levels))
        report["calibrated_median"] = report["level_p50"] / LEVELS
    else:
        report.update(_level_stats(np.zeros(LEVELS + 1, np.int64)))
    report["taxels_data"] = int(data_mask.sum())
    if spec is not None:
        report["taxels_spec"] = int(spec.sum())
        report["taxels_data_not_spec"] = int((data_mask & ~spec).sum())
        report["taxels_spec_not_data"] = int((spec & ~data_mask).sum())
        report["taxel_mask_matches_spec"] = bool(np.array_equal(data_mask, spec))
    return report


def check_dynamic_range(
    raw_or_calibrated: np.ndarray,
    profile: SensorProfile = STAG_GLOVE,
    *,
    min_levels: int = MIN_LEVELS,
    already_calibrated: bool = False,
) -> dict[str, Any]:
    """The dynamic-range regression gate (paper Sec. forensics). Returns the level report.

    Raises :class:`DynamicRangeError` when "raw" input already looks normalised (floats in
    [0, 1], or nothing above the sensor offset), when calibrated input kept the pedestal
    (median above 0.35: max-scaled, not calibrated), or when the calibrated taxels span fewer
    than ``min_levels`` 1/255 levels.
    """
    arr = np.asarray(raw_or_calibrated)
    if arr.size == 0:
        raise DynamicRangeError("no pressure values to check")
    if not np.all(np.isfinite(arr)):
        raise DynamicRangeError("pressure contains NaN or inf")
    if already_calibrated:
        if arr.min() < 0 or arr.max() > 1:
            raise DynamicRangeError(
                f"calibrated pressure must lie in [0, 1], got {arr.min()}..{arr.max()}"
            )
        frames = _frames(arr, profile.shape)
        mask = taxel_mask_from_data(frames)
        if not mask.any():
            mask = np.ones(frames.shape[1:], bool)
        counts = np.zeros(LEVELS + 1, np.int64)
        for s in range(0, frames.shape[0], _CHUNK_FRAMES):
            counts += _level_counts(frames[s : s + _CHUNK_FRAMES][:, mask])
        report: dict[str, Any] = {"profile": profile.name, "frames": int(frames.shape[0])}
        report.update(_level_stats(counts))
        median = report["level_p50"] / LEVELS
        report["calibrated_median"] = median
        if median > MAX_CALIBRATED_MEDIAN:
            raise DynamicRangeError(
                f"calibrated median {median:.3f} > {MAX_CALIBRATED_MEDIAN}: the resting "
                "pedestal was kept, so the data looks max-scaled rather than calibrated with "
                f"clip((raw - {profile.offset:g}) / {profile.span:g}, 0, 1)"
            )
    else:
        if np.issubdtype(arr.dtype, np.floating) and arr.min() >= 0 and arr.max() <= 1.0:
            raise DynamicRangeError(
                f"'raw' pressure lies in [0, 1] (max {arr.max():.4g}): it looks already "
                "normalised (e.g. max-scaled); pass raw sensor readings, or "
                "already_calibrated=True if it is the calibrated output"
            )
        if arr.max() <= profile.offset:
            raise DynamicRangeError(
                f"no raw reading above the sensor offset {profile.offset:g} (max {arr.max()}): "
                f"the data looks already normalised or belongs to another sensor than "
                f"{profile.name!r}"
            )
        report = dynamic_range_report(arr, profile)
    if report["levels_used"] < min_levels:
        raise DynamicRangeError(
            f"calibrated pressure spans only {report['levels_used']} of {LEVELS} intensity "
            f"levels (p1..p99.9), fewer than {min_levels}: the input was probably scaled by "
            "its maximum instead of the sensor calibration (the paper's 3%-range defect)"
        )
    return report
