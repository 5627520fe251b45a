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
its `MEMORY` most recent scales.
"""
from __future__ import annotations

import collections
import threading

import numpy as np

BIN_PX = 10.0
NEIGHBOURHOOD_PX = 10.0  # the scales of targets this near in distance from the centre are pooled
MIN_SAMPLES = 5
MEMORY = 20
SCALE_FACTOR = 1.3  # the scales tried lie within this factor of the learned one


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

    def record(self, distance_px: float, scale: float) -> None:
        """A look ended on target; its first sighting found the patch of a target `distance_px`
        from the image centre stretched `scale` times along the radius."""
        if not (np.isfinite(distance_px) and np.isfinite(scale) and scale > 0):
            return
        with self._lock:
            self._bins[int(distance_px // BIN_PX)].append(float(scale))

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
