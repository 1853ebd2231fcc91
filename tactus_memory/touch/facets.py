"""Facets: what a touch window or a grasp physically was, computed from its calibrated frames
with numpy alone (no model): how hard, how much of the sensor, where, on which regions, and
for a grasp when it began and ended, how fast it tightened, whether it slid, which grip.

Per window (:func:`window_facets`, vectorised over B windows of K frames, (B, K, H, W) in):

* ``force``: per frame the sum of the calibrated taxel values (:func:`taxel_mask`), averaged
  over the window's frames (calibrated units; times ``newtons_per_unit`` when the caller
  knows the sensor's factor to newtons). Every taxel counts, so a resting sensor has a
  floor (the STAG glove's pedestal sits near 0.07-0.10 calibrated, stag-format.md: about
  55 of force on the blindfolded recordings' held frames);
* ``area``: per frame the share of the sensor's taxels (:func:`taxel_mask`) at or
  above the contact level (``touch.windows.contact_level``: the profile's, else the glove's
  1/6), averaged over the frames;
* ``peak``: the highest calibrated taxel value of the window;
* ``centroid`` (row, col) and ``spread`` (taxels): the mean position and the RMS distance from
  it of the *contact load*, the calibrated values of the taxels at or above the contact level
  summed over the frames (the resting pedestal would pull every centroid to the middle);
  None without contact;
* ``regions``: each region's (:mod:`tactus_memory.touch.regions`) share of the contact load;
  empty for a sensor without regions;
* ``grip``: :func:`grip_of` the regions;
* ``load``: the contact load itself (what a grasp weighs its windows by).

Per grasp (:func:`grasp_facets`, from its member windows' facets and time spans):
``force``, ``area``, ``peak`` and ``spread`` are the maxima over the windows; ``centroid`` and
``regions`` the contact-load-weighted means; ``onset`` the first window's start, ``release``
the last window's end, ``duration`` their difference; ``peak_time`` the middle of the window
of highest force; ``ramp`` (squeeze) the rise of force from the first window to that one per
second (0 when the first window is the firmest); ``slip`` the centroid's speed, the length of
its path through the windows over the time between the first and the last window's middle
(taxels per second; 0 for one window); ``grip`` from the grasp's regions.

**The grip rule** (:func:`grip_of`). A region is *active* when it carries at least
:data:`ACTIVE_SHARE` of the contact load. Then, in this order: no active region: ``none``;
the palm and any other region: ``power``; one region alone: ``press``; the thumb and one
finger: ``pinch``; the thumb and two fingers: ``tripod``; anything else (three or more fingers
without the palm, fingers without the thumb): ``other``. Region roles come from their names:
``thumb`` and ``palm``; every other region (a pad of a robot hand) is a finger. A sensor
without regions has no grip (None).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from typing import Any

import numpy as np

from tactus_memory.errors import InvalidInputError
from tactus_memory.touch.profile import SensorProfile
from tactus_memory.touch.regions import PALM, THUMB, RegionMap, regions_of
from tactus_memory.touch.windows import contact_level

#: a region carries at least this share of the contact load to count as active in the grip
#: rule: one finger's strip of the STAG glove is 42 of its 548 taxels (7.7 %), so a tenth of
#: the load is more than a uniform spread would give it
ACTIVE_SHARE = 0.10
#: grip names, in the order the rule tests them (module docstring)
GRIPS = ("none", "power", "press", "pinch", "tripod", "other")
#: the facet names a window has, and those a grasp adds
WINDOW_FACETS = (
    *("force", "area", "peak", "centroid", "spread", "regions", "grip", "load", "taxels"),
)
GRASP_FACETS = (
    *WINDOW_FACETS,
    *("onset", "release", "duration", "peak_time", "ramp", "rise", "slip"),
    *("caption", "caption_rule"),
)


def grip_of(shares: dict[str, float]) -> str | None:
    """The grip a region -> load-share mapping shows (the rule in the module docstring);
    None when there are no regions (a sensor without them)."""
    if not shares:
        return None
    active = {r for r, s in shares.items() if s >= ACTIVE_SHARE}
    fingers = len(active - {THUMB, PALM})
    if not active:
        return "none"
    if PALM in active and len(active) > 1:
        return "power"
    if len(active) == 1:
        return "press"
    if THUMB in active and PALM not in active and fingers == 1:
        return "pinch"
    if THUMB in active and PALM not in active and fingers == 2:
        return "tripod"
    return "other"


@dataclass(frozen=True)
class WindowFacets:
    """Facets of B windows, one entry per window. ``centroid`` (B, 2) (row, col) and
    ``spread`` (B,) are NaN without contact; ``regions`` (B, R) shares of the contact load
    (0 without contact), names in ``region_names``; ``load`` (B,) the contact load itself
    (the weight a grasp gives each window)."""

    force: np.ndarray
    area: np.ndarray
    peak: np.ndarray
    centroid: np.ndarray
    spread: np.ndarray
    regions: np.ndarray
    load: np.ndarray
    region_names: tuple[str, ...]
    #: the sensor's taxel count (:func:`taxel_mask`): ``force`` over it is the mean
    #: calibrated reading, the sensor-relative firmness (:func:`pressure`); None: not known
    #: (facets stored before it was kept)
    taxels: int | None = None

    def __len__(self) -> int:
        return int(self.force.shape[0])

    def shares(self, i: int) -> dict[str, float]:
        return {n: float(v) for n, v in zip(self.region_names, self.regions[i], strict=True)}

    def row(self, i: int) -> dict[str, Any]:
        """Window ``i``'s facets as plain values (the names of :data:`WINDOW_FACETS`)."""
        c = self.centroid[i]
        shares = self.shares(i)
        return {
            "force": float(self.force[i]),
            "area": float(self.area[i]),
            "peak": float(self.peak[i]),
            "centroid": None if np.isnan(c).any() else [float(c[0]), float(c[1])],
            "spread": None if np.isnan(self.spread[i]) else float(self.spread[i]),
            "regions": shares,
            "grip": grip_of(shares) if self.load[i] > 0 or not shares else "none",
            "load": float(self.load[i]),
            "taxels": self.taxels,
        }

    def rows(self) -> list[dict[str, Any]]:
        return [self.row(i) for i in range(len(self))]


