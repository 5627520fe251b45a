"""Pursuit's disparity on an unsynchronised pair (two free-running cameras): the head pans
while the right image is taken 15 ms after the left, and the disparity measured is brought
to the left image's time; without the correction it is off by the image's motion."""
from __future__ import annotations

import numpy as np
import pytest

from calib_free.gaze.pursuit import Pursuit, PursuitParams
from calib_free.kinematics import vergence_of
from calib_free.sim.head_model import HeadModel
from drivers.cameras.camera import create_camera
from drivers.cameras.config import CameraConfig
from drivers.sim.camera import fixed_pose

W, H = 320, 240
PAN_DEG_S = 30.0
LAG_S = 0.015  # the right camera's phase after the left's


class YoungMap:
    """A map without a plausible Jacobian: pursuit uses its default one (the foveated lens)."""

    def command(self, position: object) -> np.ndarray:
        return np.zeros(3)


def joints_at(t_s: float) -> dict[str, float]:
    return {"pan": -5.0 + PAN_DEG_S * t_s, "tilt": 3.0, "left_eye": 2.0, "right_eye": -2.0}


def pose_at(t_s: float) -> np.ndarray:
    j = joints_at(t_s)
    return np.array([j["pan"], j["tilt"], vergence_of(j["left_eye"], j["right_eye"])])


@pytest.fixture(scope="module")
def eyes():
    head = HeadModel.default(W, H)
    cams = [create_camera(CameraConfig.from_mapping({"backend": "sim", "eye": eye, "width": W, "height": H,
                                                    "seed": 1}), head=head, pose_source=fixed_pose())
            for eye in ("left", "right")]
    for cam in cams:
        cam.open()
    yield cams
    for cam in cams:
        cam.close()


def disparity(pursuit: Pursuit, left: np.ndarray, right: np.ndarray, t_s: float, lag_s: float = 0.0) -> float:
    step = pursuit.start(left, right, t_s, pose_at(t_s), (W - 1) / 2.0, (H - 1) / 2.0, right_lag_s=lag_s,
                         right_pose=pose_at(t_s + lag_s))
    assert step is not None and step.match is not None and step.match.d_ncc > 0.8
    return step.match.d


@pytest.mark.parametrize("t_s", [0.2, 0.35, 0.5])
def test_a_disparity_on_an_unsynchronised_pair_is_brought_to_the_left_image_time(eyes, t_s):
    left_cam, right_cam = eyes
    left = left_cam.render(joints_at(t_s))
    synchronous = right_cam.render(joints_at(t_s))
    late = right_cam.render(joints_at(t_s + LAG_S))  # the head panned 0.45 deg meanwhile
    pursuit = Pursuit(YoungMap(), (W, H), (-60.0, 60.0))
    truth = disparity(pursuit, left, synchronous, t_s)
    corrected = disparity(pursuit, left, late, t_s, LAG_S)
    assert corrected == pytest.approx(truth, abs=0.5)
    uncorrected = disparity(Pursuit(YoungMap(), (W, H), (-60.0, 60.0), PursuitParams(correct_skew=False)),
                            left, late, t_s, LAG_S)
    assert abs(uncorrected - truth) > 1.2  # 30 deg/s x 15 ms x ~4 px/deg = 1.8 px


def test_a_step_brings_the_disparity_to_the_left_image_time(eyes):
    left_cam, right_cam = eyes
    pursuit = Pursuit(YoungMap(), (W, H), (-60.0, 60.0))
    t0 = 0.3
    assert pursuit.start(left_cam.render(joints_at(t0)), right_cam.render(joints_at(t0)), t0, pose_at(t0),
                         (W - 1) / 2.0, (H - 1) / 2.0) is not None
    t1 = t0 + 1 / 30
    truth = Pursuit(YoungMap(), (W, H), (-60.0, 60.0))
    x, y = pursuit.last.x, pursuit.last.y
    left = left_cam.render(joints_at(t1))
    step = pursuit.step(left, right_cam.render(joints_at(t1 + LAG_S)), t1, pose_at(t1), t1 + 0.04,
                        right_lag_s=LAG_S, right_pose=pose_at(t1 + LAG_S))
    assert step.match is not None and step.match.d_ncc > 0.8
    # The same patch, where the head's pan moved it, measured on a synchronous pair.
    reference = truth.start(left, right_cam.render(joints_at(t1)), t1, pose_at(t1), step.match.x, step.match.y)
    assert reference is not None and reference.match is not None
    assert step.match.d == pytest.approx(reference.match.d, abs=0.5)
    assert abs(step.match.x - x) > 3  # the head moved the patch: 30 deg/s for a frame
