"""Finding a look's target again: where the patch it was chosen by is after a fixation.

The head turned, so the patch is seen through another part of the lens: a fish-eye lens
magnifies a patch brought from the periphery to the fovea, along the radius from the image
centre more than across it. The patch is therefore resampled at a few radial and tangential
scales (about the image centre, the one point the method assumes; no calibration), each
searched for by NCC near the fovea first, then farther (`find_target`); the best candidate's
warp is fitted by ECC (an affine fit of the patch, `cv2.findTransformECC`), the region
scored again with it, and the position taken from ECC, to sub-pixel. Later steps start from
the warp found before. A patch too flat or repetitive to identify the target in its own view
is refused before it is used (`calib_free.gaze.target_patch`). A best match below
`min_target_ncc` (occluded, out of view) or a second place nearly as good
(`ambiguity_ncc_margin`: repetitive texture) is refused: the target is not found, unless
the places are told apart by where the fixation was expected to bring the target (its
measured landing error, `expected_place`) or, where that was not measured or reaches more
than one of them, by the view before: only the true target has, in that view, repeats where
the other places lie (`place_told_by_repeats`).

Where no place matches at `min_target_ncc`, the view may have turned in a way the warps tried
do not show: both searches then try every candidate warp turned about the patch's centre
(`turned`, `TURNS_DEG`; `find_first_sighting`, `find_later_sighting`). A neck that pans about
an axis the tilt leans away from the optical axis turns the view by about the pan times the
sine of the tilt; in the realistic world's offline looks, 7 of 11 targets within 1.5 px of the
fovea that no candidate warp matched at 0.7 were seen turned by 2.7-9.0 deg (ECC's fit), each
within 1.0 deg of -pan x sin(tilt). A corrective step's search does not try every candidate
warp unturned: of the targets that search found offline, 4 of 7 were look-alikes. A place that
matched, but could not be told from a repeat, is not searched for again with other warps: a
warp beyond those the view shows would only find a look-alike.
"""
from __future__ import annotations

import dataclasses
import enum
from dataclasses import dataclass
from typing import Callable

import cv2
import numpy as np

from calib_free.correspondence.disparity import as_grey_float, subpixel_peak
from calib_free.gaze.fixation import LookParams
from calib_free.gaze.magnification import LearnedMagnification

# Where two places match the target's patch nearly alike, the one within this many times the
# expected error of where the target was expected is the target, if it is the only one there.
PRIOR_SIGMAS = 3.0
# The least expected error (px, in the image searched): sub-pixel localisation, and fine vergence
# moving the left eye by a fraction of a degree after the saccade.
MIN_EXPECTED_ERROR_PX = 1.0
PEAK_SEPARATION_PX = 2.0  # two local maxima of the scores this near are one place (a plateau)
REFINE_BELOW_NCC = 0.2  # a best match this far below min_target_ncc is still refined before judged
# Telling repeats apart by the view before the saccade (`place_told_by_repeats`): a repeat is
# looked for within this much (px, or this fraction of its distance: the lens bends the view's
# change farther out) of where the warp carries it back; matching at most the confirm margin
# less well than its place after the saccade it is there, more than the refute margin less it
# is not.
REPEAT_SLACK_PX = 2.0
REPEAT_SLACK_FRACTION = 0.1
REPEAT_CONFIRM_MARGIN = 0.15
REPEAT_REFUTE_MARGIN = 0.3
# A look's first search takes the larger patch's place where it lies farther than this from the
# smaller one's, and nearer the fovea (`nearer_of_two_patches`): farther than the two patches'
# disagreement about one point where both are right (in the recorded looks p90 0.56 px, p99 1.3 px).
PATCHES_DISAGREE_PX = 2.0
# The warps tried again turned about the patch's centre (deg), where none matched a place: a neck
# that pans about an axis the tilt leans away from the optical axis turns the view about that
# axis, by about the pan times the sine of the tilt (a 30 deg pan at a 15 deg tilt: 8 deg). No
# warp of `candidate_warps` turns, and ECC refines only a match near min_target_ncc.
TURNS_DEG = (-12.0, -6.0, 6.0, 12.0)


