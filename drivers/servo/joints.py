"""The head's four joints, by the names the hardware and every config use.

A servo bus drives exactly these joints; a config names a servo for each. How the eyes
move together (vergence) is composed above the drivers (`calib_free.kinematics`).
"""
from __future__ import annotations

JOINTS: tuple[str, str, str, str] = ("pan", "tilt", "left_eye", "right_eye")
