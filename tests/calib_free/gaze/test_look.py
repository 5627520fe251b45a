"""Closed-loop looks (calib_free.gaze.look, calib_free.gaze.refind) on a head looking at a textured plane.

The plane head (`tests.support.planar_head`) knows exactly where every texel of the plane is
in its images, so a look's figures are checked against the truth, not against themselves.
"""
from __future__ import annotations

import dataclasses

import cv2
import numpy as np
import pytest
import yaml

from calib_free.correspondence.search import EyeMatch, FixationMatch
from calib_free.errors import TargetPatchError
from calib_free.gaze.look import VERGED_BACK_BEYOND_DEG, LookController, LookOutcome, LookRecord
from calib_free.gaze.look_geometry import (corrective_step_error_px, foveal_px_per_deg, left_landing_px,
                                           shares_the_fovea, step_turn_bound_deg, vergence_goal)
from calib_free.gaze.target_depth import target_disparity, vergence_on_a_repeat
from calib_free.gaze.refind import TargetSearch, TargetSighting, find_target, nearer_of_two_patches, search_target
from calib_free.gaze.target_patch import identifying_patches, own_view_peaks, patch_problem, target_patch_problem
from calib_free.gaze.fixation import (FixationController, FixationKind, FixationOutcome, FixationParams,
                                      FixationRecord, LookParams)
from headctl.config.head import load_config
from headctl.errors import ConfigError
from tests.support import CONFIGS
from tests.support.planar_head import HEIGHT, PX_PER_DEG, WIDTH, LinearMap, PlanarHead, rich_texture

FOVEA = np.array([(WIDTH - 1) / 2, (HEIGHT - 1) / 2])


class Learner:
    def __init__(self) -> None:
        self.samples = []

    def submit(self, sample) -> None:
        self.samples.append(sample)


def looker(head, gain=0.8, params=None, **look):
    learner = Learner()
    fixation = params or FixationParams()
    controller = FixationController(head, LinearMap(gain), fixation, seed=0, learner=learner)
    return LookController(controller, LookParams(**look) if look else None), learner


def true_error_px(head, texel) -> float:
    """How far the texel chosen as target is from the left fovea at the head's pose now."""
    return float(np.hypot(*(head.image_position(texel) - FOVEA)))


def test_a_look_corrects_until_the_target_is_on_the_fovea_and_every_step_teaches():
    head = PlanarHead()
    controller, learner = looker(head, gain=0.8)  # every saccade falls 20 % short
    target = (262.0, 58.0)
    texel = head.texel_at(target)
    record = controller.look((*target, 0.0))
    assert record.outcome is LookOutcome.ON_TARGET and record.on_target
    assert 1 <= record.corrective_steps <= 3
    assert true_error_px(head, texel) <= 1.0  # the truth, not the look's own figure
    assert record.final_error_px == pytest.approx(true_error_px(head, texel), abs=0.3)
    assert all(f.taught for f in record.fixations) and len(learner.samples) == len(record.fixations)
    # The open-loop figure is the first saccade's: 20 % of the way short, in the target's image.
    assert record.landing_error_px == pytest.approx(0.2 * np.hypot(*(np.array(target) - FOVEA)), rel=0.15)


class FramedHead(PlanarHead):
    """A plane head whose camera exposes a new pair every 1/30 s of its own clock: a pair asked
    for after a time no held pair was exposed after costs a frame. At rest since its last move,
    it answers `wait_settled` with the time now, or with `same_rest` that rest's time."""

    FRAME_S = 1.0 / 30.0

    def __init__(self) -> None:
        super().__init__()
        self.now_s = 0.0
        self.rest_s = 0.0
        self.exposed_s = -1.0  # the pair held
        self.exposures = 0

    def move_to(self, pose: np.ndarray) -> np.ndarray:
        self.now_s += 0.1
        self.rest_s = self.now_s
        return super().move_to(pose)

    def wait_settled(self, timeout_s: float, same_rest: bool = False) -> float:
        self.now_s += 0.01  # the time the fixation before took to judge its last pair
        return self.rest_s if same_rest else self.now_s

    def wait_pair(self, after_s: float, timeout_s: float) -> tuple[np.ndarray, np.ndarray]:
        if self.exposed_s < after_s:
            self.now_s = self.exposed_s = max(after_s, self.exposed_s) + self.FRAME_S
            self.exposures += 1
        return super().wait_pair(after_s, timeout_s)


def test_a_step_that_carried_the_target_across_the_fovea_is_not_taken_for_one_not_made():
    """The saccade leaves the target 3 px right of the fovea; the first corrective step turns
    the head twice as far as commanded (play taken up at once), carrying the target 3 px left:
    as far from the fovea as before, but moved. The next step goes as planned, not twice as
    long, and the look ends on target after it."""
    head = PlanarHead()
    target = (236.0, 84.0)
    texel = head.texel_at(target)
    before: list[np.ndarray] = []

    def unruly(h) -> None:
        if len(h.moves) == 1:
            h.pose[0] += 0.75  # the target 3 px right of the fovea (pan + moves the view left)
        elif len(h.moves) == 2:
            h.pose[:2] = before[0][:2] + 2.0 * (h.pose[:2] - before[0][:2])
        before[:] = [h.pose.copy()]

    head.on_move = unruly
    controller, _ = looker(head, gain=1.0)
    record = controller.look((*target, 0.0))
    assert [round(float(s.x - FOVEA[0]), 1) for s in record.sightings[:2]] == [3.0, -3.0]
    assert record.on_target and record.corrective_steps == 2, record.detail
    assert true_error_px(head, texel) <= 1.0


def test_a_corrective_step_starts_from_the_pair_its_target_was_found_in():
    """Every pair but the look's first is one exposed after a move: a corrective fixation, aimed
    from the pair its target was just found in, waits for no new one before it moves."""
    head = FramedHead()
    controller, _ = looker(head, gain=0.8)
    record = controller.look((262.0, 58.0, 0.0))
    assert record.on_target and record.corrective_steps >= 1
    assert head.exposures == len(head.moves) + 1


def test_a_look_whose_map_is_right_needs_no_corrective_step():
    head = PlanarHead()
    controller, _ = looker(head, gain=1.0)
    record = controller.look((90.0, 170.0, 0.0))
    assert record.on_target and record.corrective_steps == 0 and record.final_error_px <= 1.0
    assert record.landing_error_px == pytest.approx(record.final_error_px, abs=0.5)


def test_a_look_stops_after_its_corrective_steps_and_fails_saying_where_the_target_is():
    head = PlanarHead()
    controller, _ = looker(head, gain=0.3, max_corrective_steps=2)  # a map far too timid
    texel = head.texel_at((290.0, 200.0))
    record = controller.look((290.0, 200.0, 0.0))
    assert record.outcome is LookOutcome.NOT_ON_TARGET and not record.on_target
    assert record.corrective_steps == 2
    assert record.final_error_px == pytest.approx(true_error_px(head, texel), abs=0.5)
    assert record.final_error_px > 1.0 and "px from the fovea" in record.detail


def test_a_target_occluded_after_the_saccade_is_not_found_again_and_no_error_is_reported():
    head = PlanarHead()
    target = (250.0, 170.0)
    u, v = (int(round(c)) for c in head.texel_at(target))

    def cover(h) -> None:  # something grey moves in front of the target once the head has moved
        if len(h.moves) == 1:
            h.plane = h.plane.copy()
            h.plane[v - 40:v + 40, u - 40:u + 40] = 128.0

    head.on_move = cover
    controller, _ = looker(head, gain=0.8)
    record = controller.look((*target, 0.0))
    assert record.outcome is LookOutcome.TARGET_LOST and not record.on_target
    assert "NCC" in record.detail or "texture" in record.detail
    assert record.final_error_px is None and record.sightings == []
    assert record.corrective_steps == 0  # nothing to correct towards


def test_a_refused_correspondence_never_gives_the_landing_error():
    head = PlanarHead()
    params = FixationParams(confidence_floor=1.0)  # no correspondence is ever confident enough
    controller, learner = looker(head, gain=0.8, params=params)
    record = controller.look((240.0, 80.0, 0.0))
    assert all(f.outcome is FixationOutcome.LOW_CONFIDENCE for f in record.fixations)
    assert record.fixations[0].position is not None  # a correspondence was computed...
    assert record.landing_error_px is None  # ...but refused: it is not the look's error
    assert learner.samples == []
    # The target was found and corrected for all the same: the head is on it.
    assert record.on_target and record.final_error_px <= 1.0


def test_a_repetitive_target_is_refused_for_want_of_a_patch_that_identifies_it():
    plane = rich_texture()
    stripes = 128 + 80 * np.sign(np.sin(2 * np.pi * np.arange(plane.shape[1]) / 9.0))
    plane[:, :] = stripes[None, :].astype(np.float32)  # vertical stripes everywhere
    head = PlanarHead(plane)
    controller, _ = looker(head)
    record = controller.look((200.0, 100.0, 0.0))
    assert record.outcome is LookOutcome.NO_TARGET_PATCH and "ambiguous" in record.detail
    assert record.final_error_px is None


def test_a_target_beyond_the_joint_limits_fails_saying_so():
    head = PlanarHead(pose=(-39.0, 0.0, 8.0))  # at the right end of pan
    controller, _ = looker(head, gain=1.0)
    record = controller.look((300.0, 120.0, 0.0))  # 35 deg further right
    assert record.outcome is LookOutcome.OUT_OF_REACH and "pan" in record.detail
    assert all(np.all(m >= head.pose_low) and np.all(m <= head.pose_high) for m in head.moves)


