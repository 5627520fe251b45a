"""Closed-loop looks: a look at an image target ends with the target on the left fovea.

One fixation through the map (`FixationController.fixate`: saccade, fine vergence,
correspondence) brings the target near the foveae, as near as the map is right. A look then
closes the loop on what it sees: the target's patch, taken around (x, y) in the left image just
before the saccade, is found again in the left image after it (`calib_free.gaze.refind`), and
while it lies farther than `LookParams.tolerance_px` from the left fovea a corrective fixation
goes to where it is now -- the map's command for that position and the disparity measured there
(the fovea's, where the target lies so near the fovea the eyes converged on that it shares its
surroundings; d = 0, the depth the eyes fixate, where the measured d would verge them away from
the target's known depth, or the map's command for it turn the head beyond what a step this
short calls for: `calib_free.gaze.step_disparity`) -- up to `max_corrective_steps` of them, and
`finishing_steps` more while the target lies within `finishing_reach_px` of the fovea (the
servos' play can leave it a pixel or two off after a step). Every step is a fixation like any
other: converged and confident, it teaches the map. A saccade the joint limits stopped ends the
look: no correction can go further.

A target is in the view of the pose it was chosen in (`reference_pose`). When the head has
moved since (a queued look), the look first returns to that pose, so that the image before
the saccade is the view the target was chosen in and its patch is the target's. A target
sent without its disparity is looked at with the one measured in that view, else from the
depth the eyes fixate (`calib_free.gaze.target_depth`).

Where the target's patch matches two places of the new image nearly alike (a texture that
repeats), the look takes the one alone near where the fixation is expected to have left the
target. Where the fixation measured where its left fovea landed (its correspondence when that
was accepted, else the left eye's alone: `left_landing_px`), that is the fovea plus the
target's offset from the landing, seen through the patch's warp, within a reach that grows
with the offset (`LANDING_OFFSET_SPREAD`; `calib_free.gaze.refind.find_target`): the landing
says in which direction the saccade missed, not only how far. A repeat within that reach
leaves the patch ambiguous. A corrective step whose landing nothing measured, or whose
measured landing contradicts it, has a reach of its own about the fovea: a step that aimed a
few pixels from the fovea, and that the encoders say went as planned, cannot have left the
target farther than it aimed plus what the head did beyond the plan
(`corrective_step_error_px`). A first saccade whose landing nothing measured is expected to
have left the target within a pixel of the fovea, and farther by what the encoders say went
beyond the plan (`FIRST_SACCADE_ERROR_PX`): a prior among repeats, not a bound. A corrective
step's reach bounds the search after it, not only the choice among repeats: a best match
beyond it is a look-alike, whatever its score. In the realistic world's recorded looks (five
seeds, 116 searches after corrective steps), 3 found the target 12-30 px from the fovea after
steps that could have left it no farther than 2-3 px; the truth put it 0.2-3.4 px away. Where
more than one repeat lies within the reach, the view before the saccade tells them apart where
it shows them around the target (`place_told_by_repeats`). The geometry of these priors and of
the joint limits is `calib_free.gaze.look_geometry`'s.

The first search after the saccade tries only the radial scales of the patch that the looks
on target have found the lens to show at the target's distance from the image centre, once
they have (`calib_free.gaze.magnification`), and every candidate scale where those find
nothing: a look-alike that the patch resembles only when stretched beyond what the lens does
is not taken for the target.

The target not found again, or found where the eyes converged far from the vergence the map
gives the target's d (`max_vergence_mismatch_deg`: a look-alike at another depth; judged only
where d is the target's, given or measured, and the fovea's patch does not repeat along its rows
in the right image, where the right eye may be on a repeat), fails the look saying so. A look
that lost its target or ran out of steps after its first fixation's eyes converged at another
depth than the saccade planned with tries once more from the target's view, at the depth they
found (`calib_free.gaze.second_attempt`); not one that refused a look-alike at another depth. A
look's figures come only from accepted measurements: `final_error_px` from the target found
after the last step, `landing_error_px` from a first fixation whose correspondence was accepted
(it taught).
"""
from __future__ import annotations

