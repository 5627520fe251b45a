"""Whether a fixation's two eyes' matches can both be right (beyond the paper; default profile
only): each eye's patch is found on its own (II-B), so on repetitive texture each can land on
a different repeat, which eq. 5 does not see."""
from __future__ import annotations

import numpy as np

from calib_free.correspondence.disparity import DISPARITY_BAND_PX, as_grey_float, horizontal_offset
from calib_free.correspondence.search import CorrespondenceParams, FixationMatch


def stereo_inconsistency(match: FixationMatch, pre_left: np.ndarray, pre_right: np.ndarray,
                         params: CorrespondenceParams, row_offset_px: float = 0.0) -> str:
    """Why the left and right matches of a fixation cannot both be right ('' if they agree).

    Each eye's patch is found on its own (II-B), so on repetitive texture each can land on a
    different repeat. Two checks the geometry allows without calibration: the rows agree
    within `max_vertical_disparity_px` (the paper's lens: 3.5 px at most, II-A footnote), and
    the pre-fixation pair's own disparity at (x*, y*) equals d* within `stereo_tolerance_px`.
    `row_offset_px`: how far the right camera's rows lie below the left's (their vertical
    misalignment, measured at the foveae), where the pre-fixation pair's disparity is looked
    for. The rows of the two matches agree whatever it is: each eye's fovea content is found
    in that eye's own earlier image.
    """
    left, right = match.left, match.right
    # Away from the foveae the cameras' rows differ by more than at them where their rolls and
    # focal lengths differ: a few rows either side of the misalignment are searched.
    band_px = DISPARITY_BAND_PX if row_offset_px else 0
    vertical = abs(left.y - right.y)
    if vertical > params.max_vertical_disparity_px:
        return f"left and right rows differ by {vertical:.1f} px > {params.max_vertical_disparity_px} px"
    d_star = right.x - left.x
    margin = 3 * params.stereo_tolerance_px + 2
    d_pre, score = horizontal_offset(as_grey_float(pre_left), as_grey_float(pre_right), (left.x, left.y),
                                     params.patch_size, (d_star - margin, d_star + margin),
                                     band_px=band_px, row_offset_px=row_offset_px)
    if score < params.min_correlation or abs(d_pre - d_star) > params.stereo_tolerance_px:
        return (f"the pre-fixation pair's disparity at (x*, y*) is {d_pre:.1f} px (NCC {score:.2f}), "
                f"d* = {d_star:.1f} px")
    search_px = pre_left.shape[1] / 3.0
    rival = row_repeat_ncc(as_grey_float(pre_left), as_grey_float(pre_right), (left.x, left.y), params.patch_size,
                           d_pre, score, search_px, params.stereo_rival_margin, row_offset_px, band_px)
    if rival is not None:
        return (f"the patch at (x*, y*) repeats along its rows in the right image (NCC {rival:.2f} against "
                f"{score:.2f} at d* = {d_star:.1f} px): the eyes may have verged on different repeats")
    return ""


def row_repeat_ncc(left: np.ndarray, right: np.ndarray, xy: tuple[float, float], patch_size: tuple[int, int],
                   d: float, ncc: float, search_px: float, margin: float, row_offset_px: float = 0.0,
                   band_px: int = 0) -> float | None:
    """The NCC of a repeat of the left patch at `xy` along the same rows of `right` that scores
    within `margin` of `ncc`, its match at `d` (`_row_rival_ncc`): on such a texture d may be a
    repeat's. None where no place along the rows comes that near."""
    rival = _row_rival_ncc(left, right, xy, patch_size, d, search_px, row_offset_px, band_px)
    return rival if rival > ncc - margin else None


def _row_rival_ncc(left: np.ndarray, right: np.ndarray, xy: tuple[float, float], patch_size: tuple[int, int],
                   d: float, search_px: float, row_offset_px: float = 0.0, band_px: int = 0) -> float:
    """NCC of the best placement of the left patch at `xy` along the same rows of `right`
    (`row_offset_px` below, and `band_px` rows either side), within +-`search_px` of disparity
    and more than half a patch from `d`: how well a repeat of it matches (-1 when nothing is
    searched)."""
    exclude = patch_size[0] / 2.0
    best = -1.0
    for side in ((-search_px, d - exclude), (d + exclude, search_px)):
        if side[1] - side[0] > patch_size[0]:
            best = max(best, horizontal_offset(left, right, xy, patch_size, side, band_px, row_offset_px)[1])
    return best