def test_a_queued_look_returns_to_the_view_its_target_was_chosen_in():
    head = PlanarHead()
    reference = head.read_pose()
    target = (220.0, 150.0)
    texel = head.texel_at(target)
    head.move_to(np.array([12.0, -7.0, 8.0]))  # the head moved on before the look ran
    controller, _ = looker(head, gain=0.9)
    record = controller.look((*target, 0.0), reference_pose=reference)
    assert record.view_restored_deg == pytest.approx(12.0)
    assert np.allclose(head.moves[1], reference)  # back first, then the saccade
    assert record.on_target and true_error_px(head, texel) <= 1.0


def test_a_cancelled_look_ends_with_the_interruption():
    from calib_free.gaze.fixation import FixationInterrupted

    head = PlanarHead()

    def cancel(h) -> None:
        if len(h.moves) == 2:
            raise FixationInterrupted(FixationOutcome.CANCELLED, "look 1 stopped: cancelled by a client")

    head.on_move = cancel
    controller, _ = looker(head, gain=0.5)
    record = controller.look((280.0, 200.0, 0.0))
    assert record.outcome is FixationOutcome.CANCELLED and not record.on_target


def test_the_target_is_found_through_a_fish_eye_like_magnification():
    image = rich_texture(seed=3, size=(WIDTH, HEIGHT))
    source_xy = (262.3, 71.6)
    # The patch comes to the fovea magnified 1.7x along the radius, 1.05x across it, and lands
    # at a known point: an affine warp of the whole image about the target.
    radial = (np.array(source_xy) - FOVEA) / np.hypot(*(np.array(source_xy) - FOVEA))
    rotation = np.column_stack([radial, [-radial[1], radial[0]]])
    linear = rotation @ np.diag([1.7, 1.05]) @ rotation.T
    landed = FOVEA + np.array([3.4, -2.2])
    matrix = np.hstack([linear, (landed - linear @ np.array(source_xy))[:, None]])
    after = cv2.warpAffine(image, matrix, (WIDTH, HEIGHT), flags=cv2.INTER_LINEAR)
    sighting, why = find_target(image, source_xy, after, LookParams())
    assert why == "" and sighting is not None
    assert np.hypot(sighting.x - landed[0], sighting.y - landed[1]) <= 0.3
    assert np.allclose(sighting.warp, linear, atol=0.1)


def test_a_flat_or_clipped_patch_cannot_identify_a_target():
    image = np.full((HEIGHT, WIDTH), 90.0, np.float32)
    assert "no texture" in patch_problem(image, (100.0, 100.0), LookParams())
    assert "beyond the image" in patch_problem(rich_texture(size=(WIDTH, HEIGHT)), (3.0, 100.0), LookParams())


def test_look_params_are_checked_and_read_from_the_fixation_section(tmp_path):
    with pytest.raises(ValueError, match="tolerance_px"):
        LookParams(tolerance_px=0.0)
    with pytest.raises(ValueError, match="max_corrective_steps"):
        LookParams(max_corrective_steps=-1)
    with pytest.raises(ValueError, match="finishing_steps"):
        LookParams(finishing_steps=-1)
    with pytest.raises(ValueError, match="finishing_reach_px must be at least tolerance_px"):
        LookParams(tolerance_px=1.0, finishing_reach_px=0.5)
    data = yaml.safe_load((CONFIGS / "sim.yaml").read_text())
    data["fixation"]["look"] = {"tolerance_px": 0.5, "max_corrective_steps": 5}
    path = tmp_path / "head.yaml"
    path.write_text(yaml.safe_dump(data))
    look = load_config(path).fixation.params.look
    assert (look.tolerance_px, look.max_corrective_steps) == (0.5, 5)
    data["fixation"]["look"] = {"tolerance_px": -1}
    path.write_text(yaml.safe_dump(data))
    with pytest.raises(ConfigError, match="fixation.look.tolerance_px: got -1"):
        load_config(path)


def test_a_look_alike_at_another_depth_is_not_taken_for_the_target():
    head = PlanarHead()  # the whole plane is at one depth: d = 0 at the start pose
    controller, _ = looker(head, gain=1.0)
    record = controller.look((200.0, 100.0, 40.0))  # told the target is 40 px of disparity farther
    # The eyes converge on the plane, 8 deg of vergence from what the map gives d = 40 px.
    assert record.fixations[-1].converged
    assert record.outcome is LookOutcome.TARGET_LOST and "another depth" in record.detail
    assert "or the map's vergence for it is that far off" in record.detail
    assert not record.on_target


def test_eyes_that_converged_as_far_from_the_targets_depth_as_a_young_maps_vergence_errs_end_on_target():
    """After 5 minutes of exploring, the map's vergence for a target's d can be 4-7 deg off
    where the left eye is on the target: not another depth."""
    head = PlanarHead()
    controller, _ = looker(head, gain=1.0)
    record = controller.look((200.0, 100.0, 22.0))  # 4.4 deg of vergence from the plane the eyes converge on
    assert record.fixations[-1].converged
    assert record.outcome is LookOutcome.ON_TARGET, record.detail


class RowRepeatHead(PlanarHead):
    """A plane head whose right eye sees, `REPEAT_PX` along its rows from the left fovea's
    content, a copy of that content's surroundings with noise (NCC about 0.97 against the true
    place's 1): texture repeating along the rows wherever the head looks."""

    REPEAT_PX = -50

    def wait_pair(self, after_s: float, timeout_s: float) -> tuple[np.ndarray, np.ndarray]:
        left, right = super().wait_pair(after_s, timeout_s)
        u, v = int(round(FOVEA[0])), int(round(FOVEA[1]))
        source = left[v - 16:v + 17, u - 24:u + 25]
        noise = np.random.default_rng(1).normal(0.0, 0.25 * float(source.std()), source.shape)
        at = u + int(round(self.disparity_px())) + self.REPEAT_PX
        right = right.copy()
        right[v - 16:v + 17, at - 24:at + 25] = source + noise.astype(np.float32)
        return left, right


def test_eyes_at_another_depth_on_a_patch_repeating_along_its_rows_end_the_look_on_the_left_fovea():
    """The target told at the d of its repeat 50 px along the right image's rows: the saccade
    verges the eyes 10 deg nearer than the plane, where the repeat lies at the right fovea, and
    fine vergence takes them back to the plane (the truer match). As with a look-alike, the
    eyes end 10 deg from the vergence the map gives the told d, but the fovea's patch repeats
    along its rows, so the vergence may be a repeat's and does not say the left eye sees a
    look-alike: the look ends on target, truly, and says why the vergence differs."""
    head = RowRepeatHead()
    controller, _ = looker(head, gain=1.0)
    target = (200.0, 100.0)
    texel = head.texel_at(target)
    record = controller.look((*target, -50.0))
    assert record.fixations[-1].converged
    assert record.outcome is LookOutcome.ON_TARGET and record.on_target
    assert true_error_px(head, texel) <= 1.0
    assert "deg away from the vergence the map gives the target's d" in record.detail
    assert "repeats along its rows in the right image" in record.detail


def test_the_vergence_may_be_a_repeats_only_where_the_foveas_patch_repeats_along_the_rows():
    left = rich_texture(seed=4, size=(WIDTH, HEIGHT))
    right = np.roll(left, 4, axis=1)
    assert vergence_on_a_repeat(left, right, (32, 20), 106) == ""
    twice = with_a_copy_beside(right, FOVEA + np.array([4.0, 0.0]), (-40, 0), size=41)
    assert "repeats along its rows" in vergence_on_a_repeat(left, twice, (32, 20), 106)
    assert vergence_on_a_repeat(left, twice, (32, 20), 30) == ""  # the repeat beyond the search
    below = with_a_copy_beside(right, FOVEA + np.array([4.0, 0.0]), (-40, 24), size=41)
    assert vergence_on_a_repeat(left, below, (32, 20), 106) == ""  # a repeat on other rows


def test_a_target_is_looked_at_with_its_measured_disparity_else_from_the_fixation_depth():
    left = rich_texture(seed=4, size=(WIDTH, HEIGHT))
    measured = target_disparity(left, np.roll(left, 6, axis=1), 150.0, 110.0, (32, 20), (-60.0, 60.0), LookParams())
    assert measured.measured and measured.d == pytest.approx(6.0, abs=0.3) and measured.reason == ""
    unmeasured = target_disparity(left, rich_texture(seed=5, size=(WIDTH, HEIGHT)), 150.0, 110.0, (32, 20),
                                  (-60.0, 60.0), LookParams())
    assert not unmeasured.measured and unmeasured.ncc is None and unmeasured.d == 0.0
    assert unmeasured.reason.startswith("the disparity at (150, 110) could not be measured")
    assert unmeasured.reason.endswith(": looked at from the depth the eyes fixate (d = 0)")


def test_a_targets_disparity_is_measured_about_the_rows_vergence_found_the_pair_misaligned_by():
    """Two real cameras' optical centres differ by some rows: the right image 12 rows lower
    than the left, 8 more than the rows searched either side."""
    left = rich_texture(seed=4, size=(WIDTH, HEIGHT))
    right = np.roll(np.roll(left, 6, axis=1), 12, axis=0)
    assert not target_disparity(left, right, 150.0, 110.0, (32, 20), (-60.0, 60.0), LookParams()).measured
    found = target_disparity(left, right, 150.0, 110.0, (32, 20), (-60.0, 60.0), LookParams(), row_offset_px=12.0)
    assert found.measured and found.d == pytest.approx(6.0, abs=0.3)


