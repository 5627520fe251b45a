"""The disparity a look's corrective step takes (`StepDisparity.for_step`).

A corrective step is a fixation aimed at where the target is now, (x, y) in the left image,
with a disparity d the map turns into the step's command. The d measured at the target in the
final pair is the first candidate; what the eyes converged on, the target's known depth, the
map's reach in d and the vergence's joint limits decide whether the step takes it, the one fine
vergence left at the fovea, d = 0 (the depth the eyes fixate), or the d that verges the eyes
back to the target's depth.
"""
from __future__ import annotations

import logging

import numpy as np

from calib_free.correspondence.disparity import horizontal_offset
from calib_free.errors import OutOfRangeError
from calib_free.gaze.fixation import FixationController, FixationOutcome, FixationRecord, LookParams
from calib_free.gaze.look_geometry import (REACH_MARGIN_DEG, STEP_DEPTH_TOLERANCE_DEG, foveal_px_per_deg,
                                           shares_the_fovea, step_turn_bound_deg, vergence_goal)
from calib_free.gaze.refind import TargetSighting, fovea
from calib_free.gaze.second_attempt import disparity_for_vergence

log = logging.getLogger(__name__)


def vergence_search_px(fixation: FixationController, width: int) -> int:
    """How far either side of the right fovea fine vergence looks (`vergence_search_px`, else
    a third of the image's width)."""
    search = fixation.params.vergence_search_px
    return search if search is not None else width // 3


