"""A look's second attempt, at the depth its first one found.

A look plans its saccade with the target's d, measured before the head moved or, where it
could not be, the depth the eyes fixate (d = 0). Where that d was not the target's (a repeat
along the rows matched, or none could), fine vergence after the saccade finds the depth the
eyes converge at, and the vergence it changes turns the left eye by half of it: a few degrees
leave the target tens of pixels off the left fovea, among the repeats of a textured floor,
where a search cannot tell it from them. A look that fails so has learned the depth near its
target. It returns to the view it chose the target in, finds the target's pixel again there
(the servos' play leaves the view a pixel or two off the one it left; `target_in_restored_view`)
and tries once more, with the d the map gives that vergence at the target
(`disparity_for_vergence`): the saccade then verges the eyes where fine vergence will leave
them, and the left eye stays on the target.
"""
from __future__ import annotations

import cv2
import numpy as np

from calib_free.correspondence.disparity import subpixel_peak
from calib_free.errors import OutOfRangeError
from calib_free.gaze.fixation import FixationRecord, MapReader

# A first fixation whose eyes converged at least this far (deg) from the vergence its saccade
# planned went there with another depth than the target's: the left eye turned by about half
# of it, 2 px a degree at the fovea, beyond what a look's first search expects of a saccade.
RETRY_VERGENCE_DEG = 1.0
# The disparities (px) the map is asked about to find the one that verges the eyes as wanted.
DISPARITY_SCAN_PX = np.arange(-100.0, 100.5, 1.0)
# The target's patch looked for this far (px) about its pixel in the restored view, and taken
# only where it matches at least this well: the same view, a play's pixel or two off.
RESTORED_VIEW_REACH_PX = 4
RESTORED_VIEW_MIN_NCC = 0.8


def depth_found_elsewhere(first: FixationRecord, vergence_low: float, vergence_high: float) -> float | None:
    """The vergence (deg) `first`, a look's first fixation, converged at, where it lies at least
    `RETRY_VERGENCE_DEG` from the one its saccade planned (clamped to [`vergence_low`,
    `vergence_high`], as the head clamps it); None where the eyes did not converge, the poses
    were not read or the depth was the planned one."""
    if not first.converged or first.pose_before is None or first.pose_after is None or first.planned is None:
        return None
    planned = float(np.clip(first.pose_before[2] + first.planned[2], vergence_low, vergence_high))
    converged = float(first.pose_after[2])
    return converged if abs(converged - planned) >= RETRY_VERGENCE_DEG else None


def disparity_for_vergence(gaze_map: MapReader, pose: np.ndarray, xy: tuple[float, float],
                           vergence_deg: float) -> float | None:
    """The d whose map command for (x, y, d), seen at `pose`, ends at `vergence_deg`: linear
    between the two disparities of `DISPARITY_SCAN_PX` that bracket it; None where no d the map
    covers does."""
    ds, ends = [], []
    for d in DISPARITY_SCAN_PX:
        try:
            ends.append(float(pose[2] + gaze_map.command((xy[0], xy[1], float(d)), pose=pose)[2]))
        except OutOfRangeError:
            continue
        ds.append(float(d))
    for i in range(len(ds) - 1):
        if ds[i + 1] - ds[i] > 1.5:  # not neighbours: the map skipped the disparities between
            continue
        low, high = ends[i] - vergence_deg, ends[i + 1] - vergence_deg
        if low == 0.0:
            return ds[i]
        if low * high < 0.0:
            return ds[i] + (ds[i + 1] - ds[i]) * low / (low - high)
    return ds[-1] if ds and ends[-1] == vergence_deg else None


def target_in_restored_view(source: np.ndarray, source_xy: tuple[float, float], image: np.ndarray,
                            patch_size: tuple[int, int]) -> tuple[float, float] | None:
    """Where the patch of `patch_size` (w, h) about `source_xy` in `source` lies in `image`, the
    same view restored, searched within `RESTORED_VIEW_REACH_PX` (to a tenth of a pixel, by
    the parabola through the scores about the best); None where the patch or its neighbourhood
    reaches beyond either image or matches below `RESTORED_VIEW_MIN_NCC`."""
    w, h = patch_size
    r = RESTORED_VIEW_REACH_PX
    tx0, ty0 = int(round(source_xy[0] - (w - 1) / 2.0)), int(round(source_xy[1] - (h - 1) / 2.0))
    x0, y0 = tx0 - r, ty0 - r
    if x0 < 0 or y0 < 0 or x0 + w + 2 * r > min(source.shape[1], image.shape[1]) \
            or y0 + h + 2 * r > min(source.shape[0], image.shape[0]):
        return None
    template = source[ty0:ty0 + h, tx0:tx0 + w].astype(np.float32)
    window = image[y0:y0 + h + 2 * r, x0:x0 + w + 2 * r].astype(np.float32)
    scores = np.nan_to_num(cv2.matchTemplate(window, template, cv2.TM_CCOEFF_NORMED), nan=-1.0)
    iy, ix = np.unravel_index(int(np.argmax(scores)), scores.shape)
    if scores[iy, ix] < RESTORED_VIEW_MIN_NCC:
        return None
    u, v = subpixel_peak(scores, int(iy), int(ix))
    # The template's top-left sat at (tx0, ty0) about source_xy; the best place moved it by (u - r, v - r).
    return source_xy[0] + u - r, source_xy[1] + v - r


def why_again(first: FixationRecord, d: float, ended: object) -> str:
    """What a look's detail says of its second attempt: the `d` it went with, where the first
    attempt's first fixation (`first`) converged against the vergence its saccade planned, and how
    the first attempt `ended`."""
    if first.pose_before is None or first.planned is None or first.pose_after is None:
        return f"second attempt, with d {d:.1f} px; the first ended {ended}"
    return (f"second attempt, with d {d:.1f} px: the first's eyes converged at {first.pose_after[2]:.1f} deg, "
            f"not the {first.pose_before[2] + first.planned[2]:.1f} it planned, and it ended {ended}")