def test_a_corrective_step_takes_no_disparity_beyond_the_maps_range():
    """Where a target a few pixels from the converged foveae matches the right image 90 px
    away (a look-alike: the map's range ends at 60 px), the step aims at the eyes' depth."""
    head = PlanarHead()
    controller, _ = looker(head, gain=1.0)
    left = rich_texture(seed=4, size=(WIDTH, HEIGHT))
    sighting = TargetSighting(162.0, 121.0, 0.95, np.eye(2))
    fixation = FixationRecord(0, FixationKind.TARGET, target=np.array([162.0, 121.0, 0.0]), converged=True,
                              outcome=FixationOutcome.TAUGHT)
    fixation.final_left_image = left
    fixation.final_right_image = np.roll(left, 12, axis=1)
    assert controller.step_disparity.measured_at(fixation, sighting) == pytest.approx(12.0, abs=0.3)
    fixation.final_right_image = np.roll(left, 90, axis=1)
    controller.fixation.params = dataclasses.replace(controller.fixation.params, vergence_search_px=120)
    assert controller.step_disparity.measured_at(fixation, sighting) == 0.0


@pytest.mark.parametrize("left_by_vergence, step_d", [(25.0, 25.0), (90.0, 0.0)])
def test_a_step_after_eyes_that_did_not_converge_takes_what_vergence_left_within_the_maps_range(left_by_vergence,
                                                                                               step_d):
    """The right image matches nothing at the target (NCC below the floor): the step takes the
    disparity fine vergence left, unless that lies beyond the map's range (60 px), where the
    map has no command for it and the step would fail as outside the map."""
    controller, _ = looker(PlanarHead(), gain=1.0)
    left = rich_texture(seed=4, size=(WIDTH, HEIGHT))
    sighting = TargetSighting(162.0, 121.0, 0.95, np.eye(2))
    fixation = FixationRecord(0, FixationKind.TARGET, target=np.array([162.0, 121.0, 0.0]), converged=False,
                              outcome=FixationOutcome.NOT_CONVERGED, vergence_disparities_px=[40.0, left_by_vergence])
    fixation.final_left_image, fixation.final_right_image = left, rich_texture(seed=5, size=(WIDTH, HEIGHT))
    assert controller.step_disparity.measured_at(fixation, sighting) == step_d


class MapBeyondItsSamples(LinearMap):
    """A linear map that, for a |d| beyond 30 px (where it learned nothing), turns the pan a
    degree more for every pixel further: what a map's polynomial does off its samples."""

    def command(self, position, pose=None) -> np.ndarray:
        command = super().command(position, pose)
        command[0] += max(0.0, abs(float(position[2])) - 30.0)
        return command


class MapKeepingTheLeftEye(LinearMap):
    """A linear map whose pan turns by half the vergence change, as a real head's does: the
    left eye turns with half of it, and the head makes that up to keep the eye's direction."""

    def command(self, position, pose=None) -> np.ndarray:
        command = super().command(position, pose)
        command[0] += command[2] / 2.0
        return command


@pytest.mark.parametrize("gaze_map, shift_px, step_d", [
    (LinearMap(1.0), 12, 12.0),  # a d the map has learned: taken as measured
    (MapBeyondItsSamples(1.0), 12, 12.0),  # the same map within its samples
    (MapKeepingTheLeftEye(1.0), 45, 45.0),  # a large d: the head turns 4.5 deg with the vergence, as it must
    (MapBeyondItsSamples(1.0), 45, 0.0),  # a large d the map would turn the head 15 deg for
])
def test_a_corrective_step_takes_no_disparity_whose_command_turns_the_head_beyond_the_step(gaze_map, shift_px,
                                                                                        step_d):
    """A target 2.2 px from the fovea after a fixation whose eyes did not converge, where the
    right image matches it `shift_px` px to the right. The step aims 0.6 deg of pan away and
    the vergence 9 deg at most (4.5 for the left eye): a command that turns the head 15 deg is
    the map's beyond its samples, and the step takes d = 0 instead."""
    head = PlanarHead()
    controller, _ = looker(head, gain=1.0)
    controller.fixation.map = gaze_map
    left = rich_texture(seed=4, size=(WIDTH, HEIGHT))
    sighting = TargetSighting(FOVEA[0] + 2.0, FOVEA[1] + 1.0, 0.95, np.eye(2))
    fixation = FixationRecord(0, FixationKind.TARGET, target=np.array([200.0, 100.0, 0.0]), converged=False,
                              outcome=FixationOutcome.NO_VERGENCE_MATCH, pose_after=np.array([0.0, 0.0, 12.0]))
    fixation.final_left_image, fixation.final_right_image = left, np.roll(left, shift_px, axis=1)
    controller.fixation.params = dataclasses.replace(controller.fixation.params, vergence_search_px=80)
    aim = (sighting.x, sighting.y)
    assert controller.step_disparity.for_step(fixation, sighting, aim, None) == pytest.approx(step_d, abs=0.3)


@pytest.mark.parametrize("vergence_deg, step_d", [
    (12.0, 45.0),  # the map verges the eyes 9 deg, to 3: within the limits [1, 20]
    (10.2, 45.0),  # to 1.2: within
    (9.5, 0.0),  # to 0.5: the vergence stops at 1 and the left eye turns by half the cut
    (8.0, 0.0),  # to -1
])
def test_a_corrective_step_takes_no_disparity_that_verges_the_eyes_beyond_their_limits(vergence_deg, step_d):
    """The right image matches the target 45 px to the right, which the map verges the eyes 9
    deg for, turning the head by half of it to keep the left eye's direction. Where that
    vergence lies beyond the joint limits the head stops it there, the left eye turns by half
    of what was cut off, and the step takes d = 0 instead."""
    head = PlanarHead()
    controller, _ = looker(head, gain=1.0)
    controller.fixation.map = MapKeepingTheLeftEye(1.0)
    left = rich_texture(seed=4, size=(WIDTH, HEIGHT))
    sighting = TargetSighting(FOVEA[0] + 2.0, FOVEA[1] + 1.0, 0.95, np.eye(2))
    fixation = FixationRecord(0, FixationKind.TARGET, target=np.array([200.0, 100.0, 0.0]), converged=False,
                              outcome=FixationOutcome.NO_VERGENCE_MATCH,
                              pose_after=np.array([0.0, 0.0, vergence_deg]))
    fixation.final_left_image, fixation.final_right_image = left, np.roll(left, 45, axis=1)
    controller.fixation.params = dataclasses.replace(controller.fixation.params, vergence_search_px=80)
    assert controller.step_disparity.for_step(fixation, sighting, (sighting.x, sighting.y), None) == \
        pytest.approx(step_d, abs=0.3)


@pytest.mark.parametrize("converged, offset_px, step_d", [
    (True, (2.0, 1.0), 0.4),  # near the fovea the eyes converged on: what fine vergence left there
    (True, (9.0, 0.0), 6.0),  # the fine vergence patch about it covers 72 % of the fovea's: measured
    (True, (0.0, 4.5), 6.0),  # 77 % of it, a patch 20 px high: measured
    (False, (2.0, 1.0), 6.0),  # eyes that did not converge fixate nothing to go by: measured
])
def test_a_corrective_step_near_the_fovea_the_eyes_converged_on_takes_the_foveas_disparity(converged, offset_px,
                                                                                          step_d):
    """The right image matches the target 6 px to the right, though fine vergence left 0.4 px at
    the fovea a few pixels away: a step from there plans with the fovea's 0.4, not 6 px that
    would verge the eyes away for fine vergence to verge them back."""
    head = PlanarHead()
    controller, _ = looker(head, gain=1.0)
    left = rich_texture(seed=4, size=(WIDTH, HEIGHT))
    sighting = TargetSighting(FOVEA[0] + offset_px[0], FOVEA[1] + offset_px[1], 0.95, np.eye(2))
    fixation = FixationRecord(0, FixationKind.TARGET, target=np.array([200.0, 100.0, 0.0]), converged=converged,
                              outcome=FixationOutcome.TAUGHT if converged else FixationOutcome.NOT_CONVERGED,
                              pose_after=np.array([0.0, 0.0, 8.0]), vergence_disparities_px=[3.0, 0.4])
    fixation.final_left_image, fixation.final_right_image = left, np.roll(left, 6, axis=1)
    assert controller.step_disparity.for_step(fixation, sighting, (sighting.x, sighting.y), None) == \
        pytest.approx(step_d, abs=0.3)
    assert shares_the_fovea((-3.0, 0.0), (32, 20)) and not shares_the_fovea((40.0, 30.0), (32, 20))


@pytest.mark.parametrize("target_vergence, step_d", [
    (None, 6.0),  # the target's depth not known: measured
    (7.0, 6.0),  # the measured d verges the eyes to 6.8 deg, within 3 of the target's depth: measured
    (12.0, -20.0),  # 5.2 deg from it: the d that verges them back to 12, from 8
    (2.0, 30.0),  # and to 2
])
def test_a_corrective_step_after_eyes_that_did_not_converge_verges_them_back_to_the_targets_depth(
        target_vergence, step_d):
    """Fine vergence that did not converge left the eyes at 8 deg, and the right image matches
    the target 6 px to the right (the map: -0.2 deg of vergence a pixel of d, to 6.8 deg). Where
    that is farther from the target's depth than `STEP_DEPTH_TOLERANCE_DEG`, it is what the
    right eye found on something else, wherever the eyes wandered; the step verges them back to
    the target's depth instead."""
    head = PlanarHead()
    controller, _ = looker(head, gain=1.0)
    left = rich_texture(seed=4, size=(WIDTH, HEIGHT))
    sighting = TargetSighting(FOVEA[0] + 12.0, FOVEA[1] + 5.0, 0.95, np.eye(2))
    fixation = FixationRecord(0, FixationKind.TARGET, target=np.array([200.0, 100.0, 0.0]), converged=False,
                              outcome=FixationOutcome.NOT_CONVERGED, pose_after=np.array([0.0, 0.0, 8.0]),
                              vergence_disparities_px=[9.0, 7.0])
    fixation.final_left_image, fixation.final_right_image = left, np.roll(left, 6, axis=1)
    aim = (sighting.x, sighting.y)
    assert controller.step_disparity.for_step(fixation, sighting, aim, target_vergence) == \
        pytest.approx(step_d, abs=0.3)