class SearchStage(enum.StrEnum):
    """Which warps of the patch found a look's target (`find_first_sighting`, `find_later_sighting`)."""

    LEARNED_SCALES = "the lens's learned scales"
    EVERY_SCALE = "every scale"
    CARRIED = "the warp found before"
    TURNED = "every warp turned, none unturned matching"


@dataclass(frozen=True)
class TargetSighting:
    """Where the target's patch is in an image, how well it matched, the linear part of the
    warp from the image the patch was taken in to this one, and which warps found it (None: a
    search of `search_target`'s caller's choosing)."""

    x: float
    y: float
    ncc: float
    warp: np.ndarray  # 2 x 2
    found_by: SearchStage | None = None

    def distance_px(self, point: tuple[float, float]) -> float:
        return float(np.hypot(self.x - point[0], self.y - point[1]))


def fovea(image: np.ndarray) -> tuple[float, float]:
    """The left fovea: the image centre ((w - 1) / 2, (h - 1) / 2)."""
    h, w = image.shape[:2]
    return (w - 1) / 2.0, (h - 1) / 2.0


def radial_scale_grid(max_scale: float) -> list[float]:
    """The radial scales `candidate_warps` tries: from 0.85 to `max_scale` in steps of 1.2."""
    scales = [0.85]
    while scales[-1] * 1.2 <= max_scale * 1.0001:
        scales.append(scales[-1] * 1.2)
    return scales


def candidate_warps(source_xy: tuple[float, float], centre: tuple[float, float], max_scale: float,
                    radial_scales: list[float] | None = None) -> list[np.ndarray]:
    """Linear warps a patch at `source_xy` may undergo on its way to the fovea: radial scales
    (along the line from the image centre; `radial_scales`, default `radial_scale_grid`) and two
    tangential ones."""
    dx, dy = source_xy[0] - centre[0], source_xy[1] - centre[1]
    norm = float(np.hypot(dx, dy))
    radial = np.array([dx, dy]) / norm if norm > 1.0 else np.array([1.0, 0.0])
    rotation = np.column_stack([radial, [-radial[1], radial[0]]])
    warps = []
    for s_radial in (radial_scales if radial_scales is not None else radial_scale_grid(max_scale)):
        for s_tangential in (1.0, 1.15):
            if s_radial < 1.0 and s_tangential > 1.0:
                continue
            warps.append(rotation @ np.diag([s_radial, s_tangential]) @ rotation.T)
    return warps


def turned(warps: list[np.ndarray], angles_deg: tuple[float, ...] = TURNS_DEG) -> list[np.ndarray]:
    """Each of `warps` turned by each of `angles_deg` (a positive angle turns x towards y:
    clockwise as the image is seen, y down)."""
    out: list[np.ndarray] = []
    for angle in np.radians(angles_deg):
        rotation = np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])
        out.extend(rotation @ warp for warp in warps)
    return out


def warped_patch(source: np.ndarray, source_xy: tuple[float, float], warp: np.ndarray,
                 size: tuple[int, int]) -> np.ndarray | None:
    """The patch of `size` (w, h) around `source_xy` as `warp` shows it; None when it reaches
    beyond the image."""
    w, h = size
    c = np.array([(w - 1) / 2.0, (h - 1) / 2.0])
    inverse = np.linalg.inv(warp)
    corners = np.array([[0, 0], [w - 1, 0], [0, h - 1], [w - 1, h - 1]], dtype=float) - c
    reach = corners @ inverse.T + np.asarray(source_xy)
    if reach.min() < 0 or np.any(reach[:, 0] > source.shape[1] - 1) or np.any(reach[:, 1] > source.shape[0] - 1):
        return None
    # dst q -> src inverse (q - c) + source_xy
    matrix = np.hstack([inverse, (np.asarray(source_xy) - inverse @ c)[:, None]]).astype(np.float64)
    patch: np.ndarray = cv2.warpAffine(source, matrix, (w, h), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                                       borderMode=cv2.BORDER_REPLICATE)
    return patch


