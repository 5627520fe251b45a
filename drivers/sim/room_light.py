"""The simulated room's light as the cameras see it: its relative illumination over an exposure.

`Scene.light` is an `Illumination`; the simulated camera multiplies what it renders by
`light.mean_over(exposure_start_s, exposure_s)` before its sensor model. `CONSTANT_LIGHT`
is a room lit evenly and steadily (1.0 at every time).
"""
from __future__ import annotations

from typing import Protocol


class Illumination(Protocol):
    def mean_over(self, start_s: float, exposure_s: float) -> float:
        """The room's relative illumination (1.0 nominal) averaged over the exposure window."""


class ConstantLight:
    """Steady light at the nominal level."""

    def mean_over(self, start_s: float, exposure_s: float) -> float:
        return 1.0


CONSTANT_LIGHT: Illumination = ConstantLight()
