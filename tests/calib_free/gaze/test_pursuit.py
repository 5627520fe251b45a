"""Smooth pursuit apart from any head (calib_free.gaze.pursuit): the pose history, the patch tracker on
synthetic images with known shifts, and the control law closing the loop on a synthetic world
where the image moves as a known Jacobian says."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from calib_free.gaze.pursuit import DEFAULT_JACOBIAN, PatchTracker, PoseHistory, Pursuit, PursuitParams

W, H = 160, 120
FOVEA = np.array([(W - 1) / 2.0, (H - 1) / 2.0])


def texture(seed: int = 0, size: int = 400) -> np.ndarray:
    rng = np.random.default_rng(seed)
    out = np.zeros((size, size), np.float32)
    for cell, amplitude in ((40, 40.0), (12, 30.0), (4, 20.0)):
        small = rng.standard_normal((size // cell + 2, size // cell + 2)).astype(np.float32)
        out += amplitude * cv2.resize(small, (size, size), interpolation=cv2.INTER_CUBIC)
    return np.clip(128 + out, 0, 255).astype(np.float32)


def view(tex: np.ndarray, x: float, y: float, d: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Left and right images in which the texture's point (200, 200) lies at (x, y) in the left
    image and at (x + d, y) in the right."""
    def shifted(dx: float) -> np.ndarray:
        m = np.float32([[1, 0, x + dx - 200], [0, 1, y - 200]])
        return cv2.warpAffine(tex, m, (W, H), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
    return shifted(0.0), shifted(d)


def test_the_pose_history_interpolates_and_knows_its_reach():
    history = PoseHistory(size=4, max_gap_s=0.05)
    assert history.at(1.0) is None
    history.add(1.0, np.array([0.0, 0.0, 5.0]))
    history.add(1.1, np.array([2.0, -1.0, 5.0]))
    history.add(1.05, np.array([9.0, 9.0, 9.0]))  # older than the newest: ignored
    np.testing.assert_allclose(history.at(1.025), [0.5, -0.25, 5.0])
    np.testing.assert_allclose(history.at(1.14), [2.0, -1.0, 5.0])  # just past the newest: held
    assert history.at(1.2) is None and history.at(0.9) is None  # beyond the reach
    for t in (1.2, 1.3, 1.4):
        history.add(t, np.zeros(3))
    assert len(history) == 4 and history.at(1.0) is None  # the oldest were dropped


def test_the_tracker_finds_the_patch_where_it_moved_and_its_disparity():
    tex = texture()
    tracker = PatchTracker(PursuitParams(), (-30.0, 30.0))
    left, right = view(tex, 80.0, 60.0, d=-6.0)
    start = tracker.start(left, right, 80.0, 60.0)
    assert start is not None and start.d == pytest.approx(-6.0, abs=0.3)
    for x, y, d in ((86.3, 57.6, -5.0), (71.8, 66.2, -7.5)):
        left, right = view(tex, x, y, d)
        found = tracker.find(left, right, np.array([80.0, 60.0, -6.0]))
        assert found is not None and found.ncc > 0.9
        assert (found.x, found.y) == (pytest.approx(x, abs=0.25), pytest.approx(y, abs=0.25))
        assert found.d == pytest.approx(d, abs=0.3)
    # Gone (another texture there): not found.
    left, right = view(texture(seed=5), 80.0, 60.0)
    assert tracker.find(left, right, np.array([80.0, 60.0, -6.0])) is None
    # No patch to take on a flat image, nor across the border.
    flat = np.full((H, W), 90, np.float32)
    assert tracker.start(flat, flat, 80.0, 60.0) is None
    assert tracker.start(*view(tex, 80, 60), 3.0, 60.0) is None


class LinearMap:
    """A map whose command is J (r - fovea): pursuit's Jacobian must come out as J."""

    def __init__(self, jacobian: np.ndarray) -> None:
        self.jacobian = jacobian

    def command(self, position):
        r = np.asarray(position, dtype=float) - np.array([*FOVEA, 0.0])
        return self.jacobian @ r


def test_pursuit_follows_a_target_at_constant_speed_and_learns_its_velocity():
    """The closed loop on a synthetic world: the target's direction q(t) moves at 12 deg/s in pan
    and -4 deg/s in tilt; the image shows it where J^-1 (q - pose) says; each goal is reached
    one frame later (the head lags a frame). After a second the retinal error is well under a
    pixel and the estimated velocity is the true one."""
    jacobian = np.array([[-0.25, 0.0, -0.12], [0.0, -0.25, 0.0], [0.0, 0.0, -0.24]])
    velocity = np.array([12.0, -4.0, 0.0])
    q0 = np.array([1.0, 0.5, 8.0])
    period = 1 / 30
    tex = texture(3)
    pursuit = Pursuit(LinearMap(jacobian), (W, H), (-30.0, 30.0), PursuitParams(lead_s=period))

    def image_position(t: float, pose: np.ndarray) -> np.ndarray:
        return np.array([*FOVEA, 0.0]) + np.linalg.solve(jacobian, q0 + velocity * t - pose)

    pose = np.array([0.0, 0.0, 8.0])
    r = image_position(0.0, pose)
    step = pursuit.start(*view(tex, r[0], r[1], r[2]), 0.0, pose, r[0], r[1])
    assert step is not None and step.goal is not None
    np.testing.assert_allclose(pursuit.jacobian, jacobian, atol=1e-9)
    errors = []
    for k in range(1, 60):
        t = k * period
        pose = step.goal  # reached by the next exposure
        r = image_position(t, pose)
        step = pursuit.step(*view(tex, r[0], r[1], r[2]), t, pose, t)
        assert step.match is not None and step.goal is not None, f"lost at frame {k}"
        errors.append(float(np.hypot(*(r[:2] - FOVEA))))
    assert max(errors[30:]) < 0.6, errors
    np.testing.assert_allclose(step.velocity_deg_s, velocity, atol=0.8)


def test_a_patch_gone_for_n_pairs_is_lost_and_a_young_map_gives_way_to_the_default_jacobian():
    tex = texture(1)
    random_map = LinearMap(np.array([[0.3, 0.0, 0.0], [0.0, 0.3, 0.0], [0.0, 0.0, 0.3]]))  # wrong signs
    pursuit = Pursuit(random_map, (W, H), (-30.0, 30.0), PursuitParams(lost_after_frames=3))
    start = pursuit.start(*view(tex, 80, 60), 0.0, np.zeros(3), 80, 60)
    assert start is not None and not pursuit.map_plausible
    np.testing.assert_allclose(pursuit.jacobian, DEFAULT_JACOBIAN)
    noise = np.random.default_rng(9).uniform(0, 255, (H, W)).astype(np.float32)  # nothing of the patch
    other = (noise, noise)
    steps = [pursuit.step(*other, k / 30, np.zeros(3), k / 30) for k in range(1, 4)]
    assert [s.misses for s in steps] == [1, 2, 3] and [s.lost for s in steps] == [False, False, True]
    assert all(s.goal is None for s in steps)  # nothing is commanded on a missing patch
