"""Sensor profiles from a TOML file or from flags (``--sensor FILE.toml`` or
``--shape HxW --offset O --span S``), for training on your own sensor.

A profile file (every key but ``name`` and ``span`` optional; arrays may be inline or ``.npy``
files named relative to the TOML file)::

    name = "five-pad-hand"
    shape = [12, 16]          # (H, W); default: the extent of the pads
    offset = 200              # raw reading calibrated to 0 ...
    span = 3000               # ... and offset + span to 1: clip((raw - offset) / span, 0, 1)
    rest = 210                # untouched reading (diagnostics; fills pixels no pad covers)
    saturation = 4095         # reading where the sensor saturates (diagnostics)
    # contact_level = 0.08    # calibrated level of a touching taxel (default: the glove's 1/6)
    # taxel_offset = "offsets.npy"   # (H, W) per-taxel offset, replaces offset
    # taxel_gain = "gains.npy"       # (H, W) per-taxel gain (1/span), replaces span
    # mask = "mask.npy"              # (H, W) bool real taxels (default: the pads' taxels)

    [[pad]]
    name = "thumb"
    shape = [4, 4]            # rows, cols
    at = [0, 0]               # top-left taxel in the frame

The built-in ``stag-glove`` is :data:`tactus_memory.touch.profile.STAG_GLOVE`.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import numpy as np
import tomllib

from tactus_memory.errors import InvalidInputError
from tactus_memory.touch.pads import Pad, layout_extent
from tactus_memory.touch.profile import PROFILES, SensorProfile

PROFILE_KEYS = frozenset(
    {"name", "shape", "offset", "span", "rest", "saturation", "taxel_offset", "taxel_gain"}
    | {"mask", "pad", "contact_level"}
)
_SHAPE = re.compile(r"^\s*(\d+)\s*[xX]\s*(\d+)\s*$")


def parse_shape(text: str) -> tuple[int, int]:
    """``"16x16"`` -> (16, 16); anything else raises :class:`InvalidInputError`."""
    m = _SHAPE.match(text or "")
    if not m:
        raise InvalidInputError(f"a frame shape is HxW, e.g. 16x16, got {text!r}")
    return int(m.group(1)), int(m.group(2))


def _array(value: Any, base: Path, key: str) -> np.ndarray | None:
    if value is None:
        return None
    if isinstance(value, str):
        path = (base / value).resolve()
        if path.suffix != ".npy" or not path.is_file():
            raise InvalidInputError(f"{key}: no .npy file at {path}")
        return np.load(path, allow_pickle=False)
    return np.asarray(value)


def profile_from_toml_dict(d: dict[str, Any], base: Path = Path(".")) -> SensorProfile:
    """A parsed profile TOML (``tomllib``) -> :class:`SensorProfile`; ``base`` resolves
    ``.npy`` paths."""
    unknown = sorted(set(d) - PROFILE_KEYS)
    if unknown:
        raise InvalidInputError(
            f"unknown sensor profile key(s) {unknown}; known: {sorted(PROFILE_KEYS)}"
        )
    for key in ("name", "span"):
        if key not in d:
            raise InvalidInputError(f"a sensor profile needs {key!r}")
    pads = tuple(Pad.from_dict(p) for p in d.get("pad", []))
    if "shape" in d:
        shape = tuple(int(v) for v in d["shape"])
    elif pads:
        shape = layout_extent(pads)
    else:
        raise InvalidInputError("a sensor profile needs shape = [H, W] (or a pad layout)")
    arrays = {k: _array(d.get(k), base, k) for k in ("taxel_offset", "taxel_gain", "mask")}
    offset = d.get("offset")
    if offset is None:  # per-taxel offsets: the gates' bar is the lowest one
        t_off = arrays["taxel_offset"]
        offset = float(np.min(t_off)) if t_off is not None else 0.0
    try:
        return SensorProfile(
            name=str(d["name"]),
            offset=float(offset),
            span=float(d["span"]),
            shape=shape,  # type: ignore[arg-type]
            rest_raw=None if d.get("rest") is None else float(d["rest"]),
            saturation_raw=None if d.get("saturation") is None else float(d["saturation"]),
            taxel_offset=arrays["taxel_offset"],  # type: ignore[arg-type]
            taxel_gain=arrays["taxel_gain"],  # type: ignore[arg-type]
            mask=arrays["mask"],  # type: ignore[arg-type]
            pads=pads,
            contact_level=None if d.get("contact_level") is None else float(d["contact_level"]),
        )
    except (TypeError, ValueError) as exc:
        raise InvalidInputError(f"bad sensor profile: {exc}") from exc


def load_profile_toml(path: str | Path) -> SensorProfile:
    """Read a sensor profile TOML file (format in this module's docstring)."""
    p = Path(path)
    if not p.is_file():
        raise InvalidInputError(f"no sensor profile file at {p}")
    try:
        d = tomllib.loads(p.read_text())
    except tomllib.TOMLDecodeError as exc:
        raise InvalidInputError(f"{p}: not valid TOML: {exc}") from exc
    return profile_from_toml_dict(d, p.parent)


def resolve_profile(
    sensor: str | Path | None = None,
    shape: str | None = None,
    offset: float | None = None,
    span: float | None = None,
    default: SensorProfile | None = None,
) -> SensorProfile | None:
    """The profile the training flags name: ``sensor`` is a built-in name (``stag-glove``) or a
    TOML file; else ``shape`` (``HxW``) with ``offset`` and ``span`` makes an unnamed one
    (``sensor-HxW``); else ``default``. Mixing both ways raises :class:`InvalidInputError`."""
    flags = [n for n, v in (("--shape", shape), ("--offset", offset), ("--span", span)) if v]
    if sensor is not None and flags:
        raise InvalidInputError(f"give --sensor or {', '.join(flags)}, not both")
    if sensor is not None:
        return PROFILES[str(sensor)] if str(sensor) in PROFILES else load_profile_toml(sensor)
    if flags:
        if shape is None or span is None:
            raise InvalidInputError("--shape HxW needs --span S (and --offset O, default 0)")
        h, w = parse_shape(shape)
        return SensorProfile(f"sensor-{h}x{w}", float(offset or 0.0), float(span), (h, w))
    return default