@dataclass(frozen=True)
class TargetSearch:
    """A target search's answer (`search_target`): where the target is, or why it was not found
    (`why`), and whether any place matched its patch at `min_target_ncc` (`matched`: one did,
    though the target was not told from a repeat, or was refused)."""

    sighting: TargetSighting | None
    why: str = ""
    matched: bool = False


def find_target(source: np.ndarray, source_xy: tuple[float, float], image: np.ndarray, params: LookParams,
                warps: list[np.ndarray] | None = None, expected_error_px: float | None = None,
                expected_offset_px: tuple[float, float] | None = None,
                step_error_px: float | None = None) -> tuple[TargetSighting | None, str]:
    """Where the patch around `source_xy` of `source` is in `image`: (sighting, '') or (None, why
    not); see `search_target`."""
    found = search_target(source, source_xy, image, params, warps, expected_error_px, expected_offset_px,
                          step_error_px)
    return found.sighting, found.why


def search_target(source: np.ndarray, source_xy: tuple[float, float], image: np.ndarray, params: LookParams,
                  warps: list[np.ndarray] | None = None, expected_error_px: float | None = None,
                  expected_offset_px: tuple[float, float] | None = None,
                  step_error_px: float | None = None, prior_in_image: bool = False) -> TargetSearch:
    """Where the patch around `source_xy` of `source` is in `image` (both grey), searched within
    `params.search_radius_px` of the fovea; after a corrective step, within its reach.

    `warps`: the linear warps to try (default: `candidate_warps`, for a patch brought from
    wherever it was to near the fovea). Where the fixation is expected to have brought the
    target, in `source`'s pixels: `expected_offset_px` from the fovea (default: at it; the
    image searched sees the offset through the patch's warp) with an expected error
    `expected_error_px` about that place. Where two places match the patch nearly alike, the
    one alone within `PRIOR_SIGMAS` times that error (magnified as the patch is, at least
    `MIN_EXPECTED_ERROR_PX`) of the expected place is the target (`expected_place`). None: no
    such prior; the place whose repeats `source` shows around the target is it
    (`place_told_by_repeats`). `prior_in_image`: the offset and the error are in the pixels of
    the image searched, about its fovea, and no warp carries them (a prior a diagnostic tries:
    where the encoders say the head's motion moved the view, `benchmarks.diag.ambiguous_places`).

    `step_error_px`: a corrective step's expected error (`calib_free.gaze.look_geometry.corrective_step_error_px`),
    which bounds where the target can be, not only which repeat it is: a step that aimed a few
    pixels from the fovea and went as the encoders say cannot have left the target farther. The
    search then keeps within `PRIOR_SIGMAS` times it (at least `MIN_EXPECTED_ERROR_PX`) either
    side of the fovea, and a best match farther out is no sighting (`step_reach_px`)."""
    source, image = as_grey_float(source), as_grey_float(image)
    w, h = params.target_patch_size
    height, width = image.shape
    centre = fovea(image)
    if warps is None:
        warps = candidate_warps(source_xy, fovea(source), params.max_target_scale)
    radius = full_radius = params.search_radius_px if params.search_radius_px is not None else width // 3
    bound = ""
    if step_error_px is not None:
        step_reach = step_reach_px(step_error_px)
        if step_reach < radius:
            radius = step_reach
            bound = f" within {step_reach} px of the fovea, as far as the corrective step can have left it,"
    x0 = int(max(0, np.floor(centre[0] - radius - w / 2)))
    y0 = int(max(0, np.floor(centre[1] - radius - h / 2)))
    x1 = int(min(width, np.ceil(centre[0] + radius + w / 2) + 1))
    y1 = int(min(height, np.ceil(centre[1] + radius + h / 2) + 1))
    window = image[y0:y1, x0:x1]
    if window.shape[0] < h + 2 or window.shape[1] < w + 2:
        return TargetSearch(None, f"the search window {window.shape[1]} x {window.shape[0]} px is smaller than the patch")
    # The patch as each candidate warp shows it, if it shows enough to find the target by.
    templates: list[tuple[np.ndarray, np.ndarray]] = []  # (template, warp)
    for warp in warps:
        template = warped_patch(source, source_xy, warp, (w, h))
        if template is not None and float(template.std()) >= params.min_patch_std:
            templates.append((template, warp))
    if not templates:
        return TargetSearch(None, f"the target's patch at ({source_xy[0]:.1f}, {source_xy[1]:.1f}) reaches beyond "
                                  "the image or is too flat to find it by")
    placements = (window.shape[0] - h + 1, window.shape[1] - w + 1)  # of the patch in the window (rows, columns)

    def scored(template: np.ndarray, rows: tuple[int, int], columns: tuple[int, int]) -> np.ndarray:
        """The NCC of `template` at the window's placements `rows` x `columns` (top-left
        corners, end exclusive): each placement's score is its own, so only the region
        judged is computed."""
        part = window[rows[0]:rows[1] + h - 1, columns[0]:columns[1] + w - 1]
        return np.nan_to_num(cv2.matchTemplate(part, template, cv2.TM_CCOEFF_NORMED), nan=0.0, posinf=0.0,
                             neginf=0.0)

    c = np.array([(w - 1) / 2.0, (h - 1) / 2.0])
    # Near the fovea first, where the saccade meant to bring the target: a repeat of its texture
    # farther away does not make it ambiguous there. Else the whole search window. The near
    # part is a third of the unbounded radius whatever bounds the window: a corrective step's
    # reach narrower than that is searched whole at once.
    near = min(radius, max(full_radius // 3, 4))
    u0 = int(max(0, np.floor(centre[0] - near - x0 - c[0])))
    v0 = int(max(0, np.floor(centre[1] - near - y0 - c[1])))
    u1 = min(placements[1], int(np.ceil(centre[0] + near - x0 - c[0])) + 1)
    v1 = min(placements[0], int(np.ceil(centre[1] + near - y0 - c[1])) + 1)
    why, matched = "", False
    for (a, b) in (((v0, v1), (u0, u1)), ((0, placements[0]), (0, placements[1]))):
        regions = [scored(template, a, b) for template, _ in templates]
        peak, index = max((float(scores.max()), i) for i, scores in enumerate(regions))
        region, (template, warp) = regions[index], templates[index]
        _, _, _, (ix, iy) = cv2.minMaxLoc(region)
        position: tuple[float, float] | None = None
        if peak >= params.min_target_ncc - REFINE_BELOW_NCC:
            # The warp fitted (ECC) where the best candidate matched, and the whole region
            # scored again with the patch so warped: the grid's nearest warp can fall short
            # of the view's, which lowers the true match more than the others.
            u, v = subpixel_peak(region, iy, ix)
            refined = ecc_fit(template, image, x0 + b[0] + u, y0 + a[0] + v)
            if refined is not None and np.hypot(refined[0][0] - (x0 + b[0] + u + c[0]),
                                                refined[0][1] - (y0 + a[0] + v + c[1])) > 2.0:
                refined = None  # ECC wandered off to something else
            better = None if refined is None else warped_patch(source, source_xy, refined[1] @ warp, (w, h))
            if refined is not None and better is not None and float(better.std()) >= params.min_patch_std:
                rescored = scored(better, a, b)
                _, repeak, _, (jx, jy) = cv2.minMaxLoc(rescored)
                if np.hypot(jx - ix, jy - iy) <= 2.0:
                    region, peak, (ix, iy) = rescored, float(repeak), (jx, jy)
                    position, warp = refined[0], refined[1] @ warp
        if peak < params.min_target_ncc:
            why = why or (f"the best match of the target's patch{bound} scores NCC {peak:.2f} < "
                          f"{params.min_target_ncc}")
            continue
        matched = True
        second = second_peak(region, ix, iy, max(w, h) / 2)
        if second > peak - params.ambiguity_ncc_margin:
            ambiguous = (f"the target's patch is ambiguous: two places match it, NCC {peak:.2f} and {second:.2f} "
                         f"(margin {params.ambiguity_ncc_margin})")
            origin = (x0 + b[0] + c[0], y0 + a[0] + c[1])  # image position of the region's (0, 0)
            chosen: tuple[int, int] | None = None
            near, reach = 0, np.inf
            offset = np.asarray(expected_offset_px if expected_offset_px is not None else (0.0, 0.0))
            shift = offset if prior_in_image else warp @ offset
            expected_at = (centre[0] + shift[0] - origin[0], centre[1] + shift[1] - origin[1])  # in the region
            if expected_error_px is not None:
                reach = PRIOR_SIGMAS * max(MIN_EXPECTED_ERROR_PX,
                                           expected_error_px * (1.0 if prior_in_image else _magnification(warp)))
                chosen, near = expected_place(region, peak - params.ambiguity_ncc_margin, expected_at, reach)
            undecided = ""
            if chosen is None and (expected_error_px is None or near > 1):
                # No landing measured, or one too far off to tell the repeats apart: the view
                # before may still, if it shows the repeats where they lie around the target.
                places = distinct_places(region, peak - params.ambiguity_ncc_margin, max(w, h) / 2)
                told, undecided = place_told_by_repeats(
                    source, source_xy, (w, h), [(origin[0] + u, origin[1] + v) for u, v in places],
                    [float(region[v, u]) for u, v in places], warp)
                if told is not None and np.hypot(places[told][0] - expected_at[0],
                                                 places[told][1] - expected_at[1]) <= reach:
                    chosen = places[told]
            if chosen is None:
                if expected_error_px is None:
                    why = (f"{ambiguous}, and where the saccade landed is not known to tell them apart (its "
                           f"correspondence was not accepted; {undecided})")
                    continue
                put_by = "the prior in the image's pixels" if prior_in_image else "the fixation's measured landing"
                where = (f"within {reach:.1f} px of the fovea, where the fixation was expected to bring it "
                         f"({PRIOR_SIGMAS:g} x its expected error)" if expected_offset_px is None else
                         f"within {reach:.1f} px of ({origin[0] + expected_at[0]:.1f}, "
                         f"{origin[1] + expected_at[1]:.1f}), where {put_by} puts the "
                         f"target ({PRIOR_SIGMAS:g} x its expected error)")
                why = (f"{ambiguous}, and {near} of them lie {where}: the target's texture repeats nearer "
                       f"than the map can tell apart ({undecided})" if near else f"{ambiguous}, and neither lies {where}")
                continue
            if chosen != (ix, iy):
                (ix, iy), peak, position = chosen, float(region[chosen[1], chosen[0]]), None
        if position is None:
            u, v = subpixel_peak(region, iy, ix)
            position = (x0 + b[0] + u + c[0], y0 + a[0] + v + c[1])
        return TargetSearch(TargetSighting(float(position[0]), float(position[1]), peak, warp), "", True)
    return TargetSearch(None, why, matched)


def step_reach_px(step_error_px: float) -> int:
    """How far either side of the fovea a search after a corrective step looks for the target
    (`search_target`): `PRIOR_SIGMAS` times the step's expected error, at least
    `MIN_EXPECTED_ERROR_PX`; whole pixels, rounded up. The error is in the pixels of the image
    searched already (the step aimed in the image before it, at the fovea too), so no warp
    magnifies it."""
    return int(np.ceil(PRIOR_SIGMAS * max(MIN_EXPECTED_ERROR_PX, step_error_px)))


def find_first_sighting(source: np.ndarray, source_xy: tuple[float, float], image: np.ndarray,
                        variants: list[LookParams], magnification: LearnedMagnification,
                        expected_error_px: float | None = None, expected_offset_px: tuple[float, float] | None = None,
                        ) -> tuple[TargetSighting | None, LookParams, str]:
    """The target after a look's first saccade: searched by each of the patches `variants` in
    turn (`search_target`), first with only the radial scales the looks have learned the lens
    to show at the target's distance from the centre (`LearnedMagnification.radial_scales`),
    then with every candidate scale where those matched nothing by any patch (no place at
    `min_target_ncc`: a lens that changed). Where a learned scale matched a place but the search
    could not tell the target from a repeat, the lens shows the patch as learned, and no other
    scale is tried: a stretch beyond the learned one would only find a look-alike. Where the
    patch found the target and a larger one finds it elsewhere, the nearer the fovea is taken
    (`nearer_of_two_patches`). (sighting, the patch it was found by, '') or (None, the first
    patch, why not)."""
    centre = fovea(source)
    distance = float(np.hypot(source_xy[0] - centre[0], source_xy[1] - centre[1]))

    def learned(variant: LookParams) -> TargetSearch | None:
        scales = magnification.radial_scales(distance, radial_scale_grid(variant.max_target_scale))
        if scales is None:
            return None  # nothing learned at this distance: every scale
        return search_target(source, source_xy, image, variant,
                             candidate_warps(source_xy, centre, variant.max_target_scale, scales), expected_error_px,
                             expected_offset_px)

    def every_scale(variant: LookParams) -> TargetSearch:
        return search_target(source, source_xy, image, variant, None, expected_error_px, expected_offset_px)

    learned_why, matched = "", False
    for k, variant in enumerate(variants):
        found = learned(variant)
        if found is None:
            break
        if found.sighting is not None:
            return (*_found_by(SearchStage.LEARNED_SCALES, *nearer_of_two_patches(
                found.sighting, variant, variants[k + 1:], learned, fovea(image))), "")
        learned_why, matched = learned_why or found.why, matched or found.matched
    if matched:
        return None, variants[0], learned_why
    def every_turn(variant: LookParams) -> TargetSearch:
        return search_target(source, source_xy, image, variant,
                             turned(candidate_warps(source_xy, centre, variant.max_target_scale)), expected_error_px,
                             expected_offset_px)

    why = ""
    for stage, search in ((SearchStage.EVERY_SCALE, every_scale), (SearchStage.TURNED, every_turn)):
        for k, variant in enumerate(variants):
            found = search(variant)
            if found.sighting is not None:
                return (*_found_by(stage, *nearer_of_two_patches(found.sighting, variant, variants[k + 1:], search,
                                                                 fovea(image))), "")
            why, matched = why or found.why, matched or found.matched
        if matched:
            break
    return None, variants[0], why


def find_later_sighting(source: np.ndarray, source_xy: tuple[float, float], image: np.ndarray,
                        variants: list[LookParams], warps: list[np.ndarray], expected_error_px: float | None,
                        expected_offset_px: tuple[float, float] | None, step_error_px: float | None,
                        ) -> tuple[TargetSighting | None, LookParams, str]:
    """The target after a corrective step: searched by each of the patches `variants` with
    `warps` (the one found before), then, where no place matched by any, with every candidate
    warp turned (`turned`: the view turned with the step's pan). (sighting, its patch, '') or
    (None, the first patch, why not: the search with the warp carried)."""
    centre = fovea(source)

    def warps_of(stage: SearchStage, variant: LookParams) -> list[np.ndarray]:
        if stage is SearchStage.CARRIED:
            return warps
        return turned(candidate_warps(source_xy, centre, variant.max_target_scale))

    why, matched = "", False
    for stage in (SearchStage.CARRIED, SearchStage.TURNED):
        for variant in variants:
            found = search_target(source, source_xy, image, variant, warps_of(stage, variant), expected_error_px,
                                  expected_offset_px, step_error_px)
            if found.sighting is not None:
                return dataclasses.replace(found.sighting, found_by=stage), variant, ""
            why, matched = why or found.why, matched or found.matched
        if matched:
            break
    return None, variants[0], why


def fallback_note(sightings: list[TargetSighting]) -> str:
    """'; found again by every warp turned, ...' where a fallback search (every warp turned)
    found the target of any of `sightings`; '' where none did."""
    return f"; found again by {SearchStage.TURNED}" if any(s.found_by is SearchStage.TURNED for s in sightings) else ""


def _found_by(stage: SearchStage, sighting: TargetSighting, variant: LookParams,
              ) -> tuple[TargetSighting, LookParams]:
    return dataclasses.replace(sighting, found_by=stage), variant


def nearer_of_two_patches(sighting: TargetSighting, variant: LookParams, larger: list[LookParams],
                          search: Callable[[LookParams], TargetSearch | None], fovea_xy: tuple[float, float],
                          ) -> tuple[TargetSighting, LookParams]:
    """`sighting` (found by `variant`), or where the next of `larger` patches finds the target
    more than `PATCHES_DISAGREE_PX` from it and nearer the fovea, that one and its patch. Two
    patches about one point that disagree cannot both be right; the saccade aimed the target at
    the fovea, so the one nearer it is the likelier. The smaller patch goes wrong where the view's
    change moves its parts against each other (across a depth edge) or it slides along a straight
    edge or a faint band: in the realistic world's recorded looks (five seeds, 197 first searches)
    the larger patch put 5 of its 9 wrong first searches back within 1.4 px of the truth, and no
    right one wrong (docs/results/realistic-world.md)."""
    if not larger:
        return sighting, variant
    other = search(larger[0])
    if other is None or other.sighting is None:
        return sighting, variant
    if (np.hypot(other.sighting.x - sighting.x, other.sighting.y - sighting.y) > PATCHES_DISAGREE_PX
            and other.sighting.distance_px(fovea_xy) < sighting.distance_px(fovea_xy)):
        return other.sighting, larger[0]
    return sighting, variant


def expected_place(scores: np.ndarray, threshold: float, expected: tuple[float, float],
                   reach_px: float) -> tuple[tuple[int, int] | None, int]:
    """The one place of `scores` matching at least `threshold` within `reach_px` of `expected`
    (both in `scores`' coordinates), (ix, iy), or None when none or more than one lies there;
    and how many lie there. Places are local maxima farther than `PEAK_SEPARATION_PX` from
    every better one: a fine periodic texture's repeats lie nearer each other than half a
    patch, and the one at `expected` must not be taken for a ripple of a better one."""
    places = distinct_places(scores, threshold, PEAK_SEPARATION_PX)
    near = [(u, v) for u, v in places if np.hypot(u - expected[0], v - expected[1]) <= reach_px]
    return (near[0] if len(near) == 1 else None), len(near)


def distinct_places(scores: np.ndarray, threshold: float, min_distance_px: float) -> list[tuple[int, int]]:
    """The local maxima of `scores` at least `threshold`, best first, each farther than
    `min_distance_px` from every better one: the places a patch matches (a peak's own
    ripples and shoulders, within half a patch of it, are no other places)."""
    maxima = (scores >= cv2.dilate(scores, np.ones((3, 3), np.uint8))) & (scores >= threshold)
    ys, xs = np.nonzero(maxima)
    places: list[tuple[int, int]] = []
    for k in np.argsort(-scores[ys, xs]):
        if all(np.hypot(xs[k] - u, ys[k] - v) > min_distance_px for u, v in places):
            places.append((int(xs[k]), int(ys[k])))
    return places


def place_told_by_repeats(source: np.ndarray, source_xy: tuple[float, float], size: tuple[int, int],
                          places: list[tuple[float, float]], place_ncc: list[float],
                          warp: np.ndarray) -> tuple[int | None, str]:
    """Which of `places` (image positions where the target's patch matches nearly alike, NCC
    `place_ncc`) is the target, told by the view the target was chosen in: were place i the
    target, every other place j would be a repeat of it that `source` shows too, at `source_xy`
    plus the offset j - i carried back through `warp` (the linear part of the view's change),
    matching the patch about as well as j does. The one place whose repeats `source` confirms
    (each within `REPEAT_CONFIRM_MARGIN` of its NCC), while every other place's are refuted (one
    matching `REPEAT_REFUTE_MARGIN` or more below), is the target: (its index, ''); else (None,
    why not). A texture that repeats evenly on both sides, or repeats `source` does not show,
    stay undecided."""
    template = warped_patch(source, source_xy, np.eye(2), size)
    if template is None:
        return None, "the target's patch reaches beyond its own view"
    inverse = np.linalg.inv(warp)
    confirmed: list[int] = []
    refuted = 0
    for i, here in enumerate(places):
        shortfalls: list[float | None] = []  # how much less than place j the repeat matches in `source`
        for j, there in enumerate(places):
            if j == i:
                continue
            offset = inverse @ (np.asarray(there, dtype=float) - np.asarray(here, dtype=float))
            ncc = _best_match_near(source, template, (source_xy[0] + offset[0], source_xy[1] + offset[1]),
                                   max(REPEAT_SLACK_PX, REPEAT_SLACK_FRACTION * float(np.hypot(*offset))))
            shortfalls.append(None if ncc is None else place_ncc[j] - ncc)
        if any(short is not None and short > REPEAT_REFUTE_MARGIN for short in shortfalls):
            refuted += 1
        elif all(short is not None and short <= REPEAT_CONFIRM_MARGIN for short in shortfalls):
            confirmed.append(i)
    if len(confirmed) == 1 and refuted == len(places) - 1:
        return confirmed[0], ""
    return None, (f"its view before the saccade confirms {len(confirmed)} of the {len(places)} places as the target "
                  f"and refutes {refuted}")


def _best_match_near(source: np.ndarray, template: np.ndarray, xy: tuple[float, float],
                     slack_px: float) -> float | None:
    """The best NCC of `template` centred within `slack_px` of `xy` in `source`; None when that
    neighbourhood reaches beyond the image (the view does not show it)."""
    h, w = template.shape
    r = int(np.ceil(slack_px))
    x0, y0 = int(round(xy[0] - (w - 1) / 2.0)) - r, int(round(xy[1] - (h - 1) / 2.0)) - r
    x1, y1 = x0 + w + 2 * r, y0 + h + 2 * r
    if x0 < 0 or y0 < 0 or x1 > source.shape[1] or y1 > source.shape[0]:
        return None
    scores = np.nan_to_num(cv2.matchTemplate(source[y0:y1, x0:x1], template, cv2.TM_CCOEFF_NORMED), nan=0.0,
                           posinf=0.0, neginf=0.0)
    return float(scores.max())


def _magnification(warp: np.ndarray) -> float:
    """The most a linear warp stretches a direction (its largest singular value)."""
    return float(np.linalg.svd(warp, compute_uv=False)[0])


def second_peak(scores: np.ndarray, ix: int, iy: int, min_distance_px: float) -> float:
    """The best local maximum of `scores` farther than `min_distance_px` (half the patch) from
    the peak at (ix, iy), -1 if none: another place matching nearly as well means repetitive
    texture. The peak's own shoulders are no local maxima, and the ripples of a broad peak (a
    smooth patch) lie within half a patch of it, so neither is taken for another place."""
    maxima = (scores >= cv2.dilate(scores, np.ones((3, 3), np.uint8))) & (scores > -1.0)
    ys, xs = np.nonzero(maxima)
    far = np.hypot(xs - ix, ys - iy) > min_distance_px
    return float(scores[ys[far], xs[far]].max()) if np.any(far) else -1.0


def ecc_fit(template: np.ndarray, image: np.ndarray, u: float, v: float,
            ) -> tuple[tuple[float, float], np.ndarray, float] | None:
    """ECC's affine fit of `template` placed with its top-left at (u, v) in `image`: the
    template centre's position, the linear part, the correlation; None if it did not converge.
    ECC sees only the image within one patch of the placement: what a fit near it samples
    (one that wanders farther is refused by the caller), without the gradients of the whole
    image."""
    h, w = template.shape
    x0, y0 = max(0, int(np.floor(u)) - w), max(0, int(np.floor(v)) - h)
    near = image[y0:min(image.shape[0], int(np.ceil(v)) + 2 * h + 1),
                 x0:min(image.shape[1], int(np.ceil(u)) + 2 * w + 1)]
    matrix = np.array([[1.0, 0.0, u - x0], [0.0, 1.0, v - y0]], dtype=np.float32)
    criteria = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 50, 1e-4)
    try:
        # gaussFiltSize 1: no blur, the patch and the image are sharp; typeshed lacks this overload.
        ncc, fitted = cv2.findTransformECC(template.astype(np.float32), near.astype(np.float32), matrix,  # type: ignore[call-overload]
                                           cv2.MOTION_AFFINE, criteria, None, 1)
    except cv2.error:
        return None
    c = np.array([(w - 1) / 2.0, (h - 1) / 2.0])
    fitted = np.asarray(fitted, dtype=float)
    position = fitted[:, :2] @ c + fitted[:, 2] + (x0, y0)
    return (float(position[0]), float(position[1])), fitted[:, :2], float(ncc)