class WanderingVergenceHead(PlanarHead):
    """A plane head whose left eye turns with half the vergence (its view moves `PX_PER_DEG / 2`
    px a degree of vergence from the one at the vergence it started at), and whose right eye
    sees the left eye's view `aside_px` aside whatever the vergence: fine vergence never
    converges and runs the eyes off towards their limit."""

    def __init__(self, aside_px: float = 12.0) -> None:
        super().__init__()
        self.start_vergence = float(self.pose[2])
        self.aside_px = aside_px

    def view_centre(self, pose: np.ndarray | None = None) -> np.ndarray:
        pose = self.pose if pose is None else pose
        return super().view_centre(pose) + np.array([PX_PER_DEG * (pose[2] - self.start_vergence) / 2, 0.0])

    def wait_pair(self, after_s: float, timeout_s: float) -> tuple[np.ndarray, np.ndarray]:
        cx, cy = self.view_centre()
        left = cv2.getRectSubPix(self.plane, (WIDTH, HEIGHT), (float(cx), float(cy)))
        right = cv2.getRectSubPix(self.plane, (WIDTH, HEIGHT), (float(cx) + self.aside_px, float(cy)))
        return left, right


def test_eyes_that_wandered_without_converging_are_turned_back_before_the_target_is_searched_for():
    """The map's saccade is exact and keeps the vergence; fine vergence then runs the eyes 12
    deg off without converging, which turns the left eye 6 deg (24 px) away from the target,
    and once the head moved a copy of the target's surroundings lies 48 px beside it. Nothing
    measures where the saccade landed (the left eye's own match is not trusted here): searched
    where the eyes wandered, both places lie within the prior the wandering widened, and the
    look would fail as ambiguous. It turns the eyes back to the vergence the saccade planned,
    and finds the target where the saccade put it: on the fovea, no corrective step."""
    head = WanderingVergenceHead()
    target = (236.0, 84.0)
    texel = head.texel_at(target)
    head.on_move = repeat_after_the_first_move(texel, (48, 0))
    controller, _ = looker(head, gain=1.0, params=FixationParams(confidence_floor=1.0))
    record = controller.look((*target, 0.0))
    first = record.fixations[0]
    assert first.outcome is FixationOutcome.NOT_CONVERGED
    assert any(abs(pose[2] - head.start_vergence) > 10.0 for pose in head.moves)  # it did wander
    assert "turned back" in first.detail and first.pose_after[2] == pytest.approx(head.start_vergence)
    assert record.on_target and record.corrective_steps == 0, record.detail
    assert true_error_px(head, texel) <= 1.0


def test_eyes_that_did_not_converge_near_the_planned_vergence_are_left_where_they_are():
    """Fine vergence that ended within `VERGED_BACK_BEYOND_DEG` of the plan moved the left eye
    less than a repeat could hide in: no extra move. (One step of fine vergence, 6 px of
    disparity at the map's 0.2 deg a pixel: 1.2 deg.)"""
    head = WanderingVergenceHead(aside_px=6.0)
    controller, _ = looker(head, gain=1.0, params=FixationParams(max_vergence_steps=1))
    record = controller.look((236.0, 84.0, 0.0))
    first = record.fixations[0]
    assert first.outcome is FixationOutcome.NOT_CONVERGED
    assert 0.0 < abs(first.pose_after[2] - head.start_vergence) <= VERGED_BACK_BEYOND_DEG
    assert "turned back" not in first.detail


def test_a_steps_turn_bound_is_twice_its_aims_turn_and_half_its_vergence_change_with_slack():
    assert step_turn_bound_deg(8.0, 0.0, 4.0) == pytest.approx(2 * 2.0 + 0.5)
    assert step_turn_bound_deg(8.0, -3.0, 4.0) == pytest.approx(2 * (2.0 + 1.5) + 0.5)


class RightEyeSeesTheTargetElsewhere(PlanarHead):
    """A plane head whose right image shows the surroundings of `texel` 40 px to the left of
    where the plane's depth puts them (a repeat of its texture along the rows, say) while the
    texel lies more than 30 px from the fovea: a disparity measured there is -40 px, though the
    whole plane, and the texel, is at one depth. The fovea's surroundings stay as they are."""

    def __init__(self, texel: np.ndarray) -> None:
        super().__init__()
        self.texel = texel

    def wait_pair(self, after_s: float, timeout_s: float) -> tuple[np.ndarray, np.ndarray]:
        left, right = super().wait_pair(after_s, timeout_s)
        x, y = (int(round(v)) for v in self.image_position(self.texel))
        if self.moves and abs(x - FOVEA[0]) > 30 and x >= 70:
            right = right.copy()
            right[y - 20:y + 20, x - 70:x - 10] = left[y - 20:y + 20, x - 30:x + 30]
        return left, right


@pytest.mark.parametrize("told_d, depth_known, step_d", [
    (0.0, True, 0.0),  # the eyes converged at the target's depth: the step keeps them there
    (0.0, False, -40.0),  # no depth to hold the measurement to
    (30.0, True, -40.0),  # the eyes converged 4.5 deg from the d told: that d is in doubt
])
def test_a_corrective_step_keeps_the_eyes_at_the_targets_depth_against_a_repeats_disparity(told_d, depth_known,
                                                                                           step_d):
    """The first saccade (a map 25 % short) leaves the target 35 px from the fovea, where the
    right image shows its texture 40 px off, though the whole plane is at one depth. The
    target's d told and the eyes converged at the plane's depth (d 0): the step takes d = 0,
    not the -40 px that would verge the eyes 6 deg nearer and turn the head with them."""
    target = (FOVEA[0] - 140.0, FOVEA[1])
    head = RightEyeSeesTheTargetElsewhere(PlanarHead().texel_at(target))
    controller, _ = looker(head, gain=0.75, max_corrective_steps=5)
    record = controller.look((*target, told_d), depth_known=depth_known)
    first, step = record.fixations[0], record.fixations[1]
    assert first.converged and first.pose_after is not None
    assert abs(true_error_px_at(head, first.pose_after, target) - 35.0) <= 1.0
    assert step.target[2] == pytest.approx(step_d, abs=0.5)
    if step_d == 0.0:
        assert record.on_target, record.detail


def true_error_px_at(head: PlanarHead, pose: np.ndarray, target: tuple[float, float]) -> float:
    """How far from the left fovea, at `pose`, the texel at `target` of the start pose is."""
    texel = head.texel_at(target, np.array([0.0, 0.0, 8.0]))
    return float(np.hypot(*(head.image_position(texel, pose) - FOVEA)))


def test_the_vergence_the_maps_command_ends_at():
    gaze_map, pose = LinearMap(0.75), np.array([0.0, 0.0, 8.0])  # vergence 8 - 0.15 d
    assert vergence_goal(gaze_map, pose, (150.0, 120.0, -40.0)) == pytest.approx(14.0)
    assert vergence_goal(gaze_map, pose, (150.0, 120.0, 90.0)) is None  # beyond the map's range


def test_a_target_without_a_patch_to_find_it_by_is_refused_whatever_its_disparity():
    flat = np.full((HEIGHT, WIDTH), 128.0, np.float32)
    with pytest.raises(TargetPatchError) as err:
        target_disparity(flat, flat, 160.0, 120.0, (32, 20), (-60.0, 60.0), LookParams())
    assert "could not be measured" in str(err.value)
    assert ", and the target cannot be looked at: " in str(err.value) and "no texture" in str(err.value)
    left = rich_texture(seed=4, size=(WIDTH, HEIGHT))
    with pytest.raises(TargetPatchError) as err:  # measured, but the look's 21 x 21 patch does not fit
        target_disparity(left, np.roll(left, 6, axis=1), 150.0, 9.6, (32, 20), (-60.0, 60.0), LookParams())
    assert str(err.value).startswith("the target at (150, 9.6) cannot be looked at: ")
    assert "beyond the image" in str(err.value)


# --- a texture that repeats after the saccade: the expected landing tells the copies apart ----
def with_a_copy_beside(image: np.ndarray, at: np.ndarray, offset: tuple[int, int], size: int = 31) -> np.ndarray:
    """`image` with the square of `size` around `at` copied `offset` px away (a repeat; nearer
    than `size`, the copy covers part of the original)."""
    out = image.copy()
    u, v, h = int(round(at[0])), int(round(at[1])), size // 2
    du, dv = offset
    out[v + dv - h:v + dv + h + 1, u + du - h:u + du + h + 1] = image[v - h:v + h + 1, u - h:u + h + 1]
    return out


def test_the_expected_landing_picks_the_copy_the_saccade_brought_to_the_fovea():
    """The view after the saccade holds the target's patch twice, at the fovea (0.4 px off) and
    28 px beside it: alike, ambiguous without a prior; with the saccade's landing error known,
    the copy near where it was expected to bring the target is it."""
    source = rich_texture(seed=6, size=(WIDTH, HEIGHT))
    source_xy = (230.4, 80.7)
    landed = FOVEA + np.array([0.4, -0.3])
    shift = np.array([[1.0, 0.0, landed[0] - source_xy[0]], [0.0, 1.0, landed[1] - source_xy[1]]])
    after = with_a_copy_beside(cv2.warpAffine(source, shift, (WIDTH, HEIGHT), flags=cv2.INTER_LINEAR), landed, (28, 0))
    identity = [np.eye(2)]
    sighting, why = find_target(source, source_xy, after, LookParams(), identity)
    assert sighting is None and "ambiguous" in why and "where the saccade landed is not known" in why
    sighting, why = find_target(source, source_xy, after, LookParams(), identity, expected_error_px=0.3)
    assert why == "" and sighting is not None
    assert np.hypot(sighting.x - landed[0], sighting.y - landed[1]) <= 0.3
    # On whichever side the copy lies.
    other_side = with_a_copy_beside(cv2.warpAffine(source, shift, (WIDTH, HEIGHT), flags=cv2.INTER_LINEAR), landed,
                                    (-26, 5))
    assert find_target(source, source_xy, other_side, LookParams(), identity)[0] is None
    sighting, _ = find_target(source, source_xy, other_side, LookParams(), identity, expected_error_px=0.5)
    assert sighting is not None and np.hypot(sighting.x - landed[0], sighting.y - landed[1]) <= 0.3


