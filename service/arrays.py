"""Turning request payloads into arrays: JSON without NaN, ``.npy`` bodies, sensor frames.

The edge checks what a request is made of, once: parseable, numeric, the shape (windows (K, *F),
batches (B, K, *F), F the frame shape of the windowed sense written to: (H, W) = 32x32 for the STAG
glove, its checkpoint's sensor profile for another touch sense, (C,) for an IMU) and the size; what
the numbers mean (finite, range, calibration, idle) is the sense's check, once (``validate``:
``TactusEncoder.validate`` for touch). A stream frame is no item, so its own finiteness is checked
here (the error names the frame).
Every failure raises ``InvalidInputError`` with a message naming the problem, so it becomes a
422 problem in the one mapping (``errors.ERROR_STATUS``).
"""

from __future__ import annotations

import io
import json
from typing import Any

import numpy as np

from tactus_memory.errors import InvalidInputError

NPY_TYPES = ("application/x-npy", "application/octet-stream")


def _reject_constant(name: str) -> Any:
    raise InvalidInputError(f"JSON contains {name}; NaN and Infinity are not valid numbers here")


def loads_strict(raw: bytes | str) -> Any:
    """``json.loads`` that rejects the NaN/Infinity literals Python's json would accept."""
    try:
        return json.loads(raw, parse_constant=_reject_constant)
    except InvalidInputError:
        raise
    except (ValueError, RecursionError) as exc:
        raise InvalidInputError(f"body is not valid JSON: {exc}") from None


#: header bytes -> (dtype, shape, fortran_order, data offset) of headers already parsed once;
#: a glove streams thousands of frames with the same header, and numpy parses each header
#: with ``ast.literal_eval`` (~50 us), so a seen header is looked up instead.
_HEADERS: dict[bytes, tuple[np.dtype, tuple[int, ...], bool, int]] = {}
_MAX_HEADERS = 256


def _npy_fast(raw: bytes) -> np.ndarray | None:
    if len(raw) < 10 or raw[:6] != b"\x93NUMPY" or raw[6] != 1:
        return None
    offset = 10 + int.from_bytes(raw[8:10], "little")
    known = _HEADERS.get(raw[:offset])
    if known is None:
        return None
    dtype, shape, fortran, offset = known
    count = int(np.prod(shape, dtype=np.int64))
    if len(raw) - offset != count * dtype.itemsize:
        return None
    arr = np.frombuffer(raw, dtype=dtype, count=count, offset=offset)
    return arr.reshape(shape, order="F" if fortran else "C")


def _remember_header(raw: bytes, arr: np.ndarray) -> None:
    if raw[:6] != b"\x93NUMPY" or raw[6] != 1 or len(_HEADERS) >= _MAX_HEADERS:
        return
    offset = 10 + int.from_bytes(raw[8:10], "little")
    fortran = arr.flags.f_contiguous and not arr.flags.c_contiguous
    _HEADERS[raw[:offset]] = (arr.dtype, arr.shape, fortran, offset)


#: largest absolute pressure value accepted (raw ADC units are < 65536; calibrated 0-1)
MAX_FRAME_VALUE = 1e6
#: the first bytes of every .npy file (numpy format spec)
NPY_MAGIC = b"\x93NUMPY"


def load_npy(raw: bytes, what: str = "npy body", *, frames: bool = False) -> np.ndarray:
    """``.npy`` bytes -> a float32 array (no pickles, numeric dtypes only); ``frames``: stream
    frames, checked finite too (:func:`finite_frames`)."""
    arr = read_npy(raw, what)
    if arr.dtype.kind in "biu" and arr.dtype.itemsize <= 2:
        return arr.astype(np.float32)  # 16-bit integers (a glove's ADC): finite and in range
    out = arr.astype(np.float32, copy=False)
    return _in_range(finite_frames(out, what) if frames else out, what)