def taxel_mask(
    profile: SensorProfile | None, regions: RegionMap | None, shape: tuple[int, int]
) -> np.ndarray:
    """(H, W) bool, the taxels facets count: the profile's mask, else the taxels the regions
    cover (the STAG glove's 548), else every pixel."""
    if profile is not None and profile.mask is not None:
        return np.asarray(profile.mask, dtype=bool)
    if regions is not None:
        return regions.index >= 0
    return np.ones(shape, dtype=bool)


def window_facets(
    frames: np.ndarray,
    profile: SensorProfile | None = None,
    *,
    regions: RegionMap | None = None,
    level: float | None = None,
    newtons_per_unit: float | None = None,
) -> WindowFacets:
    """Facets of calibrated windows: ``frames`` (B, K, H, W) or one window (K, H, W), values
    in [0, 1] (the touch sense's ``validate`` output).

    ``profile`` gives the regions (:func:`~tactus_memory.touch.regions.regions_of`), the
    contact level (:func:`contact_level`) and the taxels (:func:`taxel_mask`; pixels that are
    no taxel count 0); ``regions`` and ``level`` override them (without a profile: no
    regions, the touch sense's contact level, every pixel a taxel). ``newtons_per_unit``
    scales ``force``."""
    arr = np.asarray(frames, dtype=np.float32)
    if arr.ndim == 3:
        arr = arr[None]
    if arr.ndim != 4 or arr.shape[1] < 1:
        raise InvalidInputError(f"facets need (B, K, H, W) windows, got shape {arr.shape}")
    b, k, h, w = arr.shape
    if profile is not None and tuple(profile.shape) != (h, w):
        raise InvalidInputError(f"profile {profile.name!r} reads {profile.shape}, got {h}x{w}")
    if regions is None and profile is not None:
        regions = regions_of(profile)
    if regions is not None and regions.shape != (h, w):
        raise InvalidInputError(f"the region map is {regions.shape}, frames are {h}x{w}")
    lvl = np.float32(contact_level(profile) if level is None else level)
    mask = taxel_mask(profile, regions, (h, w)).reshape(-1)  # (HW,)
    x = arr.reshape(b, k, h * w)
    if not mask.all():  # pixels that are no taxel (the glove's 476 constant ones) count 0
        x = np.where(mask, x, np.float32(0))
    n_taxels = max(1, int(mask.sum()))
    on = x >= lvl  # (B, K, HW)
    force = x.sum(axis=2, dtype=np.float64).mean(axis=1)  # (B,)
    if newtons_per_unit is not None:
        force = force * float(newtons_per_unit)
    area = on.sum(axis=2).mean(axis=1) / float(n_taxels)  # (B,)
    peak = x.max(axis=(1, 2)).astype(np.float64)  # (B,)
    lw = np.where(on, x, np.float32(0)).sum(axis=1, dtype=np.float64)  # (B, HW) contact load
    load = lw.sum(axis=1)  # (B,)
    rr, cc = np.divmod(np.arange(h * w, dtype=np.float64), w)  # (HW,) taxel row, column
    with np.errstate(invalid="ignore", divide="ignore"):
        cy, cx = lw @ rr / load, lw @ cc / load
        var = lw @ (rr * rr + cc * cc) / load - cy * cy - cx * cx
    spread = np.sqrt(np.maximum(var, 0.0))
    if regions is None:
        shares = np.zeros((b, 0))
        names: tuple[str, ...] = ()
    else:
        names = regions.names
        with np.errstate(invalid="ignore", divide="ignore"):
            shares = np.nan_to_num((lw @ regions.onehot()) / load[:, None], nan=0.0)
    return WindowFacets(
        force=force,
        area=area,
        peak=peak,
        centroid=np.stack([cy, cx], axis=1),
        spread=spread,
        regions=shares,
        load=load,
        region_names=names,
        taxels=n_taxels,
    )


