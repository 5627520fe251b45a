"""Closed-loop looks: a look at an image target ends with the target on the left fovea.

One fixation through the map (`FixationController.fixate`: saccade, fine vergence,
correspondence) brings the target near the foveae, as near as the map is right. A look then
closes the loop on what it sees: the target's patch, taken around (x, y) in the left image
just before the saccade, is found again in the left image after it, and while it lies
farther than `LookParams.tolerance_px` from the left fovea a corrective fixation goes to where
it is now -- the map's command for that position and the disparity measured there -- up to
`max_corrective_steps` of them. Every step is a fixation like any other: converged and
confident, it teaches the map. A saccade the joint limits stopped ends the look: no
correction can go further.

A target is in the view of the pose it was chosen in (`reference_pose`). When the head has
moved since (a queued look), the look first returns to that pose, so that the image before
the saccade is the view the target was chosen in and its patch is the target's.

Finding the target again (`find_target`). The head turned, so the patch is seen through
another part of the lens: a fish-eye lens magnifies a patch brought from the periphery to the
fovea, along the radius from the image centre more than across it. The patch is therefore
resampled at a few radial and tangential scales (about the image centre, the one point the
method assumes; no calibration), each searched for by NCC near the fovea first, then farther;
the best candidate's warp is fitted by ECC (an affine fit of the patch,
`cv2.findTransformECC`), the region scored again with it, and the position taken from ECC, to
sub-pixel. Later steps start from the warp found before. A patch too flat or repetitive to
identify the target in its own view is refused before it is used (`patch_problem`). A best
match below `min_target_ncc` (occluded, out of view) or a second place nearly as good
(`ambiguity_ncc_margin`: repetitive texture) is refused, and so is one on which the eyes
converged far from the vergence the map gives the target's d (`max_vergence_mismatch_deg`: a
look-alike at another depth): the target is not found, and the look fails saying so. A look's
figures come only
from accepted measurements: `final_error_px` from the target found after the last step,
`landing_error_px` from a first fixation whose correspondence was accepted (it taught).
"""
from __future__ import annotations

import dataclasses
import enum
import logging
from dataclasses import dataclass, field
from typing import Callable

import cv2
import numpy as np

from calib_free.correspondence.disparity import as_grey_float, horizontal_offset, subpixel_peak
from calib_free.gaze.fixation import (FixationController, FixationInterrupted, FixationOutcome, FixationRecord,
                                 HeadTimeoutError, LookParams, PairTimeoutError)
from calib_free.map.gaze_map import Vector

log = logging.getLogger(__name__)

MIN_PATCH_STD = 2.0  # grey levels: a flatter patch has nothing to be found by
REFINE_BELOW_NCC = 0.2  # a best match this far below min_target_ncc is still refined before judged


class LookOutcome(enum.StrEnum):
    """How a look ended, beyond its fixations' own outcomes."""

    ON_TARGET = "on target"
    TARGET_LOST = "target not found again"
    NOT_ON_TARGET = "target not on the fovea"
    NO_TARGET_PATCH = "no patch to find the target by"
    OUT_OF_REACH = "target beyond the joint limits"


# A fixation ending so stops the look: it was interrupted, or never moved (no images after it).
_STOPS_A_LOOK = frozenset({FixationOutcome.SHUTDOWN, FixationOutcome.CANCELLED, FixationOutcome.BUS_DOWN,
                           FixationOutcome.SERVO_FAULT, FixationOutcome.NO_FRAMES, FixationOutcome.NOT_SETTLED,
                           FixationOutcome.TARGET_OUTSIDE})


@dataclass(frozen=True)
class TargetSighting:
    """Where the target's patch is in an image, how well it matched, and the linear part of the
    warp from the image the patch was taken in to this one."""

    x: float
    y: float
    ncc: float
    warp: np.ndarray  # 2 x 2

    def distance_px(self, point: tuple[float, float]) -> float:
        return float(np.hypot(self.x - point[0], self.y - point[1]))