class StepDisparity:
    """Chooses d for the corrective steps of looks run through `fixation` with `params`."""

    def __init__(self, fixation: FixationController, params: LookParams) -> None:
        self.fixation = fixation
        self.params = params

    def for_step(self, fixation: FixationRecord, sighting: TargetSighting, aim: tuple[float, float],
                 target_vergence: float | None) -> float:
        """d for a corrective step aimed at `aim` from the target's `sighting` in `fixation`'s
        final pair, for a target whose depth the map gives the vergence `target_vergence` (deg;
        None where the look does not know it): the fovea's, where the sighting is near enough
        the fovea the eyes converged on (`_foveal`); else the one measured there, held to the
        target's depth (`_held`: d = 0 after eyes that converged there, the d that verges them
        back to it after eyes that did not converge); d = 0, the depth the eyes fixate, where
        the map's command for it would turn the head beyond what the step calls for
        (`_turn_beyond_step`) or verge the eyes beyond the vergence's limits
        (`_verges_beyond_range`)."""
        foveal = self._foveal(fixation, sighting)
        d = foveal if foveal is not None else self._held(fixation, sighting, aim, target_vergence)
        beyond = "" if d == 0.0 else self._turn_beyond_step(fixation, aim, d) or self._verges_beyond_range(
            fixation, aim, d)
        if beyond:
            log.debug("corrective step at (%.1f, %.1f): %s: d 0", aim[0], aim[1], beyond)
            return 0.0
        return d

    def measured_at(self, fixation: FixationRecord, sighting: TargetSighting) -> float:
        """d at the target's new position, measured between the final left and right images as
        fine vergence measures it at the fovea; else what fine vergence left (0 once converged).
        A d beyond the map's disparity range is no measurement, measured or left: a target a few
        pixels from the foveae the eyes converged on is near their depth, and such a d is a
        look-alike; and the map has no command for it (in the ideal world two looks of 674
        failed so, fine vergence having left 75 and 101 px)."""
        left, right = fixation.final_left_image, fixation.final_right_image
        assert left is not None and right is not None
        fp = self.fixation.params
        search = vergence_search_px(self.fixation, left.shape[1])
        d, ncc = horizontal_offset(left, right, (sighting.x, sighting.y), fp.vergence_patch_size, (-search, search),
                                   fp.vergence_band_px)

        def in_map(disparity: float) -> bool:
            return not self.fixation.map.check_position((sighting.x, sighting.y, disparity))

        if ncc >= fp.min_vergence_ncc and in_map(d):
            return d
        left_by_vergence = fixation.vergence_disparities_px[-1] if fixation.vergence_disparities_px else 0.0
        if fixation.outcome is FixationOutcome.NOT_CONVERGED and in_map(left_by_vergence):
            return left_by_vergence
        return 0.0

    def _foveal(self, fixation: FixationRecord, sighting: TargetSighting) -> float | None:
        """The disparity fine vergence left at the fovea, where `fixation` converged and the
        target's `sighting` lies so near the fovea that the fine vergence patch about it mostly
        covers the fovea's (`shares_the_fovea`): what the eyes fixate is the target's
        surroundings, at the target's depth. A disparity measured there that differs by pixels
        is the right eye's match on something else (a repeat along the rows; the realistic
        world's webcams that differ in roll and focal length), and a step that planned with it
        verges the eyes away, fine vergence verges them back and turns the left eye off the
        target by half of it. None where that does not hold."""
        if not fixation.converged or not fixation.vergence_disparities_px or fixation.final_left_image is None:
            return None
        cx, cy = fovea(fixation.final_left_image)
        offset = (sighting.x - cx, sighting.y - cy)
        if not shares_the_fovea(offset, self.fixation.params.vergence_patch_size):
            return None
        return float(fixation.vergence_disparities_px[-1])

    def _turn_beyond_step(self, fixation: FixationRecord, aim: tuple[float, float], d: float) -> str:
        """Why the map's command for the step (`aim`, d), from where `fixation` left the head,
        is not the step's ('' if it may be): it turns pan and tilt beyond `step_turn_bound_deg`.
        A d the map has few samples near (a near thing's large disparity, or a repeat's) is
        where its command goes astray: in the realistic world a d of 58 px measured 1.6 px from
        the fovea turned the pan 9.7 deg with a vergence change of 3.6, and left the target 47
        px off. Not judged where the map cannot say its pixels a degree at the fovea."""
        pose, image = fixation.pose_after, fixation.final_left_image
        if pose is None or image is None:
            return ""
        height, width = image.shape[:2]
        px_per_deg = foveal_px_per_deg(self.fixation.map, pose, (width, height))
        if px_per_deg is None:
            return ""
        try:
            command = self.fixation.map.command((*aim, d), pose=pose)
        except OutOfRangeError:
            return ""
        cx, cy = fovea(image)
        aim_px = float(np.hypot(aim[0] - cx, aim[1] - cy))
        turn = float(np.hypot(command[0], command[1]))
        bound = step_turn_bound_deg(aim_px, float(command[2]), px_per_deg)
        if turn <= bound:
            return ""
        return (f"d {d:.1f} px: the map's command turns the head {turn:.1f} deg, beyond the {bound:.1f} deg a step "
                f"aimed {aim_px:.1f} px from the fovea with a vergence change of {float(command[2]):.1f} deg calls for")

    def _verges_beyond_range(self, fixation: FixationRecord, aim: tuple[float, float], d: float) -> str:
        """Why the map's command for the step (`aim`, d), from where `fixation` left the head,
        cannot be the step's ('' if it may be): it verges the eyes more than `REACH_MARGIN_DEG`
        beyond the vergence's joint limits. The head stops the vergence at its limit, while
        the command's pan and tilt keep the left eye's direction only for the whole vergence
        change: the left eye turns by half of what the limit cut off, degrees for a d of tens of
        pixels, and the step leaves the target farther than it found it. No depth the eyes can
        verge to is that d's: a look-alike's, or the right eye's on something else."""
        pose = fixation.pose_after
        if pose is None:
            return ""
        verged = vergence_goal(self.fixation.map, pose, (*aim, d))
        low, high = float(self.fixation.head.pose_low[2]), float(self.fixation.head.pose_high[2])
        if verged is None or low - REACH_MARGIN_DEG <= verged <= high + REACH_MARGIN_DEG:
            return ""
        return f"d {d:.1f} px: the map's command verges the eyes at {verged:.1f} deg, outside [{low:g}, {high:g}] deg"

    def _held(self, fixation: FixationRecord, sighting: TargetSighting, aim: tuple[float, float],
              target_vergence: float | None) -> float:
        """d for a corrective step aimed at `aim` from the target's `sighting`: the one measured
        there (`measured_at`), unless the eyes converged at the target's depth (within
        `STEP_DEPTH_TOLERANCE_DEG` of `target_vergence`) and the map would verge them with the
        measured d farther from it than that, at another depth than the target's. Such a
        d is the right eye's match on a repeat of the texture along its rows, and the map turns
        the head with the vergence it gives it (the left eye keeps its direction only if the
        head turns by about half the vergence's change): in the realistic world's recorded
        looks (seven recordings, 460 looks taken on), 13 corrective steps took a d of 10 px or
        more, 10 of them left the target 3 px or more off the fovea, and 2 of their 13 looks
        ended on target. The step then takes d = 0: the depth the eyes fixate, the target's.
        Where they converged elsewhere, the target's d itself is in doubt (measured on a
        repeat before the look, say), and the step keeps what it measured.

        Where the eyes did not converge, fine vergence left them wherever its last step did,
        and the right eye's match at the target is on whatever it sees there: a measured d the
        map would verge farther than `STEP_DEPTH_TOLERANCE_DEG` from the target's depth is
        replaced by the d whose command verges the eyes back to it (`disparity_for_vergence`;
        kept where the map has none). In the realistic world's offline looks (two seeds, 437
        corrective steps), 17 of the 31 steps that followed eyes not converged with a d so far
        from the target's depth left the target 3 px or more off and farther than before, and 4
        of the 31 belonged to looks that ended on target."""
        d = self.measured_at(fixation, sighting)
        pose = fixation.pose_after
        if target_vergence is None or pose is None:
            return d
        tolerance = STEP_DEPTH_TOLERANCE_DEG
        verged = vergence_goal(self.fixation.map, pose, (*aim, d))
        if not fixation.converged:
            if verged is not None and abs(verged - target_vergence) <= tolerance:
                return d
            back = disparity_for_vergence(self.fixation.map, pose, aim, target_vergence)
            if back is None:
                return d
            log.debug("corrective step at (%.1f, %.1f) after eyes that did not converge: d %.1f px would verge them "
                      "at %s deg, the target's depth at %.1f: d %.1f", aim[0], aim[1], d,
                      "?" if verged is None else f"{verged:.1f}", target_vergence, back)
            return back
        if abs(pose[2] - target_vergence) > tolerance or verged is None or abs(verged - target_vergence) <= tolerance:
            return d
        log.debug("corrective step at (%.1f, %.1f): d %.1f px would verge the eyes at %.1f deg, the target's "
                  "depth and the eyes' at %.1f and %.1f deg: d 0", aim[0], aim[1], d, verged, target_vergence,
                  pose[2])
        return 0.0