import dataclasses
import enum
import logging
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from calib_free.correspondence.disparity import as_grey_float
from calib_free.gaze.fixation import (FixationController, FixationInterrupted, FixationOutcome, FixationRecord,
                                      HeadTimeoutError, LookParams, PairTimeoutError, next_boost)
from calib_free.gaze.look_geometry import (FIRST_SACCADE_ERROR_PX, LANDING_OFFSET_SPREAD, REACH_MARGIN_DEG,
                                           beyond_limits, corrective_step_error_px, foveal_px_per_deg,
                                           left_landing_px)
from calib_free.gaze.magnification import LearnedMagnification, radial_scale
from calib_free.gaze.refind import (MIN_EXPECTED_ERROR_PX, PRIOR_SIGMAS, TargetSighting, fallback_note,
                                    find_first_sighting, find_later_sighting, fovea)
from calib_free.gaze.second_attempt import (depth_found_elsewhere, disparity_for_vergence, target_in_restored_view,
                                            why_again)
from calib_free.gaze.step_disparity import StepDisparity, vergence_search_px
from calib_free.gaze.target_depth import vergence_on_a_repeat
from calib_free.gaze.target_patch import identifying_patches, patch_variants
from calib_free.map.gaze_map import Vector

log = logging.getLogger(__name__)


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


