"""The geometric head model: lens, kinematics, sign conventions, perturbations, sampling."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from calib_free.lens import FisheyeLens
from calib_free.sim.head_model import FixationSampler, HeadModel, Perturbation, with_perturbation

POSES = [np.array(p, dtype=float) for p in ([0, 0, 10], [25, -15, 4], [-38, 22, 19], [10, 5, 3.5])]


@pytest.mark.parametrize("kind", ["foveated", "equidistant", "equisolid"])
def test_lens_matches_opencv_fisheye_in_front_of_the_camera(kind):
    lens = FisheyeLens.named(kind, 320, 240)
    rng = np.random.default_rng(0)
    points = rng.normal(size=(200, 3))
    points[:, 2] = np.abs(points[:, 2]) + 0.3
    off_axis = np.degrees(np.arctan2(np.hypot(points[:, 0], points[:, 1]), points[:, 2]))
    points = points[off_axis < 80]  # beyond the lens's 85 deg both models are meaningless
    ours, _ = lens.project(points)
    theirs, _ = cv2.fisheye.projectPoints(points.reshape(-1, 1, 3), np.zeros(3), np.zeros(3),
                                          lens.camera_matrix, lens.opencv_distortion())
    np.testing.assert_allclose(ours, theirs.reshape(-1, 2), atol=1e-6)


@pytest.mark.parametrize("kind", ["foveated", "equidistant", "equisolid"])
def test_unproject_inverts_project(kind):
    lens = FisheyeLens.named(kind, 640, 480)
    u, v = np.meshgrid(np.linspace(0, 639, 23), np.linspace(0, 479, 17))
    pixels = np.column_stack([u.ravel(), v.ravel()])
    rays = lens.unproject(pixels)
    np.testing.assert_allclose(np.linalg.norm(rays, axis=1), 1.0)
    back, seen = lens.project(rays)
    np.testing.assert_allclose(back, pixels, atol=1e-6)
    assert seen.all()


def test_points_behind_the_camera_never_project():
    lens = FisheyeLens.named("foveated", 320, 240)
    behind = np.array([[0.01, 0.0, -1.0], [0.0, 0.0, -0.5], [0.3, 0.2, -0.01]])
    _, seen = lens.project(behind)
    assert not seen.any()
    # cv2.fisheye would put the first one right next to the image centre
    theirs, _ = cv2.fisheye.projectPoints(behind[:1].reshape(-1, 1, 3), np.zeros(3), np.zeros(3),
                                          lens.camera_matrix, lens.opencv_distortion())
    assert abs(theirs[0, 0, 0] - 159.5) < 160


def test_paper_lens_has_a_90_degree_horizontal_view_and_a_compressed_periphery():
    lens = FisheyeLens.named("foveated", 320, 240)
    edge = np.array([[np.sin(np.radians(45)), 0, np.cos(np.radians(45))]])
    uv, _ = lens.project(edge)
    assert uv[0, 0] == pytest.approx(319.5, abs=2.0)  # 45 deg off axis lands on the right edge
    def px_per_degree(angle):
        return lens.radius_px(np.radians(angle + 0.5)) - lens.radius_px(np.radians(angle - 0.5))

    centre = lens.radius_px(np.radians(1.0))
    assert centre / px_per_degree(45) > 1.5  # at the left/right edges
    assert centre / px_per_degree(75) > 4  # in the corners


@pytest.mark.parametrize("pose", POSES, ids=str)
def test_the_fixation_point_projects_to_the_centre_of_both_images(pose):
    head = HeadModel.default()
    target = head.fixation_point(pose)
    uv_l, uv_r, seen = head.project(target[None, :], pose)
    assert seen[0]
    np.testing.assert_allclose(uv_l[0], [159.5, 119.5], atol=1e-9)
    np.testing.assert_allclose(uv_r[0], [159.5, 119.5], atol=1e-9)


def test_disparity_is_negative_nearer_than_fixation_and_positive_beyond():
    head = HeadModel.default()
    pose = np.array([0.0, 0.0, 8.0])
    target = head.fixation_point(pose)
    eyes_centre = head.head_rotation(pose) @ np.array([head.eye_offset_m[0], 0, head.eye_offset_m[1]])
    direction = (target - eyes_centre) / np.linalg.norm(target - eyes_centre)
    near = eyes_centre + 0.6 * np.linalg.norm(target - eyes_centre) * direction
    far = eyes_centre + 1.8 * np.linalg.norm(target - eyes_centre) * direction
    r, seen = head.image_position(np.array([near, target, far]), pose)
    assert seen.all()
    assert r[0, 2] < 0 and abs(r[1, 2]) < 1e-9 and r[2, 2] > 0  # d = x_r - x_l
    # and converging (dverg > 0) is what fixates the near point
    sampler = FixationSampler(head, seed=0, start_pose=pose)
    before = head.landing_error_px(near, pose)
    after = head.landing_error_px(near, sampler.execute(np.array([0.0, 0.0, 5.0])))
    assert after < before


def test_pan_turns_left_and_tilt_turns_up():
    head = HeadModel.default()
    pose = np.array([0.0, 0.0, 6.0])
    left_and_up = head.fixation_point(pose) + np.array([0.0, 0.2, 0.15])
    r, _ = head.image_position(left_and_up[None, :], pose)
    assert r[0, 0] < 159.5 and r[0, 1] < 119.5  # left of and above the centre in the image
    for command in (np.array([10.0, 0, 0]), np.array([0, 10.0, 0])):
        moved = pose + command
        assert head.landing_error_px(left_and_up, moved) < head.landing_error_px(left_and_up, pose)


def test_perturbations():
    head = HeadModel.default()
    pose = np.array([5.0, -3.0, 9.0])
    point = head.fixation_point(pose) + np.array([0.1, 0.12, -0.08])
    uv_l, uv_r, _ = head.project(point[None, :], pose)

    prism = with_perturbation(head, vertical_prism=True)
    pl, pr, _ = prism.project(point[None, :], pose)
    np.testing.assert_allclose(pl[0], [uv_l[0, 0], 239 - uv_l[0, 1]])
    np.testing.assert_allclose(pr[0], [uv_r[0, 0], 239 - uv_r[0, 1]])

    swapped = with_perturbation(head, swap_eyes=True)
    sl, sr, _ = swapped.project(point[None, :], pose)
    np.testing.assert_allclose(sl, uv_r)
    np.testing.assert_allclose(sr, uv_l)

    wider = with_perturbation(head, baseline_delta_m=0.010)
    assert wider.effective_baseline_m == pytest.approx(0.070)
    r_narrow, _ = head.image_position(point[None, :], pose)
    r_wide, _ = wider.image_position(point[None, :], pose)
    assert abs(r_wide[0, 2]) != pytest.approx(abs(r_narrow[0, 2]))

    defect = Perturbation(motor_offset_deg=(10.0, 0.0, 0.0), motor_gain=(1.0, 1.0, 0.8))
    np.testing.assert_allclose(defect.executed(np.array([1.0, 2.0, 5.0])), [11.0, 2.0, 4.0])
    np.testing.assert_allclose(defect.command_for(defect.executed(np.array([1.0, 2.0, 5.0]))), [1.0, 2.0, 5.0])


@pytest.mark.parametrize("perturbation", [{}, {"motor_offset_deg": (10.0, 0.0, 0.0)}, {"vertical_prism": True},
                                          {"motor_gain": (1.2, 0.9, 1.0)}])
def test_sampled_pairs_are_exact_fixations(perturbation):
    """Executing a sample's command from its pose puts its target on the fovea of both eyes."""
    head = with_perturbation(HeadModel.default(), **perturbation)
    sampler = FixationSampler(head, (-60, 60), seed=4)
    for _ in range(50):
        s = sampler.draw()
        lo, hi = head.limits.low, head.limits.high
        after = s.pose_before + head.perturbation.executed(s.command)
        assert np.all(after >= lo - 1e-9) and np.all(after <= hi + 1e-9)
        uv_l, uv_r, _ = head.project(s.target[None, :], after)
        centre = [159.5, 119.5]
        # a prism flips the image about its centre row: the centre stays the centre
        np.testing.assert_allclose(uv_l[0], centre, atol=1e-6)
        np.testing.assert_allclose(uv_r[0], centre, atol=1e-6)
        assert -0.5 <= s.position[0] <= 319.5 and -0.5 <= s.position[1] <= 239.5
        assert -60 <= s.position[2] <= 60


