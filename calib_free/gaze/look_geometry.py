"""What a look knows of its fixations' motion, images aside: whether a saccade's goal lay beyond
the joint limits, where a fixation is expected to have left the target (the landing its left
eye measured, or the error a saccade or a corrective step is expected to have), and how far a
corrective step may turn the head. `calib_free.gaze.look` closes the loop with them; the
service's API refuses a look whose saccade would go beyond the limits with `beyond_limits`."""
from __future__ import annotations

import numpy as np

from calib_free.correspondence.search import CorrespondenceParams, match_eye
from calib_free.errors import OutOfRangeError
from calib_free.gaze.fixation import FixationRecord, MapReader
from calib_free.map.gaze_map import Vector

# A saccade's pan or tilt goal beyond the joint limits by more than this (a servo's tick, 0.088
# deg, rounded down) stops the head at the limit. Its target then stays off the fovea: in the
# real-time looks benchmark every look whose first saccade the map sent 0.13-0.83 deg beyond
# ended 3-13 px off it (5 of 5, both worlds, docs/results/realistic-world.md), farther than
# the 4 px a degree at the fovea would say (the map is least sure at the edges of its range).
REACH_MARGIN_DEG = 0.05
# Where a fixation measured where its fovea landed, the target is expected at the fovea plus its
# offset from that landing, seen through the patch's warp; expected to within this fraction of
# the offset: the warp is the lens's at the target, the landing lies that far from it, and the
# lens's magnification changes across the way (`calib_free.gaze.refind.search_target`).
LANDING_OFFSET_SPREAD = 0.15
# A first saccade whose landing nothing measured (its correspondence refused and the left eye's
# own match not confident: on a repeated texture, mostly) is expected to have left the target
# this near the fovea, and farther by what the encoders say the head did beyond the plan
# (`corrective_step_error_px`: fine vergence after the saccade turns the left eye by half its
# change); a prior to tell repeats apart, not a bound on the search. In the realistic world's
# recorded looks such saccades truly left the target p50 0.61 / p90 2.0 px from the fovea where
# fine vergence took no step. Searched again with a prior of 3 px about the fovea, 288 recorded
# first searches without a measured landing (six recordings, both worlds) found the target in 11
# that had found nothing or a repeat, and a repeat in none; one of 6 px found one more and took a
# repeat for the target in two (`benchmarks.diag.ambiguous_places`, docs/results/realistic-world.md).
FIRST_SACCADE_ERROR_PX = 1.0
# A corrective step's command turning pan and tilt farther than this many times what the step
# calls for (its aim's offset from the fovea, and half its vergence change: the left eye turns
# by half of it, which the head makes up for), plus the slack, is the map's beyond what it
# learned, and the step takes d = 0 (`step_turn_bound_deg`). In the realistic world's recorded
# corrective steps (eight recordings, 566 steps), at the 4 px a degree the steps show at the
# fovea, 5 turned beyond it and no other: each had measured d 16 or 58 px 1.5-2.4 px from the
# fovea, turned the head 1.9-11.9 deg, and left the target 6-57 px off.
STEP_TURN_FACTOR = 2.0
STEP_TURN_SLACK_DEG = 0.5
# A corrective step's target this near the fovea the eyes converged on -- the fine vergence
# patch about it covering at least this fraction of the fovea's -- is at the fovea's depth: the
# step takes the disparity fine vergence left there, not one measured at the target
# (`shares_the_fovea`). In eleven recordings of the realistic world's looks, of 155 such steps
# that planned with the d measured at the target, 16 had |d| of 2 px or more; fine vergence
# turned back at least half the vergence they planned in 10, and 6 of the 16 left the target
# within 1 px of the fovea, against 112 of the 135 with |d| below 1 px
# (`benchmarks.diag.step_disparity`, docs/results/realistic-world.md).
FOVEA_SHARED_FRACTION = 0.8
# A corrective step's measured d that the map would verge farther than this from the target's
# depth is taken for the right eye's match on a repeat or on something else, and the step keeps
# the eyes at the target's depth instead (`calib_free.gaze.step_disparity`); so are eyes that
# converged this near the target's depth taken as at it. Tighter than the look's own judgement
# of where the eyes ended (`LookParams.max_vergence_mismatch_deg`): a step that keeps the depth
# loses nothing where the measured d was right, one that follows a repeat's d turns the head
# away (the recordings cited in `StepDisparity._held`).
STEP_DEPTH_TOLERANCE_DEG = 3.0
# The map's pan for targets this far either side of the fovea gives its pixels a degree there
# (`foveal_px_per_deg`); a slope outside the plausible range (a young map) gives none.
FOVEAL_SPAN_PX = 10.0
PLAUSIBLE_PX_PER_DEG = (0.5, 50.0)