def read_npy(raw: bytes, what: str = "npy body") -> np.ndarray:
    """``.npy`` bytes -> the numeric array as sent (no pickles; any numeric dtype, so float64
    times keep their precision)."""
    if not raw:
        raise InvalidInputError(f"{what} is empty")
    arr = _npy_fast(raw)
    if arr is None:
        if not raw.startswith(NPY_MAGIC):
            raise InvalidInputError(
                f"{what} is not a .npy array (it does not start with the .npy magic bytes): "
                "send the output of numpy.save for a numeric array"
            )
        try:
            arr = np.load(io.BytesIO(raw), allow_pickle=False)
        except Exception as exc:  # noqa: BLE001  (numpy raises many kinds on garbage)
            if "pickle" in str(exc):  # numpy's wording for object arrays: name the real issue
                raise InvalidInputError(
                    f"{what} holds Python objects, not numbers: send a .npy array of a "
                    "numeric dtype"
                ) from None
            raise InvalidInputError(f"{what} is not a valid .npy array: {exc}") from None
        if not isinstance(arr, np.ndarray):
            raise InvalidInputError(f"{what} must hold one array, not an archive")
        if arr.dtype.kind in "biuf" and arr.nbytes <= 1 << 20:
            _remember_header(raw, arr)
    if arr.dtype.kind not in "biuf":
        raise InvalidInputError(f"{what} has dtype {arr.dtype}; use a numeric dtype")
    return arr


def _in_range(arr: np.ndarray, what: str) -> np.ndarray:
    if arr.size and float(np.abs(arr).max()) > MAX_FRAME_VALUE:
        raise InvalidInputError(
            f"{what} has values beyond +-{MAX_FRAME_VALUE:g}: frames are raw sensor units "
            "(a glove ADC reads < 65536) or calibrated 0-1"
        )
    return arr


def as_float_array(value: Any, what: str) -> np.ndarray:
    """Nested lists (parsed JSON: no NaN) -> a float32 array; ragged or non-numeric input is
    named, and numbers beyond float32 (inf) fail the range check."""
    try:
        arr = np.asarray(value, dtype=np.float32)
    except (ValueError, TypeError):
        raise InvalidInputError(
            f"{what} is ragged or not numeric: every frame must be H rows of W numbers "
            "(the sense's frame shape)"
        ) from None
    return _in_range(arr, what)


def finite_frames(arr: np.ndarray, what: str) -> np.ndarray:
    """Stream frames: no NaN or inf (the error names the frame, not a later window)."""
    if not np.isfinite(arr).all():
        raise InvalidInputError(f"{what} contains NaN or inf")
    return arr


def shape_name(shape: tuple[int, ...]) -> str:
    """How an error names a frame shape: ``32x32`` for (32, 32), ``6`` for (6,)."""
    return "x".join(map(str, shape))


def _expected(shape: tuple[int, ...], sense: str | None) -> str:
    """How a shape error names what was expected: the sense's frame shape, and the sense."""
    name = shape_name(shape)
    return f"{name} frames" + ("" if sense is None else f" (sense {sense!r} reads {name})")


def as_window_array(
    value: Any, lead: str, what: str, shape: tuple[int, ...], sense: str | None = None
) -> np.ndarray:
    """``value`` as frames of the ``lead`` axes, then ``shape`` (the windowed sense's frame
    shape, e.g. (H, W) for touch): ``""`` one stream frame, ``"K"`` one window (K, *shape),
    ``"BK"`` a batch of windows (B, K, *shape); a lead axis may not be empty. Parsed JSON holds
    no NaN and inf is out of range; an error names ``what``, the shape expected and ``sense``."""
    arr = value if isinstance(value, np.ndarray) else as_float_array(value, what)
    n = len(lead)
    if arr.ndim != n + len(shape) or arr.shape[n:] != tuple(shape) or 0 in arr.shape[:n]:
        axes = ", ".join([*lead, *map(str, shape)])
        raise InvalidInputError(
            f"{what} has shape {arr.shape}, expected ({axes}): " + _expected(shape, sense)
        )
    return arr
