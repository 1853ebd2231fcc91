"""``TactusEncoder``: the touch sense. Grasp windows of 32x32 pressure frames -> text space.

    from tactus_memory.adapters.touch import TactusEncoder
    memory.add_sense(TactusEncoder())            # the shipped default, no network
    memory.add("s1", "touch", window, t=12.5)    # window: (K, 32, 32) raw or calibrated
    memory.search("holding a screwdriver", senses=["touch"])

Input rules (``validate``), in this order:

1. shape ``(K, 32, 32)`` with 1 <= K <= the model's K (8 for the shipped model); a shorter
   window is padded by repeating its last frame, a longer one is rejected (pass the K most
   informative frames yourself);
2. numeric, finite (no NaN/inf);
3. ``calibrated=None`` (auto): integer arrays are raw sensor readings; float arrays whose
   values all lie in [0, 1] are calibrated; other float arrays are raw;
   ``calibrated=True``: values must lie in [0, 1];
   ``calibrated=False`` (raw): values already in [0, 1] raise ``DynamicRangeError`` (the
   max-scaling defect of the paper: raw readings sit around 500-1000), and so does a window
   with no reading above the sensor offset;
4. raw windows are calibrated with the checkpoint's sensor profile,
   ``clip((raw - 500) / 150, 0, 1)`` for the STAG glove;
5. an idle window (no frame with contact, ``touch.windows.window_idle`` on the calibrated
   window) raises ``IdleWindowError``: an idle hand is never stored as a grasp, whether it
   came over HTTP, the WebSocket stream, a recording or Python (``keep_idle=True`` keeps it).

Vectors live in the checkpoint's space (``space_name``/``dim``), so ``Memory.add_sense``
rejects a memory built on another space. Text queries compared with touch vectors go through
``Sense.query_transform`` = normalize(q - ``query_centroid``), the centring the training
targets had.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from tactus_memory import __version__
from tactus_memory.adapters.decode import ARRAYS, IMAGE, touch_frame
from tactus_memory.adapters.touch_drawing import TouchDrawer
from tactus_memory.errors import (
    DynamicRangeError,
    IdleWindowError,
    InvalidInputError,
    SenseConflictError,
)
from tactus_memory.names import validate_sense_name
from tactus_memory.senses.base import array_to_bytes
from tactus_memory.senses.plugins import register
from tactus_memory.senses.windowed import WindowedSense, WindowLayout
from tactus_memory.spaces.base import Space
from tactus_memory.touch.checkpoint import default_checkpoint_path
from tactus_memory.touch.profile import FRAME_SHAPE
from tactus_memory.touch.render import MAX_FRAMES, SCALE
from tactus_memory.touch.windows import (
    CONTACT_LEVEL,
    CONTACT_MIN_TAXELS,
    WindowStream,
    contact_level,
    window_idle,
)
from tactus_memory.vectors import as_unit_rows


def _idle_error(level: float = CONTACT_LEVEL) -> IdleWindowError:
    return IdleWindowError(
        f"idle touch window: no frame has {CONTACT_MIN_TAXELS} taxels at the contact "
        f"level ({level:.3g} calibrated); an idle hand is never stored as a grasp"
    )


class CalibratedWindow(np.ndarray):
    """A window the touch sense has validated: (K, 32, 32) float32, calibrated to [0, 1].
    ``validate`` returns one and takes one back as it is; ``embed`` trusts it.

    Arithmetic on it (``w * 1000``, ``w - bg``) gives a plain ndarray, which is validated
    again: only the window ``validate`` returned (and views of it) is trusted."""

    def __array_wrap__(self, arr: np.ndarray, context: Any = None, return_scalar: bool = False):
        out = np.asarray(arr).view(np.ndarray)
        return out[()] if return_scalar else out


@register("touch")
class TactusEncoder(WindowedSense):
    """Touch sense backed by a Tactus checkpoint (CPU by default, ``torch.inference_mode``; on
    ONNX Runtime with ``onnx``, or by default where torch is not installed)."""

    modality = "touch"
    validate_options = frozenset({"calibrated", "keep_idle"})
    message_types = (IMAGE, *ARRAYS)
    #: the frame of the shipped checkpoint (the STAG glove's 32x32): what the HTTP API's
    #: JSON schema states for a touch window
    default_frame_shape: ClassVar[tuple[int, ...]] = FRAME_SHAPE
    draw_defaults: ClassVar[WindowLayout] = WindowLayout(scale=SCALE, max_frames=MAX_FRAMES)

    def __init__(
        self,
        checkpoint: str | os.PathLike[str] | None = None,
        *,
        name: str = "touch",
        device: str = "cpu",
        batch_size: int = 64,
        onnx: str | os.PathLike[str] | None = None,
    ) -> None:
        from tactus_memory.touch.checkpoint import load_checkpoint
        from tactus_memory.touch.profile import SensorProfile

        self.name = validate_sense_name(name)
        if onnx is None:
            from tactus_memory.spaces.onnx_runtime import default_onnx_folder, has_torch

            if not has_torch():  # served without the train extra: ONNX Runtime
                onnx = default_onnx_folder(checkpoint)
        path = Path(checkpoint) if checkpoint is not None else default_checkpoint_path()
        self.ckpt = load_checkpoint(path, device=device, weights=onnx is None)
        #: the torch model, or (``onnx``: a folder of tactus_memory.export.onnx) the ONNX
        #: Runtime session of this checkpoint's export; torch is then never imported
        self.model: Any = self.ckpt.model
        self.onnx = onnx is not None
        if onnx is not None:
            from tactus_memory.spaces.onnx_runtime import OnnxTouch

            self.model = OnnxTouch(onnx, checkpoint_sha256=self.ckpt.sha256)
        self.device = device
        self.batch_size = int(batch_size)
        self.dim = self.ckpt.dim
        self.space_name = self.ckpt.space_name
        self.frames = int(self.ckpt.meta["model"]["frames"])
        self.profile = SensorProfile.from_dict(self.ckpt.meta["calibration"])
        self.classes = self.ckpt.classes
        self.phrases = list(self.ckpt.targets.phrases)
        #: (D,) removed from text queries; Memory stores it with the sense registration
        self.query_centroid = self.ckpt.targets.centroid.astype(np.float32)
        self._targets = self.ckpt.targets.centred.astype(np.float32)  # (C, D) unit rows

    def class_targets(self) -> tuple[list[str], np.ndarray]:
        """The trained classes and their (C, D) raw template-averaged phrase embeddings: the
        search targets a text query is matched to (:mod:`tactus_memory.search.teaching`)."""
        return list(self.classes), np.asarray(self.ckpt.targets.raw, np.float32)

    def target_phrases(self, label: str) -> list[str]:
        """The phrases of a taught label: the training templates filled with it, as a class's
        target is built (:func:`tactus_memory.touch.targets.class_phrases`)."""
        from tactus_memory.touch.targets import class_phrases

        return class_phrases(label)

    def bind(self, space: Space) -> None:
        """Refuse a memory of another space: name and dim (``Sense.bind``), then the model
        fingerprint when both the checkpoint and the space record one."""
        super().bind(space)
        want = self.ckpt.meta["space"].get("fingerprint")
        have = space.fingerprint()
        if want and have and want != have:
            raise SenseConflictError(
                f"sense {self.name!r} was trained in space {self.space_name!r} (dim {self.dim}) "
                f"of the model fingerprinted {want}, but this memory's {space.name!r} "
                f"(dim {space.dim}) model is fingerprinted {have}"
            )

    def warm(self, space: Space) -> None:
        """The grasp captions' embeddings in ``space``, which a touch write and a grasp search
        use (:mod:`tactus_memory.touch.caption_vectors`): 72 texts, once per process and space
        (a first write that paid them overran a 5-s client timeout in CI)."""
        from tactus_memory.touch.caption_vectors import grasp_caption_vectors

        grasp_caption_vectors(space)

    @classmethod
    def from_pretrained(cls, path: str | os.PathLike[str], **kw: Any) -> TactusEncoder:
        return cls(path, **kw)

    @staticmethod
    def shipped_sha256() -> str:
        """The sha256 of the checkpoint this install ships (the default one)."""
        from tactus_memory.hashing import file_sha256

        return file_sha256(default_checkpoint_path())

    @classmethod
    def create(cls, space: Space, /, **config: Any) -> TactusEncoder:
        return cls(config.pop("checkpoint", None), **config)

    def config(self) -> dict[str, Any]:
        """The checkpoint's path (None: the shipped one, wherever this install keeps it)."""
        shipped = self.ckpt.path.resolve() == default_checkpoint_path().resolve()
        return {"name": self.name, "checkpoint": None if shipped else str(self.ckpt.path.resolve())}

    # -- input ------------------------------------------------------------------------------

    def from_message(self, msg: Any, msgtype: str, where: str) -> np.ndarray:
        """One recorded touch message -> one (32, 32) frame (``recordings.decode``)."""
        return touch_frame(msg, msgtype, self.profile.shape, where)

    @property
    def frame_shape(self) -> tuple[int, ...]:
        """(H, W) of one frame: the checkpoint's sensor profile's."""
        return tuple(self.profile.shape)

    def window_stream(self, window: int, stride: int) -> WindowStream:
        """Raw frames (n, H, W) -> raw windows (K, H, W); no profile: :meth:`validate`
        calibrates each window and judges it idle."""
        return WindowStream(window, stride, profile=None)

    def drawer(self) -> TouchDrawer:
        """Heat maps with this checkpoint's sensor profile."""
        return TouchDrawer(self.profile)

    @classmethod
    def drawer_from_provenance(cls, provenance: dict[str, Any]) -> TouchDrawer:
        """Heat maps with the sensor profile the store recorded (the glove's when none)."""
        return TouchDrawer.from_provenance(provenance)

    def is_idle(self, window: np.ndarray) -> bool:
        """A calibrated window (K, H, W) with no frame in contact
        (:func:`~tactus_memory.touch.windows.window_idle`)."""
        return window_idle(window)

    def validate(
        self, item: Any, *, calibrated: bool | None = None, keep_idle: bool = False
    ) -> np.ndarray:
        """One window (K, 32, 32), raw or calibrated -> calibrated float32 (K, 32, 32).

        ``calibrated`` None guesses (float values in [0, 1] are calibrated); a window this
        method returned (a :class:`CalibratedWindow`) comes back as it is unless it is
        passed as raw (``calibrated=False``, an error). An idle window raises
        :class:`~tactus_memory.errors.IdleWindowError` unless ``keep_idle``."""
        if isinstance(item, CalibratedWindow) and calibrated is not False:
            return item
        window = self._calibrated(item, calibrated)
        level = contact_level(self.profile)
        if not keep_idle and window_idle(window, level):
            raise _idle_error(level)
        return window

    def validate_many(
        self,
        items: Sequence[Any] | np.ndarray,
        *,
        skip_idle: bool = True,
        **options: Any,
    ) -> tuple[list[np.ndarray], list[int]]:
        """B windows -> (the calibrated windows kept, the indices skipped as idle), as
        :meth:`validate` window by window gives them; a (B, K, 32, 32) array (an ``.npy`` body,
        a JSON batch) is checked, calibrated and tested for contact in ONE numpy pass (the
        shape once for the batch). The first window that fails raises what :meth:`validate`
        raises for it. ``options``: :meth:`validate`'s (``calibrated``, ``keep_idle``), passed
        on as given when it checks window by window."""
        calibrated: bool | None = options.get("calibrated")
        keep_idle = bool(options.get("keep_idle", False))
        opts = {"skip_idle": skip_idle, **options}
        arr = items if isinstance(items, np.ndarray) else None
        if (
            arr is None
            or arr.ndim != 4
            or arr.dtype.kind not in "iuf"
            or arr.shape[0] == 0
            or arr.shape[2:] != tuple(self.profile.shape)
            or not 1 <= arr.shape[1] <= self.frames
        ):  # not one (B, K, 32, 32) numeric array: window by window, each error as it comes
            return super().validate_many(items, **opts)
        lo, hi = arr.min(axis=(1, 2, 3)), arr.max(axis=(1, 2, 3))  # (B,) each
        is_float = arr.dtype.kind == "f"
        if calibrated is None:
            cal = is_float & (lo >= 0) & (hi <= 1)
        else:
            cal = np.full(arr.shape[0], bool(calibrated))
        unit = (lo >= 0) & (hi <= 1)
        bad = np.where(cal, ~unit, unit | (hi <= self.profile.offset))
        if is_float:
            bad |= ~np.isfinite(arr).all(axis=(1, 2, 3))
        if bad.any():  # a window fails: window by window, so the error is validate's own
            return super().validate_many(items, **opts)
        out = np.ascontiguousarray(arr, dtype=np.float32)
        if not cal.all():
            out = out.copy() if out is arr else out
            out[~cal] = self.profile.scale(arr[~cal])
        level = contact_level(self.profile)
        peak = (out >= np.float32(level)).sum(axis=(2, 3)).max(axis=1)  # (B,)
        idle = np.zeros(arr.shape[0], bool) if keep_idle else peak < CONTACT_MIN_TAXELS
        if idle.any() and not skip_idle:
            raise _idle_error(level)
        return [out[i].view(CalibratedWindow) for i in np.flatnonzero(~idle)], [
            int(i) for i in np.flatnonzero(idle)
        ]

    def _calibrated(self, item: Any, calibrated: bool | None) -> np.ndarray:
        """The checks of :meth:`validate` but the idle rule, and the one calibration."""
        try:
            arr = np.asarray(item)
        except (ValueError, TypeError) as exc:
            raise InvalidInputError(f"touch window is not an array: {exc}") from exc
        if arr.dtype == object or not (
            np.issubdtype(arr.dtype, np.integer)
            or np.issubdtype(arr.dtype, np.floating)
            or arr.dtype == bool
        ):
            raise InvalidInputError(f"touch window must be numeric, got dtype {arr.dtype}")
        h, w = self.profile.shape
        if arr.ndim != 3 or arr.shape[1:] != (h, w):
            raise InvalidInputError(
                f"touch window must have shape (K, {h}, {w}), got {arr.shape}: sense "
                f"{self.name!r} reads {h}x{w} frames (sensor {self.profile.name!r})"
            )
        k = arr.shape[0]
        if not 1 <= k <= self.frames:
            raise InvalidInputError(
                f"touch window has {k} frames; this model fuses 1..{self.frames} "
                f"(pass at most {self.frames} frames, e.g. window[:{self.frames}])"
            )
        if arr.dtype == bool:
            raise InvalidInputError("touch window must be pressure values, got a bool mask")
        if arr.dtype.kind == "f" and not np.isfinite(arr).all():  # integers are finite
            raise InvalidInputError("touch window contains NaN or inf")
        lo, hi = float(arr.min()), float(arr.max())
        is_float = np.issubdtype(arr.dtype, np.floating)
        if calibrated is None:
            calibrated = is_float and lo >= 0.0 and hi <= 1.0
        if calibrated:
            if lo < 0.0 or hi > 1.0:
                raise InvalidInputError(
                    f"calibrated touch window must lie in [0, 1], got {lo:.4g}..{hi:.4g}"
                )
            return np.ascontiguousarray(arr, dtype=np.float32).view(CalibratedWindow)
        if lo >= 0.0 and hi <= 1.0:
            raise DynamicRangeError(
                f"window passed as raw but its values lie in [0, 1] (max {hi:.4g}): it looks "
                "already normalised; pass calibrated=True, or the raw sensor readings "
                f"(the {self.profile.name} sensor reads ~{self.profile.offset:g}-1000 raw)"
            )
        if hi <= self.profile.offset:
            raise DynamicRangeError(
                f"no raw reading above the sensor offset {self.profile.offset:g} (max {hi:.4g}): "
                f"this is not raw {self.profile.name} data"
            )
        # the affine alone: shape, dtype and finiteness were checked above (not twice)
        return np.ascontiguousarray(self.profile.scale(arr), np.float32).view(CalibratedWindow)

    def _pad(self, w: np.ndarray) -> np.ndarray:
        if w.shape[0] == self.frames:
            return w
        rep = np.repeat(w[-1:], self.frames - w.shape[0], axis=0)
        return np.concatenate([w, rep], axis=0)

    def _windows(self, batch: Any, calibrated: bool | None) -> np.ndarray:
        if isinstance(batch, np.ndarray) and batch.ndim == 4:
            items: Sequence[Any] = list(batch)
        elif isinstance(batch, np.ndarray) and batch.ndim == 3:
            items = [batch]
        else:
            items = list(batch)
        if not items:
            return np.zeros((0, self.frames, *self.profile.shape), np.float32)
        # validated windows (what Memory passes) are trusted; raw ones are validated here
        trusted = calibrated is not False
        checked = [  # embedding any window is allowed (the evaluation embeds idle ones too)
            w
            if trusted and isinstance(w, CalibratedWindow)
            else self.validate(w, calibrated=calibrated, keep_idle=True)
            for w in items
        ]
        return np.stack([np.asarray(self._pad(w)) for w in checked])

    # -- output -----------------------------------------------------------------------------

    def embed(
        self, batch: Sequence[Any] | np.ndarray, *, calibrated: bool | None = None
    ) -> np.ndarray:
        """N windows ((B, K, 32, 32) array or a list of (K, 32, 32)) -> (N, D) float32 unit rows."""
        wins = self._windows(batch, calibrated)
        if self.onnx:
            return self.model.embed(wins)
        import torch

        from tactus_memory.touch.model import batched_forward

        with torch.inference_mode():
            z = batched_forward(self.model, wins, self.batch_size, self.device, self.dim)
        return as_unit_rows(z, self.dim, what="touch embedding")

    def classify(
        self, windows: Any, k: int = 3, *, calibrated: bool | None = None, scores: bool = False
    ) -> list[Any]:
        """Rank the checkpoint's classes for each window (cosine to the centred targets).

        One window (K, 32, 32) -> a list of k class names; a batch -> a list of such lists.
        ``scores=True`` gives (name, cosine) pairs instead of names.
        """
        single = isinstance(windows, np.ndarray) and windows.ndim == 3
        z = self.embed(windows, calibrated=calibrated)
        sim = z @ self._targets.T
        order = np.argsort(-sim, axis=1)[:, :k]
        out = [
            [(self.classes[j], float(sim[i, j])) if scores else self.classes[j] for j in row]
            for i, row in enumerate(order)
        ]
        return out[0] if single else out

    def to_row(self, item: np.ndarray) -> dict[str, Any]:
        """Store the calibrated window (float16 .npy bytes; 1/150 raw steps survive float16)
        and its facets (:mod:`tactus_memory.touch.facets`, from the float32 window)."""
        from tactus_memory.touch.facets import facet_columns, window_facets

        window = np.asarray(item, dtype=np.float32)
        return {
            "raw": array_to_bytes(window.astype(np.float16)),
            **facet_columns(window_facets(window[None], self.profile).row(0)),
        }

    def from_row(self, row: dict[str, Any]) -> Any:
        arr = super().from_row(row)
        return None if arr is None else np.asarray(arr, dtype=np.float32)

    def calibration_prior(self) -> dict[str, float] | None:
        """The prior score calibration (``{"mu", "sigma"}``) shipped for this checkpoint; None
        when none is shipped for its sha256
        (:func:`tactus_memory.touch.checkpoint.calibration_prior`)."""
        from tactus_memory.touch.checkpoint import calibration_prior

        return calibration_prior(self.ckpt.sha256)

    def match_precision(self) -> dict[str, Any] | None:
        """How often this checkpoint's match is right, as measured on held-out recordings
        (``GET /senses``' ``precision_at_bar``); None when none was measured for it."""
        from tactus_memory.touch.checkpoint import match_precision

        return match_precision(self.ckpt.sha256)

    def provenance(self) -> dict[str, Any]:
        m = self.ckpt.meta
        return {
            "encoder": "tactus",
            "version": __version__,
            "model": m["model"]["name"],
            "checkpoint": self.ckpt.path.name,
            "checkpoint_sha256": self.ckpt.sha256,
            "space": m["space"],
            "calibration": self.profile.to_dict(),
            "classes": list(self.classes),
            "frames": self.frames,
            "steps": m.get("steps"),
        }
