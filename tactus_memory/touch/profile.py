"""The sensor profile: how raw glove readings become calibrated pressure, and the dynamic-range
gate that makes a wrongly scaled subset loud. Shared by training
(``touch/training/data.py``), the touch sense (``adapters/touch.py``) and the service.

Every subset is calibrated with the sensor's own affine ``clip((raw - 500) / 150, 0, 1)``
(the STAG reference code; the paper, Sec. Method "Data path"), identically for every subset.
Per-file max scaling is the defect of the paper's forensics section (Sec. "Anatomy of a Silent
Data Defect"); :func:`check_dynamic_range` makes it loud. Spec: ``../shared/stag-format.md``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from tactus_memory.errors import DynamicRangeError, InvalidInputError
from tactus_memory.touch.pads import Pad, assemble, check_layout, layout_mask, split

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


# --------------------------------------------------------------------------- calibration


#: the smallest frame side a sensor may have (the trunk's stem and stages need 4 taxels a side)
MIN_SIDE = 4

#: an (H, W) grid of numbers held immutably (per-taxel offsets, gains, the taxel mask)
Grid = tuple[tuple[float, ...], ...]


def _grid(name: str, value: Any, shape: tuple[int, int], kind: type) -> Any:
    """An (H, W) array-like -> a tuple-of-tuples grid of ``kind``; None stays None."""
    if value is None:
        return None
    arr = np.asarray(value, dtype=bool if kind is bool else np.float64)
    if arr.shape != tuple(shape):
        raise InvalidInputError(f"{name} must have the frame shape {tuple(shape)}, got {arr.shape}")
    if kind is not bool and not np.all(np.isfinite(arr)):
        raise InvalidInputError(f"{name} must be finite")
    return tuple(tuple(kind(v) for v in row) for row in arr.tolist())


@dataclass(frozen=True)
class SensorProfile:
    """A named sensor: its frame shape (H, W) and calibration to [0, 1] float32.

    Calibration is ``clip((raw - offset) / span, 0, 1)``, or per taxel
    ``clip((raw - taxel_offset) * taxel_gain, 0, 1)`` where those (H, W) arrays are given
    (either replaces its scalar; ``offset`` stays the gates' "reading above rest" bar). Pixels
    outside ``mask`` (H, W) bool calibrate to 0. ``pads`` name blocks of the frame (a robot
    hand's fingertips and palm, :mod:`tactus_memory.touch.pads`); with pads and no mask the
    mask is the pads' taxels. Built-in: :data:`STAG_GLOVE`; others from a TOML file or flags
    (:mod:`tactus_memory.touch.sensor_file`).
    """

    name: str
    offset: float
    span: float
    shape: tuple[int, int] = FRAME_SHAPE
    rest_raw: float | None = None  # typical untouched reading, for diagnostics
    saturation_raw: float | None = None  # reading where the sensor saturates, for diagnostics
    taxel_offset: Grid | None = None  # (H, W) raw offset per taxel, replaces ``offset``
    taxel_gain: Grid | None = None  # (H, W) calibrated units per raw count, replaces 1 / span
    mask: tuple[tuple[bool, ...], ...] | None = None  # (H, W) bool: real taxels
    pads: tuple[Pad, ...] = ()  # named blocks of the frame, in drawing order
    #: calibrated level a taxel must reach to count as touching (None: the glove's,
    #: ``touch.windows.CONTACT_LEVEL``); read it through ``touch.windows.contact_level``
    contact_level: float | None = None

    def __post_init__(self) -> None:
        if not np.isfinite(self.offset) or not np.isfinite(self.span) or self.span <= 0:
            raise InvalidInputError(
                f"profile {self.name!r}: offset must be finite and span > 0, "
                f"got offset={self.offset}, span={self.span}"
            )
        shape = tuple(int(v) for v in self.shape)
        if len(shape) != 2 or min(shape) < MIN_SIDE:
            raise InvalidInputError(
                f"profile {self.name!r}: the frame shape must be (H, W) with H, W >= {MIN_SIDE}, "
                f"got {self.shape}"
            )
        object.__setattr__(self, "shape", shape)
        object.__setattr__(self, "pads", tuple(self.pads))
        check_layout(self.pads, shape)
        mask = self.mask
        if mask is None and self.pads:
            mask = layout_mask(self.pads, shape)  # type: ignore[assignment]  # an array as the field
        object.__setattr__(self, "mask", _grid("mask", mask, shape, bool))
        for f in ("taxel_offset", "taxel_gain"):
            object.__setattr__(self, f, _grid(f, getattr(self, f), shape, float))
        if self.taxel_gain is not None and np.any(np.asarray(self.taxel_gain) <= 0):
            raise InvalidInputError(f"profile {self.name!r}: taxel_gain must be > 0")
        if self.contact_level is not None and not 0.0 < float(self.contact_level) < 1.0:
            raise InvalidInputError(
                f"profile {self.name!r}: contact_level must be in (0, 1) calibrated, "
                f"got {self.contact_level}"
            )

    @property
    def per_taxel(self) -> bool:
        """Whether the calibration or the mask vary taxel by taxel."""
        return any(v is not None for v in (self.taxel_offset, self.taxel_gain, self.mask))

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
        out = self.scale(arr)
        if not np.all(np.isfinite(out)):
            raise InvalidInputError("raw pressure contains NaN or inf")
        return out

    def scale(self, raw: np.ndarray) -> np.ndarray:
        """The calibration alone, no checks: clip((raw - offset) / span, 0, 1) as float32 (per
        taxel where the profile says so, 0 outside the mask; NaN stays NaN). Per-taxel
        profiles need (..., H, W) input; ``calibrate`` adds the frame-shape and value checks."""
        x = np.asarray(raw).astype(np.float32)
        off = np.float32(self.offset) if self.taxel_offset is None else self._arr("taxel_offset")
        if self.taxel_gain is None:
            out = (x - off) / np.float32(self.span)
        else:
            out = (x - off) * self._arr("taxel_gain")
        if self.mask is not None:
            out = np.where(np.asarray(self.mask, dtype=bool), out, np.float32(0.0))
        return np.clip(out, 0.0, 1.0, out=out).astype(np.float32, copy=False)

    def _arr(self, name: str) -> np.ndarray:
        return np.asarray(getattr(self, name), dtype=np.float32)

    @property
    def fill_raw(self) -> float:
        """The raw reading for pixels no pad covers: the rest reading (else the offset)."""
        return float(self.offset if self.rest_raw is None else self.rest_raw)

    def assemble(self, readings: dict[str, np.ndarray]) -> np.ndarray:
        """``{pad: (..., rows, cols)}`` raw pad readings -> (..., H, W) raw frames."""
        if not self.pads:
            raise InvalidInputError(f"profile {self.name!r} has no pad layout")
        return assemble(readings, self.pads, self.shape, fill=self.fill_raw)

    def split(self, frames: np.ndarray) -> dict[str, np.ndarray]:
        """(..., H, W) frames -> ``{pad: (..., rows, cols)}`` (for drawing pads at their place)."""
        if not self.pads:
            raise InvalidInputError(f"profile {self.name!r} has no pad layout")
        return split(frames, self.pads)

    def to_dict(self) -> dict[str, Any]:
        d: dict[str, Any] = {
            "name": self.name,
            "offset": float(self.offset),
            "span": float(self.span),
            "shape": list(self.shape),
            "rest_raw": self.rest_raw,
            "saturation_raw": self.saturation_raw,
        }
        for f in ("taxel_offset", "taxel_gain", "mask"):  # only when set: old dicts stay equal
            if getattr(self, f) is not None:
                d[f] = [list(row) for row in getattr(self, f)]
        if self.pads:
            d["pads"] = [p.to_dict() for p in self.pads]
        if self.contact_level is not None:  # only when set: old dicts stay equal
            d["contact_level"] = float(self.contact_level)
        return d

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
                taxel_offset=d.get("taxel_offset"),
                taxel_gain=d.get("taxel_gain"),
                mask=d.get("mask"),
                pads=tuple(Pad.from_dict(p) for p in d.get("pads", ())),
                contact_level=(
                    None if d.get("contact_level") is None else float(d["contact_level"])
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
    if mask is None and profile.mask is not None:  # the profile's taxels (e.g. its pads)
        mask = np.asarray(profile.mask, dtype=bool)
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
