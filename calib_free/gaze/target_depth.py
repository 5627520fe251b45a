"""The disparity a look's target is looked at with, where the client sent none.

A client names a target by its pixel (x, y) in the left image. The look needs its d too: the
map's command for (x, y, d) verges the eyes at the target's depth. `target_disparity` measures
it in the pair the target was chosen in (`calib_free.correspondence.disparity.disparity_at`),
says where that measurement may be a repeat's, and falls back to the depth the eyes fixate
(d = 0) where nothing can be measured but the look can still find the target by its patch.
A target with no patch to find it by is refused here, before the head moves. At the look's
end, `vergence_on_a_repeat` says where the depth the eyes converged at may be a repeat's.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calib_free.correspondence.disparity import DISPARITY_BAND_PX, as_grey_float, disparity_at, horizontal_offset
from calib_free.correspondence.search import CorrespondenceParams
from calib_free.correspondence.stereo import row_repeat_ncc
from calib_free.errors import DisparityError, TargetPatchError
from calib_free.gaze.fixation import LookParams
from calib_free.gaze.target_patch import target_patch_problem


@dataclass(frozen=True)
class TargetDisparity:
    """The disparity a target sent without one is looked at with: measured (`ncc` its match's),
    or the fixation's own, 0, when it cannot be measured but the look can find the target by
    its patch. `reason`, when d may not be the target's: why it was not measured, or why the
    measured one may be a repeat's (the look then does not hold the eyes' final vergence
    against it)."""

    d: float
    ncc: float | None = None
    reason: str = ""

    @property
    def measured(self) -> bool:
        return self.ncc is not None


def target_disparity(left: np.ndarray, right: np.ndarray, x: float, y: float, patch_size: tuple[int, int],
                     disparity_range: tuple[float, float], look: LookParams,
                     band_px: int = DISPARITY_BAND_PX, row_offset_px: float = 0.0,
                     rival_margin: float = CorrespondenceParams.stereo_rival_margin) -> TargetDisparity:
    """The disparity to look at (x, y) of the left image with (`disparity_at`). Where it cannot
    be measured (seen by one eye only, a vertical disparity or depth edge the match does not
    survive, a patch too near the border for `patch_size`), d = 0 (`row_offset_px`: the
    pair's vertical misalignment, `FixationController.row_offset_px`): the look starts at the depth
    the eyes fixate, and fine vergence and the loop's corrective steps find the target's own.
    Where the patch matches another place along the same rows of the right image within
    `rival_margin` of NCC (`row_repeat_ncc`: a texture repeating along the rows), d is the best
    match's but may be a repeat's, and says so. TargetPatchError when the target has no patch
    for the closed loop to find it again by (`target_patch_problem`: flat, repetitive, reaching
    beyond the image): no look can end on it, whatever its d."""
    problem = target_patch_problem(as_grey_float(left), (x, y), look)
    try:
        d, ncc = disparity_at(left, right, x, y, patch_size, disparity_range, band_px, row_offset_px)
    except DisparityError as err:
        if problem:
            raise TargetPatchError(f"{err}, and the target cannot be looked at: {problem}") from None
        return TargetDisparity(0.0, None, f"{err}: looked at from the depth the eyes fixate (d = 0)")
    if problem:
        raise TargetPatchError(f"the target at ({x:g}, {y:g}) cannot be looked at: {problem}")
    search_px = max(abs(disparity_range[0]), abs(disparity_range[1]))
    rival = row_repeat_ncc(as_grey_float(left), as_grey_float(right), (x, y), patch_size, d, ncc, search_px,
                           rival_margin, row_offset_px, band_px)
    if rival is not None:
        return TargetDisparity(d, ncc, f"the patch at ({x:g}, {y:g}) repeats along its rows in the right image "
                                       f"(NCC {rival:.2f} against {ncc:.2f} at d = {d:.1f} px): d may be a "
                                       "repeat's, so the eyes' final vergence is not held against it")
    return TargetDisparity(d, ncc)


def vergence_on_a_repeat(left: np.ndarray, right: np.ndarray, patch_size: tuple[int, int], search_px: float,
                         row_offset_px: float = 0.0,
                         rival_margin: float = CorrespondenceParams.stereo_rival_margin) -> str:
    """Why the depth the eyes converged at may be a repeat's ('' where it cannot): the left
    fovea's patch (`patch_size`, fine vergence's) matches the right image where the eyes
    converged and, within `rival_margin` of NCC, another place along the same rows within
    +-`search_px` (`row_repeat_ncc`; `row_offset_px`: the pair's vertical misalignment). On
    such a texture fine vergence may settle with the right eye on a repeat, and the eyes'
    vergence then says nothing of what the left eye sees, as a d measured on such a patch says
    nothing of the target's depth (`target_disparity`)."""
    grey_left, grey_right = as_grey_float(left), as_grey_float(right)
    height, width = grey_left.shape
    fovea = ((width - 1) / 2.0, (height - 1) / 2.0)
    band_px = DISPARITY_BAND_PX if row_offset_px else 0
    d, ncc = horizontal_offset(grey_left, grey_right, fovea, patch_size, (-search_px, search_px), band_px,
                               row_offset_px)
    if ncc <= 0:
        return ""
    rival = row_repeat_ncc(grey_left, grey_right, fovea, patch_size, d, ncc, search_px, rival_margin, row_offset_px,
                           band_px)
    if rival is None:
        return ""
    return (f"the fovea's patch repeats along its rows in the right image (NCC {rival:.2f} against {ncc:.2f} at "
            f"{d:.1f} px): the right eye may be on a repeat")
