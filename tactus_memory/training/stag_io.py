"""MATLAB readers for STAG ``metadata.mat`` files: v5 (as shipped) through ``scipy.io.loadmat``,
v7.3 (HDF5) through h5py, whose arrays come back with MATLAB's axes reversed (``pressure`` is
(32, 32, N) there) and are transposed back, and whose cell arrays of strings are object
references to uint16 ``char`` datasets. :func:`read_mat_fields` returns the raw variables;
``touch/training/data.py`` builds the dataset from them.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import h5py
import numpy as np
import scipy.io

from tactus_memory.errors import DataFormatError

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


def read_mat_fields(path: str | Path) -> dict[str, Any]:
    """All variables of a v5 or v7.3 MAT file: numeric arrays in MATLAB's axis order,
    cell arrays of strings as ``list[str]``."""
    p = _resolve(path)
    return _read_v73(p) if h5py.is_hdf5(p) else _read_v5(p)