# A target accepted with its patch's std at least min_patch_std in one exposure is judged again
# in the look's own image before the saccade: another exposure, whose contrast may differ by the
# auto exposure's gain between them (up to x1.4, and a lamp or the daylight changing). The look
# takes it as flat only below this fraction of min_patch_std, 4.2 grey levels by default: the
# bare 1.8 n of a webcam's noise n = 2.3, without the third min_patch_std keeps to spare. Less
# would let noise decide: a patch seen at std 4.1 in the look's image, taken, ended counted on
# target 4.7 px truly off in the realistic world.
LOOK_FLAT_FRACTION = 0.7
# Likewise a target accepted with its patch's second place in its own view at least
# ambiguity_ncc_margin below the best is taken as ambiguous in the look's image only where the
# second comes within this fraction of the margin (0.05 by default). The look's view lies within
# `SAME_VIEW_DEG` of the one the target was accepted in, in another exposure: for patches with a
# margin below 0.2, the view's shift moves the margin by p90 0.03, p99 0.07-0.09, and
# the exposure alone (the UVC webcam's) by p90 0.006 (`python -m benchmarks.diag.own_view_margin`,
# docs/results/realistic-world.md). At the full margin, 3 of 200 looks in the realistic world were
# refused after the saccade that had brought the target within 0.5-1.9 px of the fovea.
LOOK_AMBIGUITY_FRACTION = 0.5
# A fixation of a look whose eyes did not converge, and which fine vergence left more than this
# beyond the vergence it planned, has its eyes turned back to that vergence before the target is
# searched for (`LookController._verged_back`): each degree of vergence turns the left eye half
# a degree, 2 px at the fovea of a 320 px wide fish-eye image, and where the eyes converged
# nowhere that turn is no measure of anything, only a widening of where the target may be.
VERGED_BACK_BEYOND_DEG = 2.0


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
    depth_known: bool = True  # d is the target's (given or measured), not the fixation's depth in its stead
    duration_s: float = 0.0
    at_another_depth: bool = False  # lost: what the eyes converged on is at another depth than the target
    first_attempt: LookRecord | None = None  # where this is a second attempt (`calib_free.gaze.second_attempt`)

    @property
    def attempts(self) -> int:
        return 1 if self.first_attempt is None else 1 + self.first_attempt.attempts

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
                 on_fixation: Callable[[FixationRecord], None] | None = None,
                 magnification: LearnedMagnification | None = None) -> None:
        self.fixation = fixation
        self.params = params if params is not None else fixation.params.look
        self.on_fixation = on_fixation  # told of each of a look's fixations as it ends
        # The lens's magnification as the looks on target found it, which the first search of
        # every look narrows its scales by (`calib_free.gaze.magnification`).
        self.magnification = magnification if magnification is not None else LearnedMagnification()
        self.step_disparity = StepDisparity(fixation, self.params)  # the d each corrective step takes
        self.clock = fixation.clock

    def look(self, target: Vector, reference_pose: Vector | None = None, depth_known: bool = True) -> LookRecord:
        """Look at an image target (x, y, d) chosen in the view of `reference_pose` (None: the
        head's view now), until it is on the left fovea or the look fails. `depth_known`
        False: d is not the target's (it could not be measured,
        `calib_free.gaze.target_depth.target_disparity`), so the eyes' final vergence is not
        held against it."""
        started = self.clock()
        record = LookRecord(np.asarray(target, dtype=float), depth_known=depth_known)
        try:
            self._run(record, reference_pose)
            again = self._second_attempt(record, reference_pose)
            if again is not None:
                record, reference = again
                self._run(record, reference)
                first = record.first_attempt
                assert first is not None
                record.view_restored_deg = first.view_restored_deg  # the look's, not the return to its view
                record.detail = f"{record.detail} ({why_again(first.fixations[0], record.target[2], first.outcome)})"
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

    def _second_attempt(self, record: LookRecord,
                        reference_pose: Vector | None) -> tuple[LookRecord, np.ndarray] | None:
        """The look's second attempt, ready to run from the view its target was chosen in, and
        that view's pose; None where the first attempt ended otherwise than lost or off the
        fovea, or lost as a look-alike at another depth (a second attempt at that depth would
        take what the first refused), or its first fixation's eyes converged at the vergence
        its saccade planned, or the map gives no d for the vergence they converged at, or the
        target's patch is not found again in the restored view
        (`calib_free.gaze.second_attempt`)."""
        if record.outcome not in (LookOutcome.TARGET_LOST, LookOutcome.NOT_ON_TARGET) or record.at_another_depth \
                or not record.fixations:
            return None
        first, head = record.fixations[0], self.fixation.head
        converged = depth_found_elsewhere(first, float(head.pose_low[2]), float(head.pose_high[2]))
        source = first.pre_left_image
        if converged is None or source is None or first.pose_before is None:
            return None
        reference = np.asarray(reference_pose if reference_pose is not None else first.pose_before, dtype=float)
        xy = (float(record.target[0]), float(record.target[1]))
        d = disparity_for_vergence(self.fixation.map, reference, xy, converged)
        if d is None:
            return None
        head.move_to(reference)
        left, _ = head.wait_pair(head.wait_settled(self.fixation.params.settle_timeout_s),
                                 self.fixation.params.frame_timeout_s)
        found = target_in_restored_view(source, xy, as_grey_float(left), self.params.target_patch_size)
        if found is None:
            log.debug("look at %s: no second attempt, the target's patch is not in the restored view", xy)
            return None
        again = LookRecord(np.array([found[0], found[1], d]), depth_known=False, first_attempt=record)
        return again, reference

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
        source_xy = (float(record.target[0]), float(record.target[1]))
        # The target's patch: whichever of `patch_variants` identify the target in its own view
        # (`identifying_patches`); the larger is tried where the smaller is not found again.
        # Judged again in the look's own image before the saccade (another exposure than the
        # one the target was accepted in), with the slack of `LOOK_FLAT_FRACTION` and
        # `LOOK_AMBIGUITY_FRACTION`; refused there, the head does not move.
        p = dataclasses.replace(p, min_patch_std=LOOK_FLAT_FRACTION * p.min_patch_std)
        judged = dataclasses.replace(p, ambiguity_ncc_margin=LOOK_AMBIGUITY_FRACTION * p.ambiguity_ncc_margin)
        variants = patch_variants(p)

        def identifies_target(source: np.ndarray) -> str:
            nonlocal variants
            usable, why = identifying_patches(source, source_xy, judged)
            variants = [dataclasses.replace(v, ambiguity_ncc_margin=p.ambiguity_ncc_margin) for v in usable]
            return "" if usable else why

        fixation = self._fixate(record, record.target, reference_pose, target_check=identifies_target)
        if fixation.outcome is FixationOutcome.TARGET_REFUSED:
            record.outcome, record.detail = LookOutcome.NO_TARGET_PATCH, fixation.detail
            return
        source = fixation.pre_left_image
        warps: list[np.ndarray] | None = None  # the first search tries every candidate warp
        last_offset: np.ndarray | None = None  # where the target was from the fovea before the last step
        step_aim_px: float | None = None  # how far from the fovea the last corrective step aimed
        target_before = np.array(source_xy)  # where the target was in the last fixation's image before it
        to_source = np.eye(2)  # the linear warp from that image to `source` (the patch's own view)
        boost = 1.0
        while True:
            if fixation.outcome in _STOPS_A_LOOK or fixation.final_left_image is None or source is None:
                record.outcome, record.detail = fixation.outcome, fixation.detail
                return
            fixation = record.fixations[-1] = self._verged_back(fixation)
            final_left = fixation.final_left_image
            assert final_left is not None  # a pair taken after the eyes turned back, if they did
            sighting, why = None, ""
            step = None if step_aim_px is None else self._corrective_step_error_px(fixation, step_aim_px)
            expected, offset = self._landing_prior(fixation, target_before, to_source, step,
                                                   first=step_aim_px is None)
            if warps is None:
                sighting, variant, why = find_first_sighting(source, source_xy, final_left, variants,
                                                             self.magnification, expected, offset)
                if sighting is not None:
                    variants = [variant]  # the same patch from here on, its warp carried over
            else:
                sighting, _, why = find_later_sighting(source, source_xy, final_left, variants, warps, expected, offset,
                                                       step)
            if sighting is None:
                beyond = self._beyond_limits(fixation)
                record.outcome = LookOutcome.OUT_OF_REACH if beyond else LookOutcome.TARGET_LOST
                record.detail = f"{beyond}; {why}" if beyond else why
                return
            record.sightings.append(sighting)
            warps = [sighting.warp]
            error = sighting.distance_px(fovea(final_left))
            mismatch, depth_note = self._depth_mismatch(record, fixation)
            if error <= p.tolerance_px and mismatch:
                # The patch's look-alike at another depth (a patch across a depth edge, whose two
                # parts moved apart): what the eyes converged on is not the target.
                record.outcome, record.detail, record.at_another_depth = LookOutcome.TARGET_LOST, mismatch, True
                return
            if error <= p.tolerance_px:
                # On target: the left fovea is the look's reference. Eyes that did not converge
                # (the right eye sees something else there) are said, not corrected for again.
                record.outcome = LookOutcome.ON_TARGET
                first = record.sightings[0]
                self.magnification.record(float(np.hypot(*(np.asarray(source_xy) - fovea(source)))),
                                          radial_scale(first.warp, source_xy, fovea(source)))
                record.detail = (f"{error:.2f} px from the fovea after {record.corrective_steps} corrective steps"
                                 + fallback_note(record.sightings)
                                 + ("" if fixation.converged else f"; the eyes did not converge: {fixation.outcome}")
                                 + depth_note)
                return
            beyond = self._beyond_limits(fixation)
            if beyond:
                record.outcome = LookOutcome.OUT_OF_REACH
                record.detail = f"{error:.2f} px from the fovea; {beyond}"
                return
            finishing = p.finishing_steps if error <= p.finishing_reach_px else 0
            if record.corrective_steps >= p.max_corrective_steps + finishing:
                record.outcome = LookOutcome.NOT_ON_TARGET
                record.detail = (f"{error:.2f} px from the fovea (tolerance {p.tolerance_px} px) after "
                                 f"{record.corrective_steps} corrective steps")
                return
            # A step that left the target where it was: the next aims farther beyond the fovea.
            # Where it was, not how far: a step that carried the target across the fovea to as
            # far the other side was made, and a longer one would only carry it farther.
            cx, cy = fovea(final_left)
            seen_at = np.array([sighting.x - cx, sighting.y - cy])
            boost = next_boost(boost, None if last_offset is None else float(np.hypot(*(seen_at - last_offset))))
            last_offset = seen_at
            aim_x, aim_y = cx + boost * seen_at[0], cy + boost * seen_at[1]
            step_aim_px = float(np.hypot(aim_x - cx, aim_y - cy))
            target_before, to_source = np.array([sighting.x, sighting.y]), np.linalg.inv(sighting.warp)
            d = self.step_disparity.for_step(fixation, sighting, (aim_x, aim_y), self._target_vergence(record))
            fixation = self._fixate(record, (aim_x, aim_y, d), continues=True)

    def _verged_back(self, fixation: FixationRecord) -> FixationRecord:
        """`fixation`, or, where its eyes did not converge and fine vergence left them more than
        `VERGED_BACK_BEYOND_DEG` from the vergence its saccade (or step) planned, the same
        fixation with the eyes turned back to that vergence (the head's limits clamp it) and the
        pair taken there at rest. Fine vergence that converged nowhere (a flat face, a depth
        edge, a repeat along the rows) wandered: in two seeds of recorded offline looks in the
        realistic world (`benchmarks.diag.offline_steps`), 7 of the 20 first saccades whose
        eyes ended 3 deg or more from the plan had not converged, and 6 of those looks failed,
        lost among repeats within the prior that the turn widened (the left eye turns half the
        vergence) or left off the fovea. Turned back, the left eye sees the target where the
        saccade put it, and the prior is the saccade's own. Its correspondence is dropped: the
        left eye's landing is matched again in the new image (`left_landing_px`)."""
        if fixation.converged or fixation.pose_before is None or fixation.pose_after is None \
                or fixation.planned is None:
            return fixation
        planned = float(fixation.pose_before[2] + fixation.planned[2])
        wandered = float(fixation.pose_after[2]) - planned
        if abs(wandered) <= VERGED_BACK_BEYOND_DEG:
            return fixation
        head, p = self.fixation.head, self.fixation.params
        commanded = head.verge_to(planned)
        left, right = head.wait_pair(head.wait_settled(p.settle_timeout_s), p.frame_timeout_s)
        log.debug("fixation %d: eyes not converged %.1f deg from the planned vergence, turned back to %.1f deg",
                  fixation.index, wandered, commanded)
        return dataclasses.replace(
            fixation, pose_after=head.read_pose(), match=None,
            final_left_image=as_grey_float(left), final_right_image=as_grey_float(right),
            detail=f"{fixation.detail}; the eyes turned back from {wandered:+.1f} deg beyond the planned "
                   f"vergence to {commanded:.1f} deg")

    def _landing_prior(self, fixation: FixationRecord, target_before: np.ndarray, to_source: np.ndarray,
                       step: float | None = None,
                       first: bool = False) -> tuple[float | None, tuple[float, float] | None]:
        """Where `fixation` is expected to have left the target, for the search after it: (the
        expected error, the target's expected offset from the fovea), both in `source`'s
        pixels, or (None, None) where nothing says.

        Where the fixation measured where its left fovea landed (`left_landing_px`), the target
        is expected at its offset from that landing (`target_before` less the landing, carried
        into `source`'s pixels by `to_source`), to within `LANDING_OFFSET_SPREAD` of it: the
        measured landing says in which direction the saccade missed as well as how far. A
        corrective step has a prior of its own, about the fovea: its `corrective_step_error_px`
        (`step`; None for the first fixation, or where it cannot be told). It bounds the
        measured landing too: a landing that puts the target beyond `PRIOR_SIGMAS` times it
        from the fovea contradicts what the encoders say the step did (a left eye's match that
        was confident but wrong, hundreds of pixels off in the realistic world), and the step's
        own prior is used; and it bounds the search (`search_target`'s `step_error_px`). The
        `first` fixation, the saccade, has a prior about the fovea where its landing was not
        measured: `FIRST_SACCADE_ERROR_PX` and what the encoders say went beyond the plan. The
        map's recent landing errors are no stand-in: a fixation whose correspondence was refused
        went otherwise than the map's typical one (a depth not measured, eyes that did not
        converge), and with them a look took a nearby repeat for the target in 5 of 100 random
        pixels (`benchmarks.bench.looks`, docs/results/looks.md)."""
        p = self.fixation.params
        landed = left_landing_px(fixation, p.correspondence, p.confidence_floor)
        if landed is not None:
            offset = to_source @ (np.asarray(target_before, dtype=float) - landed)
            distance = float(np.hypot(*offset))
            if step is None or distance <= PRIOR_SIGMAS * max(MIN_EXPECTED_ERROR_PX, step):
                return LANDING_OFFSET_SPREAD * distance, (float(offset[0]), float(offset[1]))
        if first:
            return self._corrective_step_error_px(fixation, FIRST_SACCADE_ERROR_PX), None
        return step, None

    def _corrective_step_error_px(self, fixation: FixationRecord, step_aim_px: float) -> float | None:
        """`corrective_step_error_px` of a corrective fixation that aimed `step_aim_px` from the
        fovea, with the map's pixels a degree at the fovea (`foveal_px_per_deg`); None where the
        map cannot say or the fixation's poses were not read."""
        if fixation.pose_before is None or fixation.pose_after is None or fixation.planned is None:
            return None
        height, width = (fixation.final_left_image.shape[:2] if fixation.final_left_image is not None
                         else (0, 0))
        px_per_deg = foveal_px_per_deg(self.fixation.map, fixation.pose_before, (width, height))
        if px_per_deg is None:
            return None
        return corrective_step_error_px(step_aim_px, fixation.pose_after - fixation.pose_before, fixation.planned,
                                        px_per_deg)

    def _fixate(self, record: LookRecord, target: Vector, reference_pose: Vector | None = None,
                continues: bool = False, target_check: Callable[[np.ndarray], str] | None = None) -> FixationRecord:
        fixation = self.fixation.fixate(target, reference_pose, continues, target_check)
        record.fixations.append(fixation)
        if self.on_fixation is not None:
            self.on_fixation(fixation)
        return fixation

    def _depth_mismatch(self, record: LookRecord, fixation: FixationRecord) -> tuple[str, str]:
        """(Why the eyes' final vergence cannot be the target's, '' if it can; what an on-target
        look says of it). Converged, it differs from the vergence the map gave the first saccade
        for the target's d (`_target_vergence`) by more than `max_vergence_mismatch_deg`: what
        the left eye sees is a look-alike at another depth. Not judged where d was not the
        target's: the vergence the map gives d = 0 is the depth the eyes fixated before, not the
        target's (in the realistic world every such look refused so was truly on target,
        docs/results/realistic-world.md). Nor where the fovea's patch repeats along its rows in
        the right image (`vergence_on_a_repeat`): the right eye may be on a repeat, which moves
        the vergence by a repeat's disparity whatever the left eye sees; the look then ends on
        the left fovea, its reference, and says so (in the benchmark runs the looks refused as at
        another depth were all but one truly on target, most on such a patch: docs/method.md)."""
        meant = self._target_vergence(record)
        if meant is None or not fixation.converged or fixation.pose_after is None:
            return "", ""
        off = abs(float(fixation.pose_after[2]) - meant)
        if off <= self.params.max_vergence_mismatch_deg:
            return "", ""
        converged = (f"the eyes converged {off:.1f} deg away from the vergence the map gives the target's d "
                     f"(max_vergence_mismatch_deg {self.params.max_vergence_mismatch_deg})")
        repeat = self._vergence_on_a_repeat(fixation)
        if repeat:
            return "", f"; {converged}: {repeat}"
        return (f"{converged}: another thing at another depth looks like the target, or the map's vergence for "
                "it is that far off (a young map's; a later look may end on it)"), ""

    def _vergence_on_a_repeat(self, fixation: FixationRecord) -> str:
        """`vergence_on_a_repeat` in the fixation's final pair, with fine vergence's patch and search."""
        left, right = fixation.final_left_image, fixation.final_right_image
        if left is None or right is None:
            return ""
        fp = self.fixation.params
        search = vergence_search_px(self.fixation, left.shape[1])
        return vergence_on_a_repeat(left, right, fp.vergence_patch_size, search,
                                    self.fixation.row_offset_px, fp.correspondence.stereo_rival_margin)

    def _target_vergence(self, record: LookRecord) -> float | None:
        """The vergence (deg) the map gave the first saccade for the target's d, within the joint
        limits: the target's depth as the look knows it. None where d was not the target's
        (`depth_known` False) or the first fixation's pose or plan was not read."""
        first = record.fixations[0]
        if not record.depth_known or first.pose_before is None or first.planned is None:
            return None
        head = self.fixation.head
        return float(np.clip(first.pose_before[2] + first.planned[2], head.pose_low[2], head.pose_high[2]))

    def _beyond_limits(self, fixation: FixationRecord) -> str:
        """Why the fixation's saccade could not go where the map sent it ('' if it could): its
        pan or tilt goal lay beyond the joint limits, so the head stopped at them."""
        if fixation.pose_before is None or fixation.planned is None:
            return ""
        head = self.fixation.head
        return beyond_limits(fixation.pose_before + fixation.planned, head.pose_low, head.pose_high, REACH_MARGIN_DEG)