def test_a_prior_in_the_images_pixels_is_not_carried_by_the_patchs_warp():
    """The lens shows the target's patch 1.5 x larger after the saccade, 12 px right of the
    fovea, with a copy 30 px left of it. A prior of 12 px right in the searched image's pixels
    (what a head's motion would say) takes the target; the same numbers in the patch's own
    view, carried by its warp, expect it 18 px right and reach neither place."""
    source = rich_texture(seed=6, size=(WIDTH, HEIGHT))
    source_xy = np.array([230.4, 80.7])
    landed = FOVEA + np.array([12.0, 0.0])
    scale = 1.5
    magnified = np.array([[scale, 0.0, landed[0] - scale * source_xy[0]], [0.0, scale, landed[1] - scale * source_xy[1]]])
    after = with_a_copy_beside(cv2.warpAffine(source, magnified, (WIDTH, HEIGHT), flags=cv2.INTER_LINEAR), landed,
                               (-30, 0))
    warps = [scale * np.eye(2)]
    xy = (float(source_xy[0]), float(source_xy[1]))
    found = search_target(source, xy, after, LookParams(), warps, 1.0, (12.0, 0.0), prior_in_image=True)
    assert found.sighting is not None, found.why
    assert np.hypot(found.sighting.x - landed[0], found.sighting.y - landed[1]) <= 0.5
    carried = search_target(source, xy, after, LookParams(), warps, 1.0, (12.0, 0.0))
    assert carried.sighting is None and "neither lies within" in carried.why
    # Nor is its error magnified: 3 x 8 px reaches the target alone, 3 x 8 x 1.5 px the copy too.
    wide = search_target(source, xy, after, LookParams(), warps, 8.0, (12.0, 0.0), prior_in_image=True)
    assert wide.sighting is not None and np.hypot(wide.sighting.x - landed[0], wide.sighting.y - landed[1]) <= 0.5


def test_a_repeat_within_the_maps_landing_error_is_refused_saying_so():
    source = rich_texture(seed=6, size=(WIDTH, HEIGHT))
    source_xy = (230.4, 80.7)
    shift = np.array([[1.0, 0.0, FOVEA[0] - source_xy[0]], [0.0, 1.0, FOVEA[1] - source_xy[1]]])
    after = with_a_copy_beside(cv2.warpAffine(source, shift, (WIDTH, HEIGHT), flags=cv2.INTER_LINEAR), FOVEA, (22, 16),
                               size=21)
    # A saccade that landed 10 px off cannot tell apart copies 27 px apart: 3 x 10 px reaches both.
    sighting, why = find_target(source, source_xy, after, LookParams(), [np.eye(2)], expected_error_px=10.0)
    assert sighting is None
    assert "ambiguous" in why and "2 of them lie within 30.0 px of the fovea" in why and "repeats" in why
    assert find_target(source, source_xy, after, LookParams(), [np.eye(2)], expected_error_px=2.0)[0] is not None


def test_a_measured_landing_says_where_the_target_is_not_only_how_far():
    """The saccade left the target (10, -6) px from the fovea, and a copy of it lies 29 px from
    the target, 12 px from the fovea: both within 3 x 11.7 px of the fovea, so the landing's
    length alone cannot tell them apart. Its direction can: where the fovea landed, the target
    lies (10, -6) px from it in the view before, so the place (10, -6) px from the fovea is it."""
    source = rich_texture(seed=6, size=(WIDTH, HEIGHT))
    source_xy = (230.4, 80.7)
    missed = np.array([10.0, -6.0])
    at = FOVEA + missed  # where the target is after the saccade
    shift = np.array([[1.0, 0.0, at[0] - source_xy[0]], [0.0, 1.0, at[1] - source_xy[1]]])
    after = with_a_copy_beside(cv2.warpAffine(source, shift, (WIDTH, HEIGHT), flags=cv2.INTER_LINEAR), at,
                               (-22, 19), size=25)
    error = float(np.hypot(*missed))
    sighting, why = find_target(source, source_xy, after, LookParams(), [np.eye(2)], expected_error_px=error)
    assert sighting is None and "ambiguous" in why and "2 of them lie within 35.0 px of the fovea" in why
    sighting, why = find_target(source, source_xy, after, LookParams(), [np.eye(2)], expected_error_px=0.15 * error,
                                expected_offset_px=(10.0, -6.0))
    assert why == "" and sighting is not None
    assert np.hypot(sighting.x - at[0], sighting.y - at[1]) <= 0.3
    # The offset is in the view before: a patch the lens shows 1.3 times as large after the
    # saccade lies 1.3 times as far from the fovea, which the warp says.
    magnified = np.array([[1.3, 0.0, FOVEA[0] + 1.3 * missed[0] - 1.3 * source_xy[0]],
                          [0.0, 1.3, FOVEA[1] + 1.3 * missed[1] - 1.3 * source_xy[1]]])
    at = FOVEA + 1.3 * missed
    after = with_a_copy_beside(cv2.warpAffine(source, magnified, (WIDTH, HEIGHT), flags=cv2.INTER_LINEAR), at,
                               (-24, 22), size=29)
    sighting, why = find_target(source, source_xy, after, LookParams(), [1.3 * np.eye(2)],
                                expected_error_px=0.15 * error, expected_offset_px=(10.0, -6.0))
    assert why == "" and sighting is not None
    assert np.hypot(sighting.x - at[0], sighting.y - at[1]) <= 0.5
    # A measured landing that puts the target where neither place is says so.
    sighting, why = find_target(source, source_xy, after, LookParams(), [1.3 * np.eye(2)],
                                expected_error_px=1.0, expected_offset_px=(-2.0, 8.0))
    assert sighting is None and "neither lies within" in why and "measured landing puts the target" in why


def repeat_after_the_first_move(texel: np.ndarray, offset: tuple[int, int] = (46, 0)):
    """A plane head's `on_move` that copies the 45 x 45 texels around `texel` `offset` px beside
    it once the head has moved: a repeat the view before did not hold."""
    def repeat(h) -> None:
        if len(h.moves) == 1:
            h.plane = with_a_copy_beside(h.plane, texel, offset, size=45)
    return repeat


def test_a_look_tells_the_target_from_a_repeat_that_appears_after_the_saccade():
    """Once the head moved, a copy of the target's surroundings (45 x 45 px, more than either of
    the look's patches) shows 46 px beside it, a repeat the view before did not hold. The first
    fixation's correspondence measured where it landed; the look takes the copy there, the
    true one."""
    head = PlanarHead()
    target = (236.0, 84.0)
    texel = head.texel_at(target)
    repeat = repeat_after_the_first_move(texel)
    head.on_move = repeat
    controller, _ = looker(head, gain=1.0, search_radius_px=150)  # the copy within the near search
    record = controller.look((*target, 0.0))
    assert record.fixations[0].landing_error_px is not None  # its correspondence was accepted
    assert record.on_target and true_error_px(head, texel) <= 1.0, record.detail
    # The same look where no correspondence is accepted: where the saccade landed is not known,
    # but a first saccade that went as planned is expected to have left the target within a few
    # pixels of the fovea, and only one copy lies there.
    head = PlanarHead()
    head.on_move = repeat
    controller, _ = looker(head, gain=1.0, params=FixationParams(confidence_floor=1.0), search_radius_px=150)
    record = controller.look((*target, 0.0))
    assert record.fixations[0].landing_error_px is None and not record.fixations[0].taught
    assert record.on_target and record.corrective_steps == 0, record.detail
    assert true_error_px(head, texel) <= 1.0


def test_a_first_saccade_whose_landing_is_unknown_does_not_take_a_repeat_beyond_its_reach():
    """The map's saccade falls 20 % short, leaving the target 17 px from the fovea; nothing
    measures where it landed, and a copy of the target's surroundings lies 45 px beside it. The
    prior a first saccade has about the fovea reaches neither: the look fails as ambiguous
    instead of taking either, and says where it expected the target."""
    head = PlanarHead()
    target = (236.0, 84.0)
    texel = head.texel_at(target)
    head.on_move = repeat_after_the_first_move(texel, (-30, -33))
    controller, _ = looker(head, gain=0.8, params=FixationParams(confidence_floor=1.0), search_radius_px=150)
    record = controller.look((*target, 0.0))
    assert record.fixations[0].landing_error_px is None
    assert record.outcome is LookOutcome.TARGET_LOST and "ambiguous" in record.detail
    assert "neither lies within" in record.detail and "of the fovea" in record.detail


def test_a_look_whose_saccade_fell_short_tells_the_target_from_a_repeat_by_where_it_landed():
    """The map's saccade falls 20 % short, leaving the target 17 px from the fovea, and once the
    head has moved a copy of the target's surroundings (45 x 45 px, more than either patch)
    lies 45 px beside it, 43 px from the fovea: both within 3 x 17 px of it, so the landing's
    length alone leaves the patch ambiguous. The first fixation's correspondence measured where
    the fovea landed, so the look knows where the target is from there and takes it."""
    head = PlanarHead()
    target = (236.0, 84.0)
    texel = head.texel_at(target)
    head.on_move = repeat_after_the_first_move(texel, (-30, -33))
    controller, _ = looker(head, gain=0.8, search_radius_px=150)  # the copy within the near search
    record = controller.look((*target, 0.0))
    first = record.fixations[0]
    assert first.taught and first.landing_error_px == pytest.approx(16.9, abs=1.0)
    assert record.on_target, record.detail
    assert true_error_px(head, texel) <= 1.0


