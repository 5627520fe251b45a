"""Poses of a stereo head with symmetric eyes: the conventions every head shares.

A pose is (pan, tilt, vergence) in degrees: pan + turns the head to its left, tilt + up,
vergence v = theta_l - theta_r + when the eyes converge. The eyes move symmetrically:
theta_l = +v/2, theta_r = -v/2 (`eye_angles`, `vergence_of`). Real heads
(`headctl.service.head`, which names the joints) and the geometric model
(`calib_free.sim.head_model`) both use these.
"""
from __future__ import annotations

AXES: tuple[str, str, str] = ("pan", "tilt", "vergence")


def eye_angles(vergence: float) -> tuple[float, float]:
    """(left eye, right eye) angles in degrees of a vergence, the eyes symmetric."""
    return vergence / 2, -vergence / 2


def vergence_of(left_eye: float, right_eye: float) -> float:
    """The vergence of two eye angles (degrees)."""
    return left_eye - right_eye