def beyond_limits(goal: np.ndarray, low: np.ndarray, high: np.ndarray, margin_deg: float) -> str:
    """Which of a saccade's pan and tilt goals (`goal`, a pose) lie more than `margin_deg`
    beyond the limits `low`, `high`, said ('' if none)."""
    beyond = [f"{name} {goal[i]:.1f} outside [{low[i]:g}, {high[i]:g}] deg"
              for i, name in enumerate(("pan", "tilt"))
              if not low[i] - margin_deg <= goal[i] <= high[i] + margin_deg]
    return "; ".join(beyond)


def left_landing_px(fixation: FixationRecord, params: CorrespondenceParams,
                    confidence_floor: float) -> np.ndarray | None:
    """Where the left fovea landed, in the image before `fixation`: the position (x, y) there of
    what its final left image shows at the fovea. From the fixation's correspondence where it
    taught; else from the left eye's alone (`match_eye`) where that is confident (at least
    `confidence_floor`): a fixation that taught nothing (its eyes did not converge, or the right
    eye's match was refused) may still say where the left eye went. A look finds its target in
    the left image, so this is the landing that tells the target from a repeat of its texture.
    None when not measured. A fixation that converged but was refused matched its left eye so
    already: that match is taken, not made again."""
    pre, post = fixation.pre_left_image, fixation.final_left_image
    if pre is None or post is None:
        return None
    if fixation.taught and fixation.position is not None:
        return np.asarray(fixation.position[:2], dtype=float)
    match = fixation.match.left if fixation.match is not None else match_eye(pre, post, params)
    if not match.confidence >= confidence_floor:  # NaN: not measured
        return None
    return np.array([match.x, match.y])


def foveal_px_per_deg(gaze_map: MapReader, pose: np.ndarray, image_size: tuple[int, int]) -> float | None:
    """Pixels of image motion at the fovea a degree of pan turns, as the map has learned it: the
    pan it commands for targets `FOVEAL_SPAN_PX` either side of the fovea, seen at `pose`; None
    where the map does not cover them or learned no plausible slope (a young map)."""
    width, height = image_size
    if width <= 0 or height <= 0:
        return None
    cx, cy = (width - 1) / 2.0, (height - 1) / 2.0
    try:
        pan = [float(gaze_map.command((cx + side * FOVEAL_SPAN_PX, cy, 0.0), pose=pose)[0]) for side in (-1, 1)]
    except OutOfRangeError:
        return None
    turn_deg = abs(pan[1] - pan[0])
    px_per_deg = 2 * FOVEAL_SPAN_PX / turn_deg if turn_deg > 0 else float("inf")
    return px_per_deg if PLAUSIBLE_PX_PER_DEG[0] <= px_per_deg <= PLAUSIBLE_PX_PER_DEG[1] else None


def shares_the_fovea(offset_px: tuple[float, float], patch_size: tuple[int, int]) -> bool:
    """Whether a patch of `patch_size` (width, height) `offset_px` (x, y) from the fovea covers
    at least `FOVEA_SHARED_FRACTION` of the one about the fovea."""
    shared = [max(0.0, 1.0 - abs(offset) / size) for offset, size in zip(offset_px, patch_size)]
    return shared[0] * shared[1] >= FOVEA_SHARED_FRACTION


def corrective_step_error_px(aim_px: float, moved: np.ndarray, planned: np.ndarray, px_per_deg: float) -> float:
    """How far from the fovea a corrective fixation is expected to have left the target, where
    it was not measured: as far as the step aimed (`aim_px`, from the fovea: a step that did
    nothing leaves the target there, one the map misjudged by a fraction of itself nearer), and
    farther by what the encoders say the head did beyond the plan (`moved` against `planned`,
    both (pan, tilt, vergence) in deg): pan and tilt, and half the vergence, which turns the
    left eye by half its change (fine vergence after the step), at `px_per_deg`. A repeat of
    the target's texture several times that far from the fovea is not where a step this short
    took it."""
    beyond = np.asarray(moved, dtype=float) - np.asarray(planned, dtype=float)
    return float(aim_px + px_per_deg * (np.hypot(beyond[0], beyond[1]) + abs(beyond[2]) / 2.0))


def step_turn_bound_deg(aim_px: float, vergence_change_deg: float, px_per_deg: float) -> float:
    """How far (deg, pan and tilt together) the command of a corrective step aimed `aim_px`
    from the fovea, with a vergence change `vergence_change_deg`, may turn the head: the turn
    that brings the aim to the fovea at `px_per_deg`, and half the vergence change (the head
    keeps the left eye's direction against it), `STEP_TURN_FACTOR` times, plus
    `STEP_TURN_SLACK_DEG`."""
    return STEP_TURN_FACTOR * (aim_px / px_per_deg + abs(vergence_change_deg) / 2.0) + STEP_TURN_SLACK_DEG


def vergence_goal(gaze_map: MapReader, pose: np.ndarray, target: Vector) -> float | None:
    """The vergence (deg) the map's command for `target` (x, y, d), seen at `pose`, ends at;
    None where the map does not cover it."""
    try:
        return float(pose[2] + gaze_map.command(target, pose=pose)[2])
    except OutOfRangeError:
        return None