def test_a_fine_periodic_texture_is_told_apart_at_its_own_period():
    """Stripes 8 px apart: the patch matches every stripe alike, nearer each other than half the
    patch; the stripe where the map lands it is the target."""
    rng = np.random.default_rng(9)
    xs, ys = np.meshgrid(np.arange(WIDTH), np.arange(HEIGHT))
    profile = cv2.GaussianBlur(rng.random((HEIGHT, 1), dtype=np.float32), (0, 0), 6.0)[:, 0]
    stripes = 128 + 60 * np.sin(2 * np.pi * xs / 8.0) * (0.5 + profile[ys] / profile.max())
    source = stripes.astype(np.float32)
    source_xy = (212.0, 92.3)
    landed = FOVEA + np.array([0.3, 0.2])
    shift = np.array([[1.0, 0.0, landed[0] - source_xy[0]], [0.0, 1.0, landed[1] - source_xy[1]]])
    after = cv2.warpAffine(source, shift, (WIDTH, HEIGHT), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
    after = after + rng.normal(0, 2.0, after.shape).astype(np.float32)
    # Every stripe repeats on both sides: the view before confirms more than one of them.
    sighting, why = find_target(source, source_xy, after, LookParams(), [np.eye(2)])
    assert sighting is None and "its view before the saccade confirms" in why
    sighting, why = find_target(source, source_xy, after, LookParams(), [np.eye(2)], expected_error_px=0.3)
    assert sighting is not None, why
    assert np.hypot(sighting.x - landed[0], sighting.y - landed[1]) <= 0.5


# --- repeats the view before the saccade shows: it tells them apart ---------------------------
def view_bringing(source: np.ndarray, source_xy: tuple[float, float], landed: np.ndarray, gain: float = 1.0,
                  seed: int = 0) -> np.ndarray:
    """The view after a saccade that brought `source_xy` to `landed`: shifted, its brightness
    `gain` times, with sensor noise."""
    shift = np.array([[1.0, 0.0, landed[0] - source_xy[0]], [0.0, 1.0, landed[1] - source_xy[1]]])
    after = cv2.warpAffine(source, shift, (WIDTH, HEIGHT), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
    return gain * after + np.random.default_rng(seed).normal(0.0, 2.0, after.shape).astype(np.float32)


@pytest.mark.parametrize("offset", [(28, 0), (-20, 18), (8, -27)])
def test_a_repeat_the_view_before_shows_beside_the_target_tells_which_place_is_it(offset):
    """The room holds a copy of the target's surroundings `offset` px beside it, in the view the
    target was chosen in too. After the saccade both match alike, near the fovea, and no landing
    is known; were the copy the target, the view before would show a repeat on the far side of
    the target, which it does not: the place the view before confirms is the target."""
    source_xy = (200.0, 90.0)
    source = with_a_copy_beside(rich_texture(seed=6, size=(WIDTH, HEIGHT)), np.array(source_xy), offset, size=25)
    landed = FOVEA + np.array([0.4, -0.3])
    after = view_bringing(source, source_xy, landed, gain=1.3)
    sighting, why = find_target(source, source_xy, after, LookParams(), [np.eye(2)])
    assert why == "" and sighting is not None
    assert np.hypot(sighting.x - landed[0], sighting.y - landed[1]) <= 0.3
    # A landing error measured but too large to tell them apart (both within 3 x 12 px): the
    # view before still does.
    sighting, why = find_target(source, source_xy, after, LookParams(), [np.eye(2)], expected_error_px=12.0)
    assert why == "" and sighting is not None
    assert np.hypot(sighting.x - landed[0], sighting.y - landed[1]) <= 0.3
    # The saccade brought the copy to the fovea instead: the target, beside it, is still told.
    copy_xy = (source_xy[0] + offset[0], source_xy[1] + offset[1])
    after = view_bringing(source, copy_xy, landed, seed=1)
    sighting, _ = find_target(source, source_xy, after, LookParams(), [np.eye(2)])
    assert sighting is not None
    assert np.hypot(sighting.x - (landed[0] - offset[0]), sighting.y - (landed[1] - offset[1])) <= 0.3


def test_a_target_between_two_copies_is_the_place_whose_repeats_the_view_before_shows():
    """Copies 28 px either side of the target: the view after shows all three alike. Only the
    middle one has, in the view before, repeats where the other two lie; it is the target."""
    source_xy = (160.0, 90.0)
    plain = rich_texture(seed=6, size=(WIDTH, HEIGHT))
    source = with_a_copy_beside(with_a_copy_beside(plain, np.array(source_xy), (28, 0), size=25),
                                np.array(source_xy), (-28, 0), size=25)
    landed = FOVEA + np.array([-0.2, 0.3])
    sighting, why = find_target(source, source_xy, view_bringing(source, source_xy, landed), LookParams(),
                                [np.eye(2)])
    assert why == "" and sighting is not None
    assert np.hypot(sighting.x - landed[0], sighting.y - landed[1]) <= 0.3


class RightEyeDazzled(PlanarHead):
    """A plane head whose right camera sees only noise once the head has moved (dazzled, say):
    fine vergence finds nothing to verge on, no fixation teaches, the left eye sees as before."""

    def wait_pair(self, after_s: float, timeout_s: float) -> tuple[np.ndarray, np.ndarray]:
        left, right = super().wait_pair(after_s, timeout_s)
        if self.moves:
            right = np.random.default_rng(len(self.moves)).uniform(0, 255, right.shape).astype(right.dtype)
        return left, right


def test_the_left_eyes_own_landing_tells_the_repeats_apart_when_nothing_taught():
    """The repeat of the test above, after a saccade whose fixation taught nothing (the right
    eye saw noise): the left eye's own correspondence measured where it landed, and the look
    takes the copy there, the true one."""
    head = RightEyeDazzled()
    target = (236.0, 84.0)
    texel = head.texel_at(target)
    head.on_move = repeat_after_the_first_move(texel)
    controller, learner = looker(head, gain=1.0, search_radius_px=150)
    record = controller.look((*target, 0.0))
    first = record.fixations[0]
    assert first.outcome is FixationOutcome.NO_VERGENCE_MATCH and first.landing_error_px is None
    assert not learner.samples
    assert record.on_target and true_error_px(head, texel) <= 1.0, record.detail
    landed = left_landing_px(first, FixationParams().correspondence, 0.3)
    assert landed is not None and np.hypot(*(landed - first.target[:2])) <= 0.5


def test_the_left_eyes_landing_is_not_measured_where_its_view_is_flat():
    head = PlanarHead(plane=np.full((600, 800), 128.0, dtype=np.float32))
    controller, _ = looker(head)
    fixation = controller.fixation.fixate((200.0, 100.0, 0.0))
    assert fixation.pre_left_image is not None and fixation.final_left_image is not None
    assert left_landing_px(fixation, FixationParams().correspondence, 0.3) is None


def test_a_refused_fixations_left_match_is_its_landing_not_matched_again():
    """A fixation that converged but was refused (here: the stereo check) has its left eye's
    match: that match is the left landing. Its images are noise, which a new match would
    find nothing in."""
    noise = np.random.default_rng(3).uniform(0, 255, (HEIGHT, WIDTH)).astype(np.float32)
    left = EyeMatch(x=103.0, y=104.0, c_max=0.95, c1=0.9, c2=1.0, competitors=0.0, confidence=0.8)
    right = EyeMatch(x=90.0, y=104.0, c_max=0.95, c1=0.9, c2=1.0, competitors=0.0, confidence=0.8)
    fixation = FixationRecord(index=0, kind=FixationKind.TARGET, target=np.array([100.0, 100.0, 0.0]),
                              converged=True, match=FixationMatch(left, right),
                              outcome=FixationOutcome.INCONSISTENT, pre_left_image=noise, final_left_image=noise)
    params = FixationParams().correspondence
    assert left_landing_px(fixation, params, 0.3) == pytest.approx([103.0, 104.0])
    unsure = dataclasses.replace(fixation, match=FixationMatch(dataclasses.replace(left, confidence=0.2), right))
    assert left_landing_px(unsure, params, 0.3) is None


def test_a_patch_whose_texture_is_the_cameras_noise_is_refused():
    """A flat face seen through a sensor with 2.3 grey levels of noise (a webcam's at mid grey):
    its patch is unique in its own view (noise matches nothing else), but the next exposure's
    noise is other noise, so nothing would find it again. Refused as flat, saying the std;
    real texture as faint as 8 grey levels is not."""
    rng = np.random.default_rng(4)
    flat = 120.0 + rng.normal(0.0, 2.3, (HEIGHT, WIDTH)).astype(np.float32)
    xy = (160.0, 120.0)
    why = target_patch_problem(flat, xy, LookParams())
    assert "has no texture to find it by" in why and "< min_patch_std 6" in why
    # Two exposures of the face match no better than noise does: the refusal is right.
    again = 120.0 + rng.normal(0.0, 2.3, (HEIGHT, WIDTH)).astype(np.float32)
    sighting, _ = find_target(flat, xy, again, LookParams(min_patch_std=1.0), [np.eye(2)])
    assert sighting is None
    texture = rich_texture(seed=2, size=(WIDTH, HEIGHT))
    faint = flat + (texture - texture.mean()) * (8.0 / texture.std())
    assert patch_problem(faint, xy, LookParams()) == ""
    # At 2 grey levels the noise alone would pass for texture.
    assert patch_problem(flat, xy, LookParams(min_patch_std=2.0)) == ""
    with pytest.raises(ValueError, match="min_patch_std"):
        LookParams(min_patch_std=0.0)


def test_a_target_on_a_flat_face_is_refused_though_its_larger_patch_reaches_an_edge():
    """The target lies on a flat face 14 px from its textured edge: its own patch (21 px) is
    flat, the larger one (41 px) holds the edge. Nothing at the fovea would be there to verge
    on or to measure the landing by, and the larger patch would find the target by its rim
    alone: refused, saying the own patch is flat."""
    rng = np.random.default_rng(5)
    image = 120.0 + rng.normal(0.0, 2.3, (HEIGHT, WIDTH)).astype(np.float32)
    texture = rich_texture(seed=7, size=(WIDTH, HEIGHT))
    image[:, 174:] = texture[:, 174:]
    xy = (160.0, 120.0)
    small, large = (LookParams(target_patch_size=size) for size in ((21, 21), (41, 41)))
    assert "has no texture" in patch_problem(image, xy, small)
    assert patch_problem(image, xy, large) == ""  # the larger one alone would be used
    usable, why = identifying_patches(image, xy, LookParams())
    assert usable == [] and "has no texture" in why
    assert "has no texture" in target_patch_problem(image, xy, LookParams())
    # A target 14 px inside the textured side is looked at with both patches.
    usable, why = identifying_patches(image, (188.0, 120.0), LookParams())
    assert why == "" and [v.target_patch_size for v in usable] == [(21, 21), (41, 41)]


def test_a_look_takes_a_patch_it_sees_fainter_than_accepted_but_not_a_flat_one():
    """The target was accepted at std >= min_patch_std in one exposure; the look's own image,
    another exposure, may show it with less contrast. A patch varying by 5 grey levels there
    (below 6, above 0.7 x 6) is looked at and ends on target; one varying by 3.5 (below the
    bare 1.8 x a webcam's noise of 2.3) ends without a patch to find the target by."""
    texture = rich_texture(seed=3) - 128.0
    target = (236.0, 84.0)
    own = float(PlanarHead(plane=texture).wait_pair(0.0, 1.0)[0][74:95, 226:247].std())  # the 21 px patch's
    for std, on_target in ((5.0, True), (3.5, False)):
        head = PlanarHead(plane=(128.0 + texture * (std / own)).astype(np.float32))
        texel = head.texel_at(target)
        controller, _ = looker(head, gain=0.9)
        assert head.wait_pair(0.0, 1.0)[0][74:95, 226:247].std() == pytest.approx(std, rel=0.01)
        record = controller.look((*target, 0.0))
        if on_target:
            assert record.on_target and true_error_px(head, texel) <= 1.0, record.detail
        else:
            assert record.outcome is LookOutcome.NO_TARGET_PATCH and "has no texture" in record.detail


def repeated_texture_with_rims(rims: int, blend: float) -> np.ndarray:
    """A 16 px tile repeated over the image, and about (160, 120), in the rows the 41 x 41 patch
    holds above (and with `rims` 2 below) the 21 x 21 one, other texture blended in by `blend`."""
    tile = cv2.resize(np.random.default_rng(3).uniform(0, 255, (4, 4)).astype(np.float32), (16, 16),
                      interpolation=cv2.INTER_CUBIC)
    image = np.tile(tile, (15, 20))[:HEIGHT, :WIDTH].copy()
    for seed, rows in zip((4, 5), (slice(100, 109), slice(132, 141))[:rims]):
        other = cv2.resize(np.random.default_rng(seed).uniform(0, 255, (4, 10)).astype(np.float32), (41, 9),
                           interpolation=cv2.INTER_CUBIC)
        image[rows, 140:181] = (1 - blend) * image[rows, 140:181] + blend * other
    return image


def test_a_larger_patch_set_apart_from_its_repeats_only_by_a_faint_rim_is_not_used():
    """The 21 px patch repeats every 16 px; the 41 px one differs from its repeats by one rim,
    its own view's second place within 0.25 of NCC of it: refused (a client is told the patch
    repeats), though it passes the 0.1 that tells repeats apart after a saccade. With two rims
    it is set apart by more than 0.25 and used."""
    xy = (160.0, 120.0)
    faint = repeated_texture_with_rims(1, 0.8)
    small, large = (LookParams(target_patch_size=size) for size in ((21, 21), (41, 41)))
    assert "ambiguous in its own view" in patch_problem(faint, xy, small)
    assert patch_problem(faint, xy, large) == ""  # within 0.1 it is told apart
    assert identifying_patches(faint, xy, LookParams()) == ([], patch_problem(faint, xy, small))
    assert "ambiguous in its own view" in target_patch_problem(faint, xy, LookParams())
    usable, _ = identifying_patches(faint, xy, LookParams(context_ncc_margin=0.1))
    assert [v.target_patch_size for v in usable] == [(41, 41)]
    clear = repeated_texture_with_rims(2, 0.8)
    usable, why = identifying_patches(clear, xy, LookParams())
    assert "ambiguous" in why and [v.target_patch_size for v in usable] == [(41, 41)]
    assert target_patch_problem(clear, xy, LookParams()) == ""
    with pytest.raises(ValueError, match="context_ncc_margin"):
        LookParams(context_ncc_margin=0.05)


# --- a corrective step's own prior: a step this short cannot have taken the target far -------
def copy_after_the_first_fixation(head: PlanarHead, texel: np.ndarray, offset: tuple[int, int]):
    """A look's `on_fixation` that copies the 25 x 25 texels around `texel` `offset` px beside
    it once the first fixation has ended: a repeat that only the corrective step's images show."""
    ended: list[FixationRecord] = []

    def copy(fixation: FixationRecord) -> None:
        ended.append(fixation)
        if len(ended) == 1:
            head.plane = with_a_copy_beside(head.plane, texel, offset, size=25)
    return copy


def corrective_look(offset: tuple[int, int], gain: float = 0.95):
    """A look whose saccades fall short by 1 - `gain` (the first, 84 px, by about 4 px at 0.95)
    and whose fixations measure no landing (no correspondence reaches a confidence of 1), with
    a copy of the target `offset` px beside it after the first fixation; the look and the truth
    after it."""
    head = PlanarHead()
    target = (236.0, 84.0)
    texel = head.texel_at(target)
    controller = FixationController(head, LinearMap(gain), FixationParams(confidence_floor=1.0), seed=0)
    looks = LookController(controller, LookParams(search_radius_px=150),
                           on_fixation=copy_after_the_first_fixation(head, texel, offset))
    record = looks.look((*target, 0.0))
    return record, true_error_px(head, texel)


def test_a_corrective_step_tells_the_target_from_a_repeat_beyond_its_own_reach():
    """The corrective step aimed about 4 px from the fovea and the encoders say the head did
    what was planned: a copy of the target 24 px away is not where it took the target, though
    no landing was measured and the view before the look never showed the copy."""
    record, truth = corrective_look((24, 0))
    assert record.corrective_steps == 1
    second = record.fixations[1]
    assert second.landing_error_px is None
    assert left_landing_px(second, FixationParams().correspondence, 1.0) is None
    assert record.on_target, record.detail
    assert truth <= 1.0


def test_a_repeat_within_a_corrective_steps_reach_leaves_the_target_ambiguous():
    """A first saccade 20 % short leaves the target 17 px from the fovea: 3 x that reaches a
    copy 30 px beside it, which the step cannot be told not to have brought there."""
    record, _ = corrective_look((30, 0), gain=0.8)
    assert record.outcome is LookOutcome.TARGET_LOST
    assert "ambiguous" in record.detail and "2 of them lie within" in record.detail


def test_a_better_match_beyond_a_corrective_steps_reach_is_not_the_target():
    """After the first fixation the target's surroundings blur and pick up noise (NCC about 0.8
    with its patch), and a sharp copy appears 24 px beside it (NCC 1): the best match, and no
    repeat within the ambiguity margin. The corrective step aimed about 4 px from the fovea and
    went as planned, so the copy is not where it took the target: the search keeps within the
    step's reach and finds the target there."""
    head = PlanarHead()
    target = (236.0, 84.0)
    texel = head.texel_at(target)
    copied = copy_after_the_first_fixation(head, texel, (24, 0))
    ended: list[FixationRecord] = []

    def degrade(fixation: FixationRecord) -> None:
        copied(fixation)
        ended.append(fixation)
        if len(ended) == 1:
            u, v, r = int(round(texel[0])), int(round(texel[1])), 14
            noise = np.random.default_rng(3).normal(0.0, 0.7 * float(head.plane.std()), (2 * r + 1, 2 * r + 1))
            head.plane[v - r:v + r + 1, u - r:u + r + 1] += noise.astype(np.float32)
    controller = FixationController(head, LinearMap(0.95), FixationParams(confidence_floor=1.0), seed=0)
    looks = LookController(controller, LookParams(search_radius_px=150), on_fixation=degrade)
    record = looks.look((*target, 0.0))
    assert record.corrective_steps >= 1
    assert record.on_target, record.detail
    assert true_error_px(head, texel) <= 1.0


def test_a_search_after_a_corrective_step_keeps_within_its_reach_and_says_so_when_empty():
    source = rich_texture(seed=6, size=(WIDTH, HEIGHT))
    source_xy = (230.4, 80.7)
    landed = FOVEA + np.array([14.0, 0.0])  # the target 14 px from the fovea
    shift = np.array([[1.0, 0.0, landed[0] - source_xy[0]], [0.0, 1.0, landed[1] - source_xy[1]]])
    after = cv2.warpAffine(source, shift, (WIDTH, HEIGHT), flags=cv2.INTER_LINEAR)
    identity = [np.eye(2)]
    sighting, _ = find_target(source, source_xy, after, LookParams(), identity, step_error_px=5.0)
    assert sighting is not None and np.hypot(sighting.x - landed[0], sighting.y - landed[1]) <= 0.3  # 15 px reach
    sighting, why = find_target(source, source_xy, after, LookParams(), identity, step_error_px=2.0)
    assert sighting is None
    assert "within 6 px of the fovea, as far as the corrective step can have left it" in why


def test_a_measured_landing_the_corrective_step_cannot_have_made_is_not_taken():
    """A corrective step aimed 4 px from the fovea and the encoders say it went as planned. Its
    left eye's match, confident, says the fovea landed 3 px from where the target was: that
    landing is the prior, a point. Another says 96 px: no step aimed 4 px makes that, the match
    is wrong, and the step's own prior about the fovea is taken instead."""
    controller, _ = looker(PlanarHead())
    image = rich_texture(seed=1, size=(WIDTH, HEIGHT))
    pose = np.array([2.0, 1.0, 8.0])
    planned = np.array([-1.0, 0.0, 0.0])
    target_before = FOVEA + np.array([4.0, 0.0])

    def stepped(landed: np.ndarray) -> FixationRecord:
        left = EyeMatch(x=float(landed[0]), y=float(landed[1]), c_max=0.95, c1=0.9, c2=1.0, competitors=0.0,
                        confidence=0.8)
        return FixationRecord(index=1, kind=FixationKind.TARGET, target=np.array([*target_before, 0.0]),
                              planned=planned, pose_before=pose, pose_after=pose + planned, converged=True,
                              match=FixationMatch(left, left), outcome=FixationOutcome.INCONSISTENT,
                              pre_left_image=image, final_left_image=image)

    far = stepped(FOVEA + np.array([100.0, 0.0]))
    step = controller._corrective_step_error_px(far, 4.0)
    assert step == pytest.approx(4.0)  # aimed 4 px, the head did as planned
    step_error, none = controller._landing_prior(far, target_before, np.eye(2), step)
    assert none is None and step_error == pytest.approx(4.0)
    error, offset = controller._landing_prior(stepped(target_before - np.array([3.0, 0.0])), target_before,
                                              np.eye(2), step)
    assert offset == pytest.approx((3.0, 0.0)) and error == pytest.approx(0.15 * 3.0)


def test_a_corrective_steps_expected_error_is_its_aim_and_what_the_head_did_beyond_the_plan():
    planned = np.array([-0.5, 0.25, 0.0])
    assert corrective_step_error_px(2.0, planned, planned, 4.0) == pytest.approx(2.0)
    # Pan 0.3 and tilt 0.4 deg beyond the plan (0.5 deg), and 1 deg more vergence (the left eye turned 0.5).
    moved = planned + np.array([0.3, 0.4, 1.0])
    assert corrective_step_error_px(2.0, moved, planned, 4.0) == pytest.approx(2.0 + 4.0 * (0.5 + 0.5))


def test_the_maps_pixels_a_degree_at_the_fovea():
    pose = np.zeros(3)
    assert foveal_px_per_deg(LinearMap(1.0), pose, (WIDTH, HEIGHT)) == pytest.approx(4.0)
    assert foveal_px_per_deg(LinearMap(0.5), pose, (WIDTH, HEIGHT)) == pytest.approx(8.0)
    assert foveal_px_per_deg(LinearMap(0.0), pose, (WIDTH, HEIGHT)) is None  # a map that commands nothing
    assert foveal_px_per_deg(LinearMap(1.0), pose, (0, 0)) is None  # no image to measure in


def test_a_disparity_measured_on_a_patch_repeating_along_its_rows_says_it_may_be_a_repeats():
    """The right image shows the target's surroundings twice along its rows, at d = 6 px and
    30 px beyond: the d measured may be either's. Without the second copy d is the target's."""
    left = rich_texture(seed=4, size=(WIDTH, HEIGHT))
    right = np.roll(left, 6, axis=1)
    found = target_disparity(left, right, 150.0, 110.0, (32, 20), (-60.0, 60.0), LookParams())
    assert found.measured and found.reason == "" and found.d == pytest.approx(6.0, abs=0.3)
    twice = with_a_copy_beside(right, np.array([156.0, 110.0]), (30, 0), size=29)
    found = target_disparity(left, twice, 150.0, 110.0, (32, 20), (-60.0, 60.0), LookParams())
    assert found.measured and "repeats along its rows" in found.reason and "may be a repeat's" in found.reason
    assert found.d == pytest.approx(6.0, abs=0.3) or found.d == pytest.approx(36.0, abs=0.3)


# --- judging the target again before the saccade ----------------------------------------------
def repeats_under_a_unique_square(blend: float) -> tuple[PlanarHead, tuple[float, float], np.ndarray]:
    """A 16 px tile repeated over the plane, and about the target an 81 px square of other
    texture blended in by `blend`: the more, the farther the target's patch stands from its
    repeats in its own view. The head, the target and its texel."""
    tile = cv2.resize(np.random.default_rng(3).uniform(0, 255, (4, 4)).astype(np.float32), (16, 16),
                      interpolation=cv2.INTER_CUBIC)
    plane = np.tile(tile, (50, 63))[:800, :1000].copy()
    target = (236.0, 84.0)
    texel = PlanarHead(plane=plane).texel_at(target)
    u, v = texel.round().astype(int)
    square = plane[v - 40:v + 41, u - 40:u + 41]
    square[:] = (1 - blend) * square + blend * rich_texture(seed=9, size=(81, 81))
    return PlanarHead(plane=plane), target, texel


def test_a_look_refuses_a_clearly_repeating_target_before_the_head_moves_and_takes_one_near_the_margin():
    """The look judges the target's patch in its own image, which the client's check did not
    see: one whose second place comes within 0.03 of NCC of it is refused with the head still
    where it was; one 0.07 apart (ambiguous at the check's full margin of 0.1, apart by more than
    half of it) is looked at, and ends on target."""
    for blend, margin, on_target in ((0.2, 0.025, False), (0.3, 0.074, True)):
        head, target, texel = repeats_under_a_unique_square(blend)
        peaks, _ = own_view_peaks(head.wait_pair(0.0, 1.0)[0], target, LookParams())
        assert peaks is not None and peaks[0] - peaks[1] == pytest.approx(margin, abs=0.01)
        assert "ambiguous in its own view" in target_patch_problem(head.wait_pair(0.0, 1.0)[0], target, LookParams())
        controller, learner = looker(head, gain=0.95)
        record = controller.look((*target, 0.0))
        if on_target:
            assert record.on_target and true_error_px(head, texel) <= 1.0, record.detail
        else:
            assert record.outcome is LookOutcome.NO_TARGET_PATCH and "ambiguous in its own view" in record.detail
            assert head.moves == [] and learner.samples == []  # refused before the saccade
            assert [f.outcome for f in record.fixations] == [FixationOutcome.TARGET_REFUSED]


# --- the first search's two patches ----------------------------------------------------------
def test_where_the_two_patches_disagree_the_first_search_takes_the_one_nearer_the_fovea():
    """The smaller patch found the target 10 px from the fovea; the larger one, about the same
    point, finds it elsewhere: nearer the fovea it wins, farther (or within 2 px of the smaller
    one's, the two patches' own disagreement, or not found) the smaller one's place stands."""
    small, large = LookParams(), LookParams(target_patch_size=(41, 41))
    fovea_xy = (159.5, 119.5)
    found = TargetSighting(169.5, 119.5, 0.9, np.eye(2))

    def larger_finds(x, y):
        return lambda variant: TargetSearch(None if x is None else TargetSighting(x, y, 0.85, np.eye(2)))

    assert nearer_of_two_patches(found, small, [large], larger_finds(160.0, 119.5), fovea_xy)[1] is large
    assert nearer_of_two_patches(found, small, [large], larger_finds(160.0, 119.5), fovea_xy)[0].x == 160.0
    for x, y in ((180.0, 119.5), (168.0, 119.5), (None, None)):
        assert nearer_of_two_patches(found, small, [large], larger_finds(x, y), fovea_xy) == (found, small)
    assert nearer_of_two_patches(found, large, [], larger_finds(160.0, 119.5), fovea_xy) == (found, large)


@pytest.mark.parametrize("finishing_steps, on_target", [(2, True), (0, False)])
def test_a_target_left_within_the_finishing_reach_takes_the_finishing_steps(finishing_steps, on_target):
    """A map that makes every move half what it should: 10 px from the fovea, the saccade leaves the
    target 5 px off, the one corrective step 2.5 px, within the 3 px finishing reach."""
    head = PlanarHead()
    controller, _ = looker(head, gain=0.5, max_corrective_steps=1, finishing_steps=finishing_steps)
    target = (FOVEA[0] + 8.0, FOVEA[1] + 6.0)
    texel = head.texel_at(target)
    record = controller.look((*target, 0.0))
    assert record.on_target is on_target
    if on_target:
        assert record.corrective_steps > 1 and true_error_px(head, texel) <= 1.0
    else:
        assert record.outcome is LookOutcome.NOT_ON_TARGET and record.corrective_steps == 1
        assert 1.0 < true_error_px(head, texel) <= 3.0


def test_a_target_beyond_the_finishing_reach_takes_no_finishing_step():
    head = PlanarHead()
    controller, _ = looker(head, gain=0.5, max_corrective_steps=1, finishing_steps=2)
    target = (FOVEA[0] + 40.0, FOVEA[1] + 30.0)  # 50 px: 25 px off after the saccade, 12.5 after the step
    record = controller.look((*target, 0.0))
    assert record.outcome is LookOutcome.NOT_ON_TARGET and record.corrective_steps == 1
    assert record.final_error_px > 3.0