def grasp_facets(f: WindowFacets, t: np.ndarray, t_end: np.ndarray) -> dict[str, Any]:
    """One grasp's facets from its n member windows' facets ``f`` and their spans ``t``,
    ``t_end`` (n,) seconds (any order: sorted by ``t`` here). Names: :data:`GRASP_FACETS`."""
    n = len(f)
    ts, te = np.asarray(t, np.float64).reshape(-1), np.asarray(t_end, np.float64).reshape(-1)
    if n == 0 or ts.shape != (n,) or te.shape != (n,):
        raise InvalidInputError(f"a grasp needs >= 1 window and one span each, got {n} windows")
    order = np.argsort(ts, kind="stable")
    ts, te = ts[order], te[order]
    force, load = f.force[order], f.load[order]
    mid = (ts + te) / 2
    top = int(np.argmax(force))
    total = float(load.sum())
    if total > 0:
        w = load / total
        has = load > 0
        cen = (f.centroid[order][has] * w[has, None]).sum(axis=0) / w[has].sum()
        centroid: list[float] | None = [float(cen[0]), float(cen[1])]
        shares = {
            name: float(v) for name, v in zip(f.region_names, w @ f.regions[order], strict=True)
        }
    else:
        centroid, shares = None, {name: 0.0 for name in f.region_names}
    path = f.centroid[order][load > 0]
    dt = float(mid[load > 0][-1] - mid[load > 0][0]) if len(path) > 1 else 0.0
    steps = np.linalg.norm(np.diff(path, axis=0), axis=1).sum() if len(path) > 1 else 0.0
    ramp_dt = float(mid[top] - mid[0])
    rise = float(force[top] - force[0])
    spread = f.spread[order]
    out: dict[str, Any] = {
        "force": float(force.max()),
        "area": float(f.area.max()),
        "peak": float(f.peak.max()),
        "centroid": centroid,
        "spread": None if np.isnan(spread).all() else float(np.nanmax(spread)),
        "regions": shares,
        "grip": grip_of(shares) if total > 0 or not shares else "none",
        "load": total,
        "onset": float(ts[0]),
        "release": float(te.max()),
        "duration": float(te.max() - ts[0]),
        "peak_time": float(mid[top]),
        "ramp": rise / ramp_dt if ramp_dt > 0 else 0.0,
        "rise": rise,
        "slip": float(steps / dt) if dt > 0 else 0.0,
        "taxels": f.taxels,
    }
    out["caption"], out["caption_rule"] = caption(out), CAPTION_RULE
    return out


def active_regions(shares: dict[str, float]) -> list[str]:
    """The regions carrying at least :data:`ACTIVE_SHARE` of the load, most loaded first."""
    return [r for r, s in sorted(shares.items(), key=lambda kv: -kv[1]) if s >= ACTIVE_SHARE]


def facet_columns(facets: dict[str, Any]) -> dict[str, Any]:
    """One window's facets (:meth:`WindowFacets.row`) -> the store's facet columns
    (``storage.tables.FACET_COLUMNS``): ``force``, ``area``, ``peak``, ``grip``, ``regions``
    (the active regions as ``",thumb,index,"``, so a filter can ask for one by name) and
    ``facets`` (all of them as JSON)."""
    active = active_regions(facets.get("regions") or {})
    return {
        "force": facets["force"],
        "area": facets["area"],
        "peak": facets["peak"],
        "grip": facets.get("grip"),
        "regions": "," + ",".join(active) + "," if active else ",",
        "facets": json.dumps(facets, separators=(",", ":")),
    }


