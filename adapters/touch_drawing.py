"""How the touch sense's windows are drawn: :class:`TouchDrawer`, the windowed-sense contract's
``WindowDrawer`` over :mod:`tactus_memory.touch.render` (magma heat maps of calibrated
pressure on the sensor's taxels, the renderer of the evaluation report too).

A live touch sense draws with its checkpoint's sensor profile (``TactusEncoder.drawer``); a
touch sense known only from the store with the profile its provenance recorded, the STAG
glove's when none (``TactusEncoder.drawer_from_provenance``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from tactus_memory.senses.windowed import WindowLayout
from tactus_memory.touch.profile import STAG_GLOVE, SensorProfile
from tactus_memory.touch.render import View, draw_window_png, window_values


@dataclass(frozen=True)
class TouchDrawer:
    """Draws (K, H, W) touch windows of ``profile``'s sensor (its shape, calibration, taxels)."""

    profile: SensorProfile = STAG_GLOVE

    @classmethod
    def from_provenance(cls, provenance: dict[str, Any]) -> TouchDrawer:
        """The drawer of a touch sense whose provenance records ``calibration`` (its sensor
        profile); the glove's when it records none."""
        recorded = provenance.get("calibration")
        if isinstance(recorded, dict):
            return cls(SensorProfile.from_dict(recorded))
        return cls()

    @property
    def frame_shape(self) -> tuple[int, ...]:
        return tuple(self.profile.shape)

    def _view(self, calibrated: bool | None, layout: WindowLayout) -> View:
        return View(**layout, calibrated=calibrated, profile=self.profile)

    def png(
        self, window: np.ndarray, *, calibrated: bool | None, legend: bool, layout: WindowLayout
    ) -> bytes:
        return draw_window_png(window, legend=legend, **self._view(calibrated, layout))

    def values(
        self, window: np.ndarray, *, calibrated: bool | None, layout: WindowLayout
    ) -> dict[str, Any]:
        return window_values(window, **self._view(calibrated, layout))