class HalfDome:
    """A sphere of radius `radius_m` about the origin, seen from inside, only where y >= 0 (the
    head's left and straight ahead): rays elsewhere meet nothing."""

    def __init__(self, radius_m: float) -> None:
        self.radius_m = radius_m

    def first_surface(self, origin, direction):
        b = float(origin @ direction)
        t = -b + np.sqrt(b * b - (origin @ origin - self.radius_m ** 2))
        point = origin + t * direction
        return point if point[1] > -1e-9 else None


def test_with_surroundings_every_pose_fixates_the_first_surface_ahead():
    head = HeadModel.default()
    dome = HalfDome(0.8)  # 4.4 deg of vergence: within the default 3-20
    sampler = FixationSampler(head, (-60, 60), seed=5, surroundings=dome)
    for _ in range(40):
        s = sampler.draw()
        after = s.pose_before + s.command
        for pose in (s.pose_before, after):
            # the eyes' axes cross on the dome, on the head's left, within the vergence limits
            point = head.fixation_point(pose)
            assert np.linalg.norm(point) == pytest.approx(0.8, abs=1e-6)
            assert point[1] > -1e-9 and head.limits.contains(pose)
        np.testing.assert_allclose(s.target, head.fixation_point(after), atol=1e-9)
    # a 0.8 m sphere seen from 2 cm in front of and 6 cm above its centre
    distance = np.sqrt(0.8 ** 2 - 0.06 ** 2) - 0.02
    vergence = head.vergence_fixating(np.array([-30.0, 0.0]), dome)
    assert vergence is None  # the head's right: nothing there
    vergence = head.vergence_fixating(np.array([30.0, 0.0]), dome)
    expected = np.degrees(2 * np.arctan(0.03 / distance))
    assert vergence == pytest.approx(expected, rel=1e-6)
