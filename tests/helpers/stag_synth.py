"""Synthetic STAG ``metadata.mat`` files (no real data: the dataset may not be redistributed).

``make_fields`` builds the variables of one subset in MATLAB's own shapes (per-frame fields
(N, 1), lists as 1 x K cell arrays of strings); ``write_v5`` saves them with
``scipy.io.savemat`` (MATLAB 5 format, compressed, like the shipped files) and ``write_v73``
writes MATLAB v7.3 (HDF5) in MATLAB's layout:

- a 512-byte userblock holding the MATLAB 7.3 text header;
- every array stored with its axes reversed (MATLAB is column-major): ``pressure``
  (N, 32, 32) is the HDF5 dataset (32, 32, N), a per-frame (N, 1) field is (1, N);
- ``MATLAB_class`` attributes (fixed-length ASCII: ``double``, ``uint8``, ``int16``,
  ``logical`` with ``MATLAB_int_decode`` 1, ``cell``, ``char``);
- a cell array of strings is a dataset of HDF5 object references (1 x K cell -> (K, 1));
  each string is a ``uint16`` dataset of UTF-16 code units shaped (len, 1) in the ``#refs#``
  group with ``MATLAB_class='char'`` and ``MATLAB_int_decode=2``; an empty string is the
  uint64 dims array ``[1, 0]`` (h5: (2,)) with ``MATLAB_empty=1``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import h5py
import numpy as np
import scipy.io

OBJECTS = [
    "empty_hand",
    "allen_key_set",
    "ball",
    "battery",
    "board_eraser",
    "bracket",
    "brain",
    "cat",
    "chain",
    "clip",
    "coin",
    "empty_can",
    "full_can",
    "gel",
    "kiwano",
    "lotion",
    "mug",
    "multimeter",
    "pen",
    "safety_glasses",
    "scissors",
    "screw_driver",
    "spoon",
    "spray_can",
    "stapler",
    "tape",
    "tea_box",
]

PEDESTAL = 510  # constant reading of the non-taxel pixels (stag-format.md)


def spec_mask() -> np.ndarray:
    """(32, 32) bool, the 548 taxels, written out independently of the package code."""
    m = np.zeros((32, 32), bool)
    rows_full = [0, 1, 2, 6, 7, 8, 10, 11, 12, 15, 16, 17]
    m[rows_full] = True
    m[[3, 4, 5, 9, 13, 14], 14:] = True
    m[18:, 25:29] = True
    return m


def make_pressure(
    frames_per_recording: list[int], rng: np.random.Generator, peak: int = 1000, n_poses: int = 8
) -> np.ndarray:
    """(N, 32, 32) int16: pedestal 510 off-taxel, rest 511-516 on taxels, and per recording
    ``n_poses`` distinct pressure patterns (so clusters exist) pressed at random strength."""
    mask = spec_mask()
    out = []
    for n in frames_per_recording:
        poses = rng.random((n_poses, 32, 32)) ** 6  # sparse hot spots, most taxels near rest
        which = rng.integers(0, n_poses, size=n)
        strength = rng.uniform(0.3, 1.0, size=(n, 1, 1))
        frames = rng.integers(511, 517, size=(n, 32, 32)).astype(np.float64)
        frames += poses[which] * strength * (peak - 516)
        frames = np.where(mask, np.minimum(frames, peak), PEDESTAL)
        out.append(np.round(frames).astype(np.int16))
    return np.concatenate(out) if out else np.zeros((0, 32, 32), np.int16)


def make_fields(
    kind: str = "classification",
    frames_per_recording: list[int] | None = None,
    *,
    seed: int = 0,
    id_dtype: Any = np.uint8,
    splits: tuple[str, ...] = ("train", "test"),
    peak: int = 1000,
) -> dict[str, Any]:
    """MATLAB variables of a synthetic subset. ``kind``: classification | blindfolded | weights.

    Recording r holds object ``r % 27``; in classification even recordings are 'train', odd
    'test' (looked up by name in ``splits``, whatever its order). Lists are ``list[str]``.
    """
    rng = np.random.default_rng(seed)
    counts = frames_per_recording or [40, 30, 25, 20]
    n_rec = len(counts)
    n = int(sum(counts))
    rec = np.repeat(np.arange(n_rec), counts)
    frame = np.concatenate([np.arange(c) for c in counts]).astype(np.int32)
    col = lambda a, dt=id_dtype: np.asarray(a, dtype=dt).reshape(-1, 1)  # noqa: E731
    fields: dict[str, Any] = {
        "recordings": [f"{r:03d}-{OBJECTS[r % 27]}" for r in range(n_rec)],
        "recordingId": col(rec),
        "objects": list(OBJECTS),
        "objectId": col(rec % 27),
        "pressure": make_pressure(counts, rng, peak=peak),
        "frame": frame.reshape(-1, 1),
        "ts": (frame / 7.4).reshape(-1, 1).astype(np.float64),
        "batchId": col(np.zeros(n)),
        "batches": ["000"],
    }
    if kind == "weights":
        fields["graspIndex"] = col(frame // max(1, max(counts) // 7) % 7)
        fields["graspValid"] = col(rng.random(n) < 0.3)
        fields["weights"] = np.arange(27, dtype=np.float64).reshape(-1, 1) * 10
        return fields
    valid = rng.random(n) < 0.6
    fields["hasValidLabel"] = col(valid)
    fields["isBalanced"] = col(rng.random(n) < 0.8 if kind == "classification" else np.ones(n))
    fields["splits"] = list(splits)
    if kind == "blindfolded":
        fields["splitId"] = col(np.full(n, splits.index("test")))
        fields["actionStartTS"] = np.full((n_rec, 1), -1.0)
        fields["actionEndTS"] = np.full((n_rec, 1), -1.0)
    else:
        names = np.where(rec % 2 == 0, splits.index("train"), splits.index("test"))
        fields["splitId"] = col(names)
        sparse = np.zeros(n, bool)
        sparse[rng.choice(n, size=max(1, n // 20), replace=False)] = True
        fields["isTransition"] = col(sparse)
        fields["isGrasp"] = col(np.roll(sparse, 1))
    return fields


def _cell(strings: list[str]) -> np.ndarray:
    arr = np.empty((1, len(strings)), dtype=object)
    for i, s in enumerate(strings):
        arr[0, i] = s
    return arr


def write_v5(path: str | Path, fields: dict[str, Any]) -> Path:
    """MATLAB 5 MAT-file via scipy (lists become 1 x K cell arrays of strings)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    data = {k: _cell(v) if isinstance(v, list) else v for k, v in fields.items()}
    scipy.io.savemat(str(path), data, do_compression=True, oned_as="column")
    return path


