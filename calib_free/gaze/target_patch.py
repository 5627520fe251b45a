"""Which of a look's patches can identify its target, judged in the target's own view.

A patch too flat to find the target by (what it shows is mostly the camera's noise), reaching
beyond the image, or matching another place of its own view within the search radius nearly as
well as its own (repetitive texture) cannot tell the target after the saccade from what
resembles it: `patch_problem`. A look tries the patch of `LookParams.target_patch_size` and the
one twice as large (`patch_variants`), whichever identify the target (`identifying_patches`).

Where the patch repeats within the search radius of its own view, the patch twice as large is
used only if its own view's second place matches it worse than the best by
`context_ncc_margin` (0.25), not just `ambiguity_ncc_margin` (0.1): it differs from its
repeats only by its rim, and at the fovea the rim is what the patch's warp matches worst (the
lens's magnification changes across a patch that large). Its own-view margin then shrinks below
0.1 on the way to the fovea: in the offline looks of the realistic world (two seeds, 381
looks), 8 of the 20 that failed as ambiguous after the saccade had a larger patch within 0.25
in its own view, and none of the 329 that ended on target did.
"""
from __future__ import annotations

import dataclasses

import cv2
import numpy as np

from calib_free.correspondence.disparity import as_grey_float
from calib_free.gaze.fixation import LookParams
from calib_free.gaze.refind import second_peak, warped_patch

AMBIGUOUS_IN_OWN_VIEW = "is ambiguous in its own view"  # `patch_problem`'s words for repeats


def patch_problem(source: np.ndarray, source_xy: tuple[float, float], params: LookParams,
                  margin: float | None = None) -> str:
    """Why the patch around `source_xy` cannot identify the target ('' if it can): beyond the
    image, too flat, or matching another place of its own image within the search radius
    within `margin` (default `ambiguity_ncc_margin`) of itself (repetitive texture)."""
    margin = params.ambiguity_ncc_margin if margin is None else margin
    peaks, why = own_view_peaks(source, source_xy, params)
    if peaks is None:
        return why
    peak, second = peaks
    if second > peak - margin:
        return (f"the target's patch at ({source_xy[0]:.1f}, {source_xy[1]:.1f}) {AMBIGUOUS_IN_OWN_VIEW}: "
                f"another place matches it with NCC {second:.2f} (repetitive texture)")
    return ""


def own_view_peaks(source: np.ndarray, source_xy: tuple[float, float],
                   params: LookParams) -> tuple[tuple[float, float] | None, str]:
    """How well the patch around `source_xy` matches its own place in `source` and the best
    other place within the search radius (`second_peak`, -1 if none), both NCC, and ''; or
    (None, why the patch has no place: it reaches beyond the image, or is too flat)."""
    source = as_grey_float(source)
    template = warped_patch(source, source_xy, np.eye(2), params.target_patch_size)
    if template is None:
        return None, f"the target's patch at ({source_xy[0]:.1f}, {source_xy[1]:.1f}) reaches beyond the image"
    if float(template.std()) < params.min_patch_std:
        return None, (f"the target's patch at ({source_xy[0]:.1f}, {source_xy[1]:.1f}) has no texture to find it "
                      f"by (grey levels' std {float(template.std()):.1f} < min_patch_std {params.min_patch_std:g}: "
                      "what it shows is mostly the camera's noise)")
    w, h = params.target_patch_size
    scores = np.nan_to_num(cv2.matchTemplate(own_view_window(source, source_xy, params), template,
                                             cv2.TM_CCOEFF_NORMED), nan=0.0, posinf=0.0, neginf=0.0)
    _, peak, _, (ix, iy) = cv2.minMaxLoc(scores)
    return (float(peak), second_peak(scores, ix, iy, max(w, h) / 2)), ""


def own_view_window(source: np.ndarray, source_xy: tuple[float, float], params: LookParams) -> np.ndarray:
    """The part of `source` whose patches of `target_patch_size` lie within the search radius
    of `source_xy` (`search_radius_px`, default a third of the width): where the own-view
    checks look for the patch's other places."""
    w, h = params.target_patch_size
    radius = params.search_radius_px if params.search_radius_px is not None else source.shape[1] // 3
    x0 = int(max(0, np.floor(source_xy[0] - radius - w / 2)))
    y0 = int(max(0, np.floor(source_xy[1] - radius - h / 2)))
    return source[y0:int(np.ceil(source_xy[1] + radius + h / 2)) + 1, x0:int(np.ceil(source_xy[0] + radius + w / 2)) + 1]


def patch_variants(params: LookParams) -> list[LookParams]:
    """The target's patches a look tries: of `target_patch_size`, or twice it (more context:
    what sets a repeating texture's places apart), whichever identify the target in its own
    view (`identifying_patches`)."""
    w, h = params.target_patch_size
    return [dataclasses.replace(params, target_patch_size=size) for size in ((w, h), (2 * w - 1, 2 * h - 1))]


def identifying_patches(source: np.ndarray, source_xy: tuple[float, float],
                        params: LookParams) -> tuple[list[LookParams], str]:
    """The target's patches (`patch_variants`) that identify it in its own view
    (`patch_problem`), and why the smaller does not ('' if it does). The larger, where the
    smaller is ambiguous there, is held to `context_ncc_margin` (see the module doc). Where the
    smaller is flat (or reaches beyond the image) none is: what the saccade brings to the fovea
    then has nothing for fine vergence to converge on nor for the correspondence to measure the
    landing by, and the larger patch would find the target only by its rim, 10-20 px away."""
    small, large = patch_variants(params)
    why = patch_problem(source, source_xy, small)
    repeats = AMBIGUOUS_IN_OWN_VIEW in why
    if why and not repeats:
        return [], why
    usable = [small] if not why else []
    if not patch_problem(source, source_xy, large, params.context_ncc_margin if repeats else None):
        usable.append(large)
    return usable, why


def target_patch_problem(source: np.ndarray, source_xy: tuple[float, float], params: LookParams) -> str:
    """Why a look cannot find the target at `source_xy` again ('' if it can): neither of its
    patches identifies the target in its own view (`identifying_patches`)."""
    usable, why = identifying_patches(source, source_xy, params)
    return "" if usable else why