def fovea(image: np.ndarray) -> tuple[float, float]:
    """The left fovea: the image centre ((w - 1) / 2, (h - 1) / 2)."""
    h, w = image.shape[:2]
    return (w - 1) / 2.0, (h - 1) / 2.0


def candidate_warps(source_xy: tuple[float, float], centre: tuple[float, float], max_scale: float) -> list[np.ndarray]:
    """Linear warps a patch at `source_xy` may undergo on its way to the fovea: radial scales
    (along the line from the image centre) from 0.85 to `max_scale` in steps of 1.2, and two
    tangential ones."""
    dx, dy = source_xy[0] - centre[0], source_xy[1] - centre[1]
    norm = float(np.hypot(dx, dy))
    radial = np.array([dx, dy]) / norm if norm > 1.0 else np.array([1.0, 0.0])
    rotation = np.column_stack([radial, [-radial[1], radial[0]]])
    scales = [0.85]
    while scales[-1] * 1.2 <= max_scale * 1.0001:
        scales.append(scales[-1] * 1.2)
    warps = []
    for s_radial in scales:
        for s_tangential in (1.0, 1.15):
            if s_radial < 1.0 and s_tangential > 1.0:
                continue
            warps.append(rotation @ np.diag([s_radial, s_tangential]) @ rotation.T)
    return warps


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


