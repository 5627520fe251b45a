"""Poses and joint angles of a 4-joint stereo head: the conventions every head shares.

A pose is (pan, tilt, vergence) in degrees: pan + turns the head to its left, tilt + up,
vergence v = theta_l - theta_r + when the eyes converge. The eyes move symmetrically:
theta_l = +v/2, theta_r = -v/2. Joint angles are {pan, tilt, left_eye, right_eye} in degrees.
Real heads (`headctl.service.head`) and the geometric model (`calib_free.sim.head_model`) both use these.
"""
from __future__ import annotations

from collections.abc import Mapping

import numpy as np

AXES: tuple[str, str, str] = ("pan", "tilt", "vergence")
JOINTS: tuple[str, str, str, str] = ("pan", "tilt", "left_eye", "right_eye")


def joints_of(pose: np.ndarray) -> dict[str, float]:
    """Joint angles {pan, tilt, left_eye, right_eye} of a pose (pan, tilt, vergence), eyes symmetric."""
    return {"pan": float(pose[0]), "tilt": float(pose[1]),
            "left_eye": float(pose[2] / 2), "right_eye": float(-pose[2] / 2)}


def pose_of(joints: Mapping[str, float]) -> np.ndarray:
    """The pose (pan, tilt, vergence = left_eye - right_eye) of joint angles."""
    return np.array([joints["pan"], joints["tilt"], joints["left_eye"] - joints["right_eye"]])