def facets_of_rows(rows: list[dict[str, Any]], taxels: int | None = None) -> WindowFacets:
    """Stored windows' facets (each a :meth:`WindowFacets.row` dict, as the ``facets`` column
    holds it) -> :class:`WindowFacets` again, for :func:`grasp_facets`; ``taxels``: the
    sensor's taxel count where the rows do not say it (facets stored before it was kept)."""
    names = tuple(rows[0].get("regions") or {}) if rows else ()
    force = np.array([r["force"] for r in rows], np.float64)
    cen = np.array(
        [r["centroid"] if r.get("centroid") else (np.nan, np.nan) for r in rows], np.float64
    ).reshape(-1, 2)
    load = np.array([r.get("load", 0.0) for r in rows], np.float64)
    known = {int(r["taxels"]) for r in rows if r.get("taxels") is not None}
    return WindowFacets(
        force=force,
        area=np.array([r["area"] for r in rows], np.float64),
        peak=np.array([r["peak"] for r in rows], np.float64),
        centroid=cen,
        spread=np.array([np.nan if r.get("spread") is None else r["spread"] for r in rows]),
        regions=np.array(
            [[(r.get("regions") or {}).get(n, 0.0) for n in names] for r in rows]
        ).reshape(len(rows), len(names)),
        load=load,
        region_names=names,
        taxels=known.pop() if len(known) == 1 else taxels,
    )


# --------------------------------------------------------------------------- captions
#: the caption rule's version, returned beside each caption (``caption_rule``): bump it when
#: :func:`caption` changes, so captions written by another rule can be told apart and redone.
#: Rule 3: firmness from ``force`` relative to the sensor (:func:`pressure`), not the peak
#: taxel, its words first; a grasp's caption says its motion (:func:`motion`) first instead
#: of its duration in digits
CAPTION_RULE = 3
#: :func:`pressure` bands of the caption's firmness word: below LIGHT_PRESSURE "light", from
#: FIRM_PRESSURE "firm", between "steady". The quartiles of the mean calibrated taxel reading
#: (force / taxels) over the 419 stored windows of the blindfolded STAG recordings (objects
#: handled; one of the shipped checkpoint's two training subsets, and the recordings of
#: benchmarks/facet_questions.py; benchmarks/firmness_bands.py, results/firmness_bands.json).
#: The glove's resting pedestal (0.07-0.10 calibrated) is most of it, so the bands are narrow;
#: the other training subset (weights held, another day) reads higher: all "firm" by them
LIGHT_PRESSURE = 0.0940
FIRM_PRESSURE = 0.0994
#: centroid speed (taxels per second) from which a grasp is "slipping": the 75th percentile
#: of the grasps the memory cuts from the checkpoint's training recordings (49 grasps, median
#: 3.7: a hand handling an object moves its load; benchmarks/results/facet_questions.json,
#: ``grasps_in_words.stats``). Rule 2 had 2.0, chosen, which called most grasps slipping
SLIP_SPEED = 6.0
#: a grasp shorter than this (seconds) is "a brief touch" (chosen: under a second, two
#: stored glove windows); one at least LONG_HOLD_S long and not slipping is "a long steady
#: hold": the 75th percentile of the same grasps' durations (median 4.3 s)
BRIEF_S = 1.0
LONG_HOLD_S = 6.0
#: what a firmness adds in words (rule 2: "squeezing hard" was at cosine 0.46 to rule 1's "a
#: firm pinch with thumb and index", 0.71 to "a firm press with palm, squeezing hard"
#: (MiniLM)); a steady one says nothing ("holding" would pull every object question)
FIRMNESS_WORDS = {"light": "touching lightly", "firm": "squeezing hard"}
#: how a grasp's motion (:func:`motion`) is said; "held" says nothing
MOTION_WORDS = {"brief": "a brief touch", "long": "a long steady hold", "slipping": "slipping"}
MOTIONS = ("brief", "held", "long", "slipping")
#: how a grip is said
GRIP_WORDS = {
    "pinch": "pinch",
    "tripod": "tripod grip",
    "power": "power grasp",
    "press": "press",
    "other": "grasp",
    "none": "touch",
}
#: each firmness's band of :func:`pressure`, [lo, hi) (None: open)
FIRMNESS_BANDS: dict[str, tuple[float | None, float | None]] = {
    "light": (None, LIGHT_PRESSURE),
    "steady": (LIGHT_PRESSURE, FIRM_PRESSURE),
    "firm": (FIRM_PRESSURE, None),
}