def find_target(source: np.ndarray, source_xy: tuple[float, float], image: np.ndarray, params: LookParams,
                warps: list[np.ndarray] | None = None) -> tuple[TargetSighting | None, str]:
    """Where the patch around `source_xy` of `source` is in `image` (both grey), searched within
    `params.search_radius_px` of the fovea; (sighting, '') or (None, why not).

    `warps`: the linear warps to try (default: `candidate_warps`, for a patch brought from
    wherever it was to near the fovea)."""
    source, image = as_grey_float(source), as_grey_float(image)
    w, h = params.target_patch_size
    height, width = image.shape
    centre = fovea(image)
    if warps is None:
        warps = candidate_warps(source_xy, fovea(source), params.max_target_scale)
    radius = params.search_radius_px if params.search_radius_px is not None else width // 3
    x0 = int(max(0, np.floor(centre[0] - radius - w / 2)))
    y0 = int(max(0, np.floor(centre[1] - radius - h / 2)))
    x1 = int(min(width, np.ceil(centre[0] + radius + w / 2) + 1))
    y1 = int(min(height, np.ceil(centre[1] + radius + h / 2) + 1))
    window = image[y0:y1, x0:x1]
    if window.shape[0] < h + 2 or window.shape[1] < w + 2:
        return None, f"the search window {window.shape[1]} x {window.shape[0]} px is smaller than the patch"
    tried: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []  # (scores, template, warp)
    for warp in warps:
        template = warped_patch(source, source_xy, warp, (w, h))
        if template is None:
            continue
        if float(template.std()) < MIN_PATCH_STD:
            continue  # magnified this much, the patch shows too little to find it by
        scores = np.nan_to_num(cv2.matchTemplate(window, template, cv2.TM_CCOEFF_NORMED), nan=0.0,
                               posinf=0.0, neginf=0.0)
        tried.append((scores, template, warp))
    if not tried:
        return None, (f"the target's patch at ({source_xy[0]:.1f}, {source_xy[1]:.1f}) reaches beyond the image "
                      "or is too flat to find it by")
    c = np.array([(w - 1) / 2.0, (h - 1) / 2.0])
    # Near the fovea first, where the saccade meant to bring the target: a repeat of its texture
    # farther away does not make it ambiguous there. Else the whole search window.
    near = max(radius // 3, 4)
    u0 = int(max(0, np.floor(centre[0] - near - x0 - c[0])))
    v0 = int(max(0, np.floor(centre[1] - near - y0 - c[1])))
    why = ""
    for (a, b) in (((v0, int(np.ceil(centre[1] + near - y0 - c[1])) + 1), (u0, int(np.ceil(centre[0] + near - x0 - c[0])) + 1)),
                   ((0, tried[0][0].shape[0]), (0, tried[0][0].shape[1]))):
        peak, index = max((float(t[0][a[0]:a[1], b[0]:b[1]].max()), i) for i, t in enumerate(tried))
        scores, template, warp = tried[index]
        region = scores[a[0]:a[1], b[0]:b[1]]
        _, _, _, (ix, iy) = cv2.minMaxLoc(region)
        position: tuple[float, float] | None = None
        if peak >= params.min_target_ncc - REFINE_BELOW_NCC:
            # The warp fitted (ECC) where the best candidate matched, and the whole region
            # scored again with the patch so warped: the grid's nearest warp can fall short
            # of the view's, which lowers the true match more than the others.
            u, v = subpixel_peak(region, iy, ix)
            refined = _refine(template, image, x0 + b[0] + u, y0 + a[0] + v)
            if refined is not None and np.hypot(refined[0][0] - (x0 + b[0] + u + c[0]),
                                                refined[0][1] - (y0 + a[0] + v + c[1])) > 2.0:
                refined = None  # ECC wandered off to something else
            better = None if refined is None else warped_patch(source, source_xy, refined[1] @ warp, (w, h))
            if refined is not None and better is not None and float(better.std()) >= MIN_PATCH_STD:
                rescored = np.nan_to_num(cv2.matchTemplate(window, better, cv2.TM_CCOEFF_NORMED), nan=0.0,
                                         posinf=0.0, neginf=0.0)[a[0]:a[1], b[0]:b[1]]
                _, repeak, _, (jx, jy) = cv2.minMaxLoc(rescored)
                if np.hypot(jx - ix, jy - iy) <= 2.0:
                    region, peak, (ix, iy) = rescored, float(repeak), (jx, jy)
                    position, warp = refined[0], refined[1] @ warp
        if peak < params.min_target_ncc:
            why = why or f"the best match of the target's patch scores NCC {peak:.2f} < {params.min_target_ncc}"
            continue
        second = second_peak(region, ix, iy, max(w, h) / 2)
        if second > peak - params.ambiguity_ncc_margin:
            why = (f"the target's patch is ambiguous: two places match it, NCC {peak:.2f} and {second:.2f} "
                   f"(margin {params.ambiguity_ncc_margin})")
            continue
        if position is None:
            u, v = subpixel_peak(region, iy, ix)
            position = (x0 + b[0] + u + c[0], y0 + a[0] + v + c[1])
        return TargetSighting(float(position[0]), float(position[1]), peak, warp), ""
    return None, why


def second_peak(scores: np.ndarray, ix: int, iy: int, min_distance_px: float) -> float:
    """The best local maximum of `scores` farther than `min_distance_px` (half the patch) from
    the peak at (ix, iy), -1 if none: another place matching nearly as well means repetitive
    texture. The peak's own shoulders are no local maxima, and the ripples of a broad peak (a
    smooth patch) lie within half a patch of it, so neither is taken for another place."""
    maxima = (scores >= cv2.dilate(scores, np.ones((3, 3), np.uint8))) & (scores > -1.0)
    ys, xs = np.nonzero(maxima)
    far = np.hypot(xs - ix, ys - iy) > min_distance_px
    return float(scores[ys[far], xs[far]].max()) if np.any(far) else -1.0


def patch_problem(source: np.ndarray, source_xy: tuple[float, float], params: LookParams) -> str:
    """Why the patch around `source_xy` cannot identify the target ('' if it can): beyond the
    image, too flat, or matching another place of its own image within the search radius
    nearly as well (repetitive texture)."""
    source = as_grey_float(source)
    identity = np.eye(2)
    template = warped_patch(source, source_xy, identity, params.target_patch_size)
    if template is None:
        return f"the target's patch at ({source_xy[0]:.1f}, {source_xy[1]:.1f}) reaches beyond the image"
    if float(template.std()) < MIN_PATCH_STD:
        return f"the target's patch at ({source_xy[0]:.1f}, {source_xy[1]:.1f}) has no texture to find it by"
    w, h = params.target_patch_size
    radius = params.search_radius_px if params.search_radius_px is not None else source.shape[1] // 3
    x0 = int(max(0, np.floor(source_xy[0] - radius - w / 2)))
    y0 = int(max(0, np.floor(source_xy[1] - radius - h / 2)))
    window = source[y0:int(np.ceil(source_xy[1] + radius + h / 2)) + 1, x0:int(np.ceil(source_xy[0] + radius + w / 2)) + 1]
    scores = np.nan_to_num(cv2.matchTemplate(window, template, cv2.TM_CCOEFF_NORMED), nan=0.0, posinf=0.0, neginf=0.0)
    _, peak, _, (ix, iy) = cv2.minMaxLoc(scores)
    second = second_peak(scores, ix, iy, max(w, h) / 2)
    if second > peak - params.ambiguity_ncc_margin:
        return (f"the target's patch at ({source_xy[0]:.1f}, {source_xy[1]:.1f}) is ambiguous in its own view: "
                f"another place matches it with NCC {second:.2f} (repetitive texture)")
    return ""


def patch_variants(params: LookParams) -> list[LookParams]:
    """The target's patches a look tries: of `target_patch_size`, or twice it (more context: an
    edge, another texture), whichever identify the target in its own view."""
    w, h = params.target_patch_size
    return [dataclasses.replace(params, target_patch_size=size) for size in ((w, h), (2 * w - 1, 2 * h - 1))]


def target_patch_problem(source: np.ndarray, source_xy: tuple[float, float], params: LookParams) -> str:
    """Why a look cannot find the target at `source_xy` again ('' if it can): neither of its
    patches (`patch_variants`) identifies the target in its own view (`patch_problem`)."""
    problems = [patch_problem(source, source_xy, variant) for variant in patch_variants(params)]
    return "" if "" in problems else problems[0]


def _refine(template: np.ndarray, image: np.ndarray, u: float, v: float,
            ) -> tuple[tuple[float, float], np.ndarray, float] | None:
    """ECC's affine fit of `template` placed with its top-left at (u, v) in `image`: the
    template centre's position, the linear part, the correlation; None if it did not converge."""
    h, w = template.shape
    matrix = np.array([[1.0, 0.0, u], [0.0, 1.0, v]], dtype=np.float32)
    criteria = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 50, 1e-4)
    try:
        # gaussFiltSize 1: no blur, the patch and the image are sharp; typeshed lacks this overload.
        ncc, fitted = cv2.findTransformECC(template.astype(np.float32), image.astype(np.float32), matrix,  # type: ignore[call-overload]
                                           cv2.MOTION_AFFINE, criteria, None, 1)
    except cv2.error:
        return None
    c = np.array([(w - 1) / 2.0, (h - 1) / 2.0])
    fitted = np.asarray(fitted, dtype=float)
    position = fitted[:, :2] @ c + fitted[:, 2]
    return (float(position[0]), float(position[1])), fitted[:, :2], float(ncc)