_MATLAB_CLASS = {
    np.dtype(np.float64): "double",
    np.dtype(np.float32): "single",
    np.dtype(np.uint8): "uint8",
    np.dtype(np.int8): "int8",
    np.dtype(np.uint16): "uint16",
    np.dtype(np.int16): "int16",
    np.dtype(np.uint32): "uint32",
    np.dtype(np.int32): "int32",
    np.dtype(np.uint64): "uint64",
    np.dtype(np.int64): "int64",
}


def _set_class(ds: h5py.Dataset, cls: str) -> None:
    ds.attrs.create("MATLAB_class", np.bytes_(cls))  # fixed-length ASCII, as MATLAB writes it


def _write_char(refs: h5py.Group, name: str, text: str) -> h5py.Dataset:
    if not text:
        ds = refs.create_dataset(name, data=np.array([1, 0], dtype=np.uint64))
        _set_class(ds, "char")
        ds.attrs.create("MATLAB_empty", np.uint8(1))
        return ds
    codes = np.frombuffer(text.encode("utf-16-le"), dtype="<u2")
    ds = refs.create_dataset(name, data=codes.reshape(-1, 1))  # 1 x len row -> h5 (len, 1)
    _set_class(ds, "char")
    ds.attrs.create("MATLAB_int_decode", np.int32(2))
    return ds


def _v73_header() -> bytes:
    text = (
        b"MATLAB 7.3 MAT-file, Platform: GLNXA64, Created on: Sat Nov 21 10:00:00 2026 "
        b"HDF5 schema 1.00 ."
    )
    header = text.ljust(116, b" ") + b"\x00" * 8 + b"\x00\x02" + b"IM"
    return header.ljust(512, b"\x00")


def write_v73(path: str | Path, fields: dict[str, Any], *, userblock: bool = True) -> Path:
    """MATLAB v7.3 (HDF5) file in MATLAB's layout (see the module docstring)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    kwargs = {"userblock_size": 512} if userblock else {}
    counter = 0
    with h5py.File(path, "w", **kwargs) as f:
        refs = f.create_group("#refs#")
        for key, value in fields.items():
            if isinstance(value, list):
                ref_list = []
                for s in value:
                    counter += 1
                    ref_list.append(_write_char(refs, f"s{counter}", s).ref)
                arr = np.empty((len(value), 1), dtype=h5py.ref_dtype)  # 1 x K cell -> (K, 1)
                for i, r in enumerate(ref_list):
                    arr[i, 0] = r
                ds = f.create_dataset(key, data=arr, dtype=h5py.ref_dtype)
                _set_class(ds, "cell")
                continue
            a = np.asarray(value)
            if a.ndim == 1:
                a = a.reshape(-1, 1)
            if a.dtype == bool:
                ds = f.create_dataset(key, data=a.T.astype(np.uint8))
                _set_class(ds, "logical")
                ds.attrs.create("MATLAB_int_decode", np.int32(1))
                continue
            ds = f.create_dataset(key, data=np.ascontiguousarray(a.T))  # reverse axes
            _set_class(ds, _MATLAB_CLASS[a.dtype])
    if userblock:
        with open(path, "r+b") as fh:
            fh.write(_v73_header())
    return path


def write_subset(root: str | Path, name: str, fields: dict[str, Any], fmt: str = "v5") -> Path:
    """``root/name/metadata.mat`` in format ``v5`` or ``v73``; returns the folder."""
    folder = Path(root) / name
    target = folder / "metadata.mat"
    (write_v5 if fmt == "v5" else write_v73)(target, fields)
    return folder