def _and(words: list[str]) -> str:
    return words[0] if len(words) == 1 else ", ".join(words[:-1]) + " and " + words[-1]


def pressure(facets: dict[str, Any], taxels: int | None = None) -> float | None:
    """``force`` over the sensor's taxel count (the facets' ``taxels``, else ``taxels``): the
    mean calibrated reading, in [0, 1] whatever the sensor's size (each profile calibrates its
    own span to [0, 1]); None when the taxel count is not known."""
    n = facets.get("taxels") or taxels
    force = facets.get("force")
    return None if not n or force is None else float(force) / float(n)


def firmness(press: float | None) -> str:
    """The firmness word of a :func:`pressure`: light, steady or firm (None: steady)."""
    if press is None:
        return "steady"
    return "light" if press < LIGHT_PRESSURE else "firm" if press >= FIRM_PRESSURE else "steady"


def motion(facets: dict[str, Any]) -> str | None:
    """A grasp's motion (None for a window, which has no ``duration``): ``slipping`` when its
    ``slip`` >= :data:`SLIP_SPEED`, else ``brief`` under :data:`BRIEF_S`, ``long`` from
    :data:`LONG_HOLD_S`, ``held`` between."""
    if facets.get("duration") is None:
        return None
    if float(facets.get("slip") or 0.0) >= SLIP_SPEED:
        return "slipping"
    d = float(facets["duration"])
    return "brief" if d < BRIEF_S else "long" if d >= LONG_HOLD_S else "held"


def caption_words(band: str, grip: str | None, active: list[str], move: str | None) -> str:
    """The caption of its parts (:func:`caption`). A window's (``move`` None): the firmness's
    words (:data:`FIRMNESS_WORDS`), then the firmness ``band``, ``grip`` and the ``active``
    regions most loaded first, e.g. "squeezing hard, a firm pinch with thumb and index". A
    grasp's (``move``, its :func:`motion`): the motion's words first, then the same without
    the regions (its windows' captions say them), e.g. "slipping, squeezing hard, a firm
    pinch"; a grasp merely held says no motion. What a question asks in words comes first
    because MiniLM weighs a short caption's first words: "a long steady hold" reached "a long
    steady hold, a steady power grasp" at cosine 0.77, "a steady power grasp with palm, middle
    and thumb, a long steady hold" at 0.54; "squeezing hard" reached "squeezing hard, a firm
    power grasp with palm, index, middle and ring" at 0.64, the same words in the other order
    at 0.57."""
    words = [f"a {band} {GRIP_WORDS.get(grip or '', 'touch')}"]
    if move is None and active:
        words[0] += " with " + _and(active)
    if band in FIRMNESS_WORDS:
        words.insert(0, FIRMNESS_WORDS[band])
    if move in MOTION_WORDS:
        words.insert(0, MOTION_WORDS[move])
    return ", ".join(words)


def grasp_captions() -> list[str]:
    """Every grasp caption there can be (each firmness band, grip and motion): few enough
    (72) to embed at once."""
    texts = {
        caption_words(band, grip, [], move)
        for band in FIRMNESS_BANDS
        for grip in (*GRIPS, None)
        for move in MOTIONS
    }
    return sorted(texts)


def caption(facets: dict[str, Any], taxels: int | None = None) -> str:
    """A window's or a grasp's facets in words, deterministically (rule :data:`CAPTION_RULE`):
    the firmness of its :func:`pressure` (light / steady / firm; ``taxels`` where the facets
    do not say it) and its words (:data:`FIRMNESS_WORDS`), the grip, the active regions most
    loaded first and, for a grasp, its motion's words (:data:`MOTION_WORDS`), e.g. "squeezing
    hard, a firm pinch with thumb and index" (a window), "slipping, squeezing hard, a firm
    pinch" (a grasp; :func:`caption_words` says the order). A window's caption is a function
    of its pressure band, grip and active regions; a grasp's of its band, grip and motion
    (what :mod:`tactus_memory.search.captions` keys on)."""
    band = firmness(pressure(facets, taxels))
    active = active_regions(facets.get("regions") or {})
    return caption_words(band, facets.get("grip"), active, motion(facets))