@dataclass
class LookRecord:
    """Everything about one look: its fixations (the first, then the corrective ones), where the
    target was found after each, and how it ended."""

    target: np.ndarray  # (x, y, d)
    fixations: list[FixationRecord] = field(default_factory=list)
    sightings: list[TargetSighting] = field(default_factory=list)  # after each fixation, while found
    outcome: LookOutcome | FixationOutcome | None = None
    detail: str = ""
    view_restored_deg: float | None = None  # how far the head was from the target's view when the look began
    duration_s: float = 0.0

    @property
    def on_target(self) -> bool:
        return self.outcome is LookOutcome.ON_TARGET

    @property
    def corrective_steps(self) -> int:
        return max(0, len(self.fixations) - 1)

    @property
    def final_error_px(self) -> float | None:
        """Distance of the target from the left fovea after the last step, in its final image;
        None when the target was not found there."""
        if not self.fixations or len(self.sightings) != len(self.fixations):
            return None
        last = self.fixations[-1].final_left_image
        assert last is not None  # a sighting was made in it
        return self.sightings[-1].distance_px(fovea(last))

    @property
    def landing_error_px(self) -> float | None:
        """The first saccade's landing error in the image the target was chosen in: from the
        first fixation's correspondence, only if it was accepted (the fixation taught)."""
        first = self.fixations[0] if self.fixations else None
        if first is None or not first.taught or first.position is None:
            return None
        return float(np.hypot(*(first.position[:2] - self.target[:2])))


