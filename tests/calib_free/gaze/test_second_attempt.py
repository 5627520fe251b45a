"""A look's second attempt at the depth its first found (calib_free.gaze.second_attempt), on a plane
head whose left eye turns with half the vergence, as a real head's does."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from calib_free.gaze.fixation import FixationController, FixationKind, FixationParams, FixationRecord, LookParams
from calib_free.gaze.look import LookController, LookOutcome
from calib_free.gaze.second_attempt import depth_found_elsewhere, disparity_for_vergence, target_in_restored_view
from tests.support.planar_head import (DISPARITY_PX_PER_DEG, HEIGHT, PLANE_VERGENCE_DEG, PX_PER_DEG, WIDTH, LinearMap,
                                       PlanarHead, rich_texture)

FOVEA = np.array([(WIDTH - 1) / 2, (HEIGHT - 1) / 2])


class LeftEyeVergingHead(PlanarHead):
    """A plane head whose eyes turn symmetrically with the vergence: the left view moves by half
    of it (to the right as the eyes converge), as pan does by all of it."""

    def view_centre(self, pose: np.ndarray | None = None) -> np.ndarray:
        pose = self.pose if pose is None else pose
        centre = super().view_centre(pose)
        return centre + np.array([PX_PER_DEG * (pose[2] - PLANE_VERGENCE_DEG) / 2.0, 0.0])


class MapKeepingTheLeftEye(LinearMap):
    """The exact map of `LeftEyeVergingHead`: its pan makes up for half the vergence change."""

    def command(self, position, pose=None) -> np.ndarray:
        command = super().command(position, pose)
        command[0] += command[2] / 2.0
        return command


def looker(head: PlanarHead, **look) -> LookController:
    controller = FixationController(head, MapKeepingTheLeftEye(1.0), FixationParams(), seed=0)
    return LookController(controller, LookParams(**look))


def test_a_look_whose_eyes_converged_at_another_depth_tries_again_from_its_view_with_that_depth():
    """The head starts verged 4 deg nearer than the plane (20 px of disparity at the target); the
    target is sent with d = 0, the depth the eyes fixate. The saccade keeps that vergence, fine
    vergence then turns it 4 deg to the plane and the left eye 2 deg, 8 px, off the target, and
    with no corrective step allowed the first attempt fails. The second returns to the view and
    goes with the d the map gives the plane's vergence: on target without a corrective step."""
    head = LeftEyeVergingHead(pose=(0.0, 0.0, PLANE_VERGENCE_DEG + 4.0))
    start = head.read_pose()
    target = (230.0, 90.0)
    texel = head.texel_at(target)
    record = looker(head, max_corrective_steps=0).look((*target, 0.0), depth_known=False)
    first = record.first_attempt
    assert first is not None and first.outcome is LookOutcome.NOT_ON_TARGET
    assert first.final_error_px == pytest.approx(8.0, abs=1.0)
    assert record.attempts == 2 and record.on_target and record.corrective_steps == 0
    assert record.target[2] == pytest.approx(4.0 * DISPARITY_PX_PER_DEG, abs=0.5)
    assert np.allclose(record.fixations[0].pose_before, start)  # from the view the target was chosen in
    assert record.view_restored_deg is None  # the look's own: it began in the target's view
    assert float(np.hypot(*(head.image_position(texel) - FOVEA))) < 1.0
    assert "second attempt" in record.detail and "converged at 8.0 deg" in record.detail


def test_a_look_whose_eyes_converged_where_it_planned_makes_no_second_attempt():
    head = LeftEyeVergingHead(pose=(0.0, 0.0, PLANE_VERGENCE_DEG))
    record = looker(head, max_corrective_steps=0).look((290.0, 200.0, 0.0), depth_known=False)
    assert record.attempts == 1 and record.first_attempt is None


def fixation(converged: bool, before_deg: float, planned_deg: float, after_deg: float) -> FixationRecord:
    return FixationRecord(0, FixationKind.TARGET, target=np.zeros(3), converged=converged,
                          pose_before=np.array([0.0, 0.0, before_deg]), planned=np.array([0.0, 0.0, planned_deg]),
                          pose_after=np.array([0.0, 0.0, after_deg]))


def test_the_depth_found_elsewhere_is_where_the_eyes_converged_a_degree_or_more_from_the_plan():
    assert depth_found_elsewhere(fixation(True, 5.0, 2.0, 5.5), 1.0, 20.0) == 5.5  # planned 7
    assert depth_found_elsewhere(fixation(True, 5.0, 2.0, 6.5), 1.0, 20.0) is None  # 0.5 off
    assert depth_found_elsewhere(fixation(False, 5.0, 2.0, 2.0), 1.0, 20.0) is None  # not converged
    # planned -3, which the head stops at 1: the eyes converged 0.4 deg from where they were sent
    assert depth_found_elsewhere(fixation(True, 2.0, -5.0, 1.4), 1.0, 20.0) is None


def test_the_disparity_for_a_vergence_is_the_one_the_maps_command_ends_there_with():
    pose = np.array([3.0, -2.0, 10.0])
    # LinearMap: vergence change -d / 5
    assert disparity_for_vergence(LinearMap(1.0), pose, (100.0, 80.0), 7.5) == pytest.approx(12.5)
    assert disparity_for_vergence(LinearMap(1.0), pose, (100.0, 80.0), 10.0) == pytest.approx(0.0)
    assert disparity_for_vergence(LinearMap(1.0), pose, (100.0, 80.0), 30.0) is None  # d -100: beyond the map


@pytest.mark.parametrize("shift", [(0.0, 0.0), (1.3, -0.6), (-3.4, 2.2)])
def test_the_target_is_found_again_in_the_restored_view_a_play_off(shift):
    plane = rich_texture(seed=7, size=(WIDTH + 40, HEIGHT + 40))
    centre = ((WIDTH + 39) / 2.0, (HEIGHT + 39) / 2.0)
    source = cv2.getRectSubPix(plane, (WIDTH, HEIGHT), centre)
    restored = cv2.getRectSubPix(plane, (WIDTH, HEIGHT), (centre[0] - shift[0], centre[1] - shift[1]))
    found = target_in_restored_view(source, (120.0, 100.0), restored, (21, 21))
    assert found is not None
    assert found == pytest.approx((120.0 + shift[0], 100.0 + shift[1]), abs=0.2)
    assert target_in_restored_view(source, (120.0, 100.0), np.full_like(source, 90.0), (21, 21)) is None  # flat
    assert target_in_restored_view(source, (8.0, 100.0), restored, (21, 21)) is None  # beyond the image
