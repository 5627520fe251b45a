"""The lens's magnification of a patch brought to the fovea, as the looks find it.

A fish-eye lens shows a patch at the fovea larger along the radius from the image centre than
where it was seen before the saccade, by how much depending on how far from the centre it was.
The target search tries radial scales from 0.85 up to `LookParams.max_target_scale`
(`calib_free.gaze.refind.candidate_warps`), so a look-alike that the patch resembles only when
stretched far beyond what the lens does can outscore the target itself: in the realistic
world's looks, a 41 x 41 patch from 75 px off the centre matched a place 14.6 px from the fovea
at NCC 0.97 stretched 2.12 times, where the target, 0.7 px from the fovea, matched at 0.90
stretched 1.02 times, the scale every other target from that far off was found with
(docs/results/realistic-world.md).

Each look that ends on target tells the radial scale its first sighting found at the target's
distance from the centre (`record`). Once `MIN_SAMPLES` such looks lie within
`NEIGHBOURHOOD_PX` of a target's distance, its first search tries only the grid's scales within
`SCALE_FACTOR` of their median (`radial_scales`), and every scale only where those find
nothing (a lens that changed, or one the looks have not learned there yet). No calibration: the
profile is learned as the looks go, as the map is, and forgets: each `BIN_PX` of distance keeps
its `MEMORY` most recent scales. The service keeps the profile in its state directory
(`as_dict`, `from_dict`), so that a restarted daemon's first looks search as narrowly as the
last ones did.
"""
from __future__ import annotations

import collections
import math
import threading
from typing import Any

import numpy as np

from calib_free.errors import CalibFreeError

BIN_PX = 10.0
NEIGHBOURHOOD_PX = 10.0  # the scales of targets this near in distance from the centre are pooled
MIN_SAMPLES = 5
MEMORY = 20
SCALE_FACTOR = 1.3  # the scales tried lie within this factor of the learned one
FORMAT = 1  # `as_dict`'s layout


class MagnificationFileError(CalibFreeError):
    """A saved profile that cannot be read back (`LearnedMagnification.from_dict`): what is wrong, where."""


def radial_scale(warp: np.ndarray, source_xy: tuple[float, float], centre: tuple[float, float]) -> float:
    """How much `warp` (2 x 2) stretches the direction from `centre` to `source_xy`; its largest
    stretch where the point is the centre (no direction)."""
    radial = np.asarray(source_xy, dtype=float) - np.asarray(centre, dtype=float)
    norm = float(np.hypot(*radial))
    if norm <= 1.0:
        return float(np.linalg.svd(warp, compute_uv=False)[0])
    return float(np.hypot(*(np.asarray(warp, dtype=float) @ (radial / norm))))


class LearnedMagnification:
    """The radial scale of the targets' first sightings by their distance from the image centre
    (see the module doc). Thread-safe: looks record from the fixation thread, a status reader may
    ask from another."""

    def __init__(self) -> None:
        self._bins: dict[int, collections.deque[float]] = collections.defaultdict(
            lambda: collections.deque(maxlen=MEMORY))
        self._lock = threading.Lock()
        self._revision = 0

    @property
    def revision(self) -> int:
        """How many scales were recorded since it was made: it changed when this did."""
        with self._lock:
            return self._revision

    def record(self, distance_px: float, scale: float) -> None:
        """A look ended on target; its first sighting found the patch of a target `distance_px`
        from the image centre stretched `scale` times along the radius."""
        if not (np.isfinite(distance_px) and np.isfinite(scale) and scale > 0 and distance_px >= 0):
            return
        with self._lock:
            self._bins[int(distance_px // BIN_PX)].append(float(scale))
            self._revision += 1

    def as_dict(self) -> dict[str, Any]:
        """The profile, JSON-ready: each bin's scales, oldest first, by the bin's first pixel."""
        with self._lock:
            bins = {f"{k * BIN_PX:g}": list(v) for k, v in sorted(self._bins.items()) if v}
        return {"format": FORMAT, "bin_px": BIN_PX, "scales_by_distance_px": bins}

    @classmethod
    def from_dict(cls, data: Any, where: str) -> "LearnedMagnification":
        """The profile `as_dict` gave; MagnificationFileError naming `where` and what is wrong
        when `data` is not one (another layout, another bin width, a scale that is no positive
        number). A bin holding more than `MEMORY` scales keeps its newest."""
        if not isinstance(data, dict) or data.get("format") != FORMAT:
            found = data.get("format") if isinstance(data, dict) else type(data).__name__
            raise MagnificationFileError(f"{where}: not a lens magnification profile of format {FORMAT} (format {found!r})")
        if data.get("bin_px") != BIN_PX:
            raise MagnificationFileError(f"{where}: bin_px is {data.get('bin_px')!r}, expected {BIN_PX:g}")
        bins = data.get("scales_by_distance_px")
        if not isinstance(bins, dict):
            raise MagnificationFileError(f"{where}: scales_by_distance_px is not a mapping")
        out = cls()
        for key, scales in bins.items():
            try:
                start_px = float(key)
            except ValueError:
                raise MagnificationFileError(f"{where}: scales_by_distance_px: {key!r} is no distance in px") from None
            if not (math.isfinite(start_px) and start_px >= 0) or not isinstance(scales, list) or not all(
                    isinstance(s, (int, float)) and not isinstance(s, bool) and math.isfinite(s) and s > 0
                    for s in scales):
                raise MagnificationFileError(f"{where}: scales_by_distance_px.{key}: expected a distance >= 0 and "
                                             f"a list of positive scales, got {scales!r}")
            out._bins[int(start_px // BIN_PX)].extend(float(s) for s in scales)
        return out

    def expected(self, distance_px: float) -> float | None:
        """The median radial scale of the looks' first sightings of targets within
        `NEIGHBOURHOOD_PX` of `distance_px` from the centre; None where fewer than
        `MIN_SAMPLES` are known."""
        low, high = int((distance_px - NEIGHBOURHOOD_PX) // BIN_PX), int((distance_px + NEIGHBOURHOOD_PX) // BIN_PX)
        with self._lock:
            scales = [s for k in range(max(0, low), high + 1) for s in self._bins.get(k, ())]
        return float(np.median(scales)) if len(scales) >= MIN_SAMPLES else None

    def radial_scales(self, distance_px: float, grid: list[float]) -> list[float] | None:
        """The scales of `grid` within `SCALE_FACTOR` of the expected one at `distance_px`, and
        always the grid's nearest to it; None (every scale) where nothing is expected there."""
        expected = self.expected(distance_px)
        if expected is None:
            return None
        near = [s for s in grid if expected / SCALE_FACTOR <= s <= expected * SCALE_FACTOR]
        nearest = min(grid, key=lambda s: abs(np.log(s / expected)))
        return sorted(set(near) | {nearest})