class LookController:
    """Closed-loop looks on a `FixationController`'s head and map (see the module doc)."""

    SAME_VIEW_DEG = 0.25  # the head this near the target's reference pose on every axis: the same view

    def __init__(self, fixation: FixationController, params: LookParams | None = None,
                 on_fixation: Callable[[FixationRecord], None] | None = None) -> None:
        self.fixation = fixation
        self.params = params if params is not None else fixation.params.look
        self.on_fixation = on_fixation  # told of each of a look's fixations as it ends
        self.clock = fixation.clock

    def look(self, target: Vector, reference_pose: Vector | None = None) -> LookRecord:
        """Look at an image target (x, y, d) chosen in the view of `reference_pose` (None: the
        head's view now), until it is on the left fovea or the look fails."""
        started = self.clock()
        record = LookRecord(np.asarray(target, dtype=float))
        try:
            self._run(record, reference_pose)
        except FixationInterrupted as err:
            record.outcome, record.detail = err.outcome, str(err)
        except HeadTimeoutError as err:
            record.outcome = FixationOutcome.NO_FRAMES if isinstance(err, PairTimeoutError) \
                else FixationOutcome.NOT_SETTLED
            record.detail = str(err)
        record.duration_s = self.clock() - started
        log.debug("look at %s: %s %s (%d corrective steps, final error %s px)", record.target.tolist(),
                  record.outcome, record.detail, record.corrective_steps, record.final_error_px)
        return record

    def _restore_view(self, record: LookRecord, reference_pose: Vector) -> None:
        head = self.fixation.head
        reference = np.asarray(reference_pose, dtype=float)
        moved = float(np.max(np.abs(head.read_pose() - reference)))
        record.view_restored_deg = moved
        if moved > self.SAME_VIEW_DEG:
            head.move_to(reference)
            head.wait_settled(self.fixation.params.settle_timeout_s)

    def _run(self, record: LookRecord, reference_pose: Vector | None) -> None:
        p = self.params
        if reference_pose is not None:
            self._restore_view(record, reference_pose)
        fixation = self._fixate(record, record.target, reference_pose)
        source = fixation.pre_left_image
        source_xy = (float(record.target[0]), float(record.target[1]))
        warps: list[np.ndarray] | None = None  # the first search tries every candidate warp
        # The target's patch: whichever of `patch_variants` identify the target in its own view;
        # the larger is tried where the smaller is not found again.
        variants = patch_variants(p)
        if source is not None and fixation.final_left_image is not None:
            problems = [patch_problem(source, source_xy, variant) for variant in variants]
            variants = [variant for variant, why in zip(variants, problems) if not why]
            if not variants:
                record.outcome, record.detail = LookOutcome.NO_TARGET_PATCH, problems[0]
                return
        while True:
            final_left = fixation.final_left_image
            if fixation.outcome in _STOPS_A_LOOK or final_left is None or source is None:
                record.outcome, record.detail = fixation.outcome, fixation.detail
                return
            sighting, why = None, ""
            for variant in variants:
                sighting, reason = find_target(source, source_xy, final_left, variant, warps)
                why = why or reason
                if sighting is not None:
                    variants = [variant]  # the same patch from here on, its warp carried over
                    break
            if sighting is None:
                beyond = self._beyond_limits(fixation)
                record.outcome = LookOutcome.OUT_OF_REACH if beyond else LookOutcome.TARGET_LOST
                record.detail = f"{beyond}; {why}" if beyond else why
                return
            record.sightings.append(sighting)
            warps = [sighting.warp]
            error = sighting.distance_px(fovea(final_left))
            mismatch = self._depth_mismatch(record, fixation)
            if error <= p.tolerance_px and mismatch:
                # The patch's look-alike at another depth (a patch across a depth edge, whose two
                # parts moved apart): what the eyes converged on is not the target.
                record.outcome, record.detail = LookOutcome.TARGET_LOST, mismatch
                return
            if error <= p.tolerance_px:
                # On target: the left fovea is the look's reference. Eyes that did not converge
                # (the right eye sees something else there) are said, not corrected for again.
                record.outcome = LookOutcome.ON_TARGET
                record.detail = (f"{error:.2f} px from the fovea after {record.corrective_steps} corrective steps"
                                 + ("" if fixation.converged else f"; the eyes did not converge: {fixation.outcome}"))
                return
            beyond = self._beyond_limits(fixation)
            if beyond:
                record.outcome = LookOutcome.OUT_OF_REACH
                record.detail = f"{error:.2f} px from the fovea; {beyond}"
                return
            if record.corrective_steps >= p.max_corrective_steps:
                record.outcome = LookOutcome.NOT_ON_TARGET
                record.detail = (f"{error:.2f} px from the fovea (tolerance {p.tolerance_px} px) after "
                                 f"{record.corrective_steps} corrective steps")
                return
            d = self._disparity_at(fixation, sighting)
            fixation = self._fixate(record, (sighting.x, sighting.y, d))

    def _fixate(self, record: LookRecord, target: Vector, reference_pose: Vector | None = None) -> FixationRecord:
        fixation = self.fixation.fixate(target, reference_pose)
        record.fixations.append(fixation)
        if self.on_fixation is not None:
            self.on_fixation(fixation)
        return fixation

    def _depth_mismatch(self, record: LookRecord, fixation: FixationRecord) -> str:
        """Why the eyes' final vergence cannot be the target's ('' if it can): converged, it
        differs from the vergence the map gave the first saccade for the target's d by more
        than `max_vergence_mismatch_deg`."""
        first = record.fixations[0]
        if not fixation.converged or fixation.pose_after is None or first.pose_before is None or first.planned is None:
            return ""
        head = self.fixation.head
        meant = float(np.clip(first.pose_before[2] + first.planned[2], head.pose_low[2], head.pose_high[2]))
        off = abs(float(fixation.pose_after[2]) - meant)
        if off <= self.params.max_vergence_mismatch_deg:
            return ""
        return (f"the eyes converged {off:.1f} deg away from the vergence the map gives the target's d "
                f"(max_vergence_mismatch_deg {self.params.max_vergence_mismatch_deg}): another thing at another "
                "depth looks like the target")

    def _beyond_limits(self, fixation: FixationRecord) -> str:
        """Why the fixation's saccade could not go where the map sent it ('' if it could): its
        pan or tilt goal lay beyond the joint limits, so the head stopped at them."""
        if fixation.pose_before is None or fixation.planned is None:
            return ""
        head = self.fixation.head
        goal = fixation.pose_before + fixation.planned
        beyond = [f"{name} {goal[i]:.1f} outside [{head.pose_low[i]:g}, {head.pose_high[i]:g}] deg"
                  for i, name in enumerate(("pan", "tilt"))
                  if not head.pose_low[i] - 0.05 <= goal[i] <= head.pose_high[i] + 0.05]
        return "; ".join(beyond)

    def _disparity_at(self, fixation: FixationRecord, sighting: TargetSighting) -> float:
        """d at the target's new position, measured between the final left and right images as
        fine vergence measures it at the fovea; else what fine vergence left (0 once converged)."""
        left, right = fixation.final_left_image, fixation.final_right_image
        assert left is not None and right is not None
        fp = self.fixation.params
        search = fp.vergence_search_px if fp.vergence_search_px is not None else left.shape[1] // 3
        d, ncc = horizontal_offset(left, right, (sighting.x, sighting.y), fp.vergence_patch_size, (-search, search))
        if ncc >= fp.min_vergence_ncc:
            return d
        if fixation.outcome is FixationOutcome.NOT_CONVERGED and fixation.vergence_disparities_px:
            return fixation.vergence_disparities_px[-1]
        return 0.0
