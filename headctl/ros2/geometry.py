"""The head's frame tree from its nominal geometry (`ros2.mechanics`), as plain numbers.

    <base> -> neck_pan_link (about z by pan) -> neck_tilt_link (about -y by tilt: + raises)
           -> left_eye_link, right_eye_link (about -z by the eye's angle: + toward the right)
           -> left_camera_optical_frame, right_camera_optical_frame (z forward, x right, y down)

The axes are the head model's (x forward, y left, z up, as ROS's REP 103), so a joint's angle
in radians is its servo angle. The joint transforms change with the joints; the optical frames
are fixed to their eyes. Nominal geometry only: the learned gaze map needs none of it. The
ROS 2 transforms (`headctl.ros2.frames`) and the Foxglove view's (`headctl.foxglove`) are made
from this one tree; it needs neither DDS nor any message library.
"""
from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

from headctl.config.ros2 import Ros2Config

Vector = tuple[float, float, float]
Quaternion = tuple[float, float, float, float]  # (x, y, z, w)

# eye link (x forward, y left, z up) -> optical frame (z forward, x right, y down)
OPTICAL: Quaternion = (-0.5, 0.5, -0.5, 0.5)
SIDES = ("left", "right")


@dataclass(frozen=True)
class Transform:
    """Where `child` is in `parent`: its origin (metres) and its rotation."""

    parent: str
    child: str
    translation_m: Vector
    rotation: Quaternion


def about(axis: Vector, angle_rad: float) -> Quaternion:
    """The rotation by `angle_rad` about the unit vector `axis`."""
    s = math.sin(angle_rad / 2)
    return axis[0] * s, axis[1] * s, axis[2] * s, math.cos(angle_rad / 2)


class FrameTree:
    """The frame ids (prefixed by `ros2.frame_prefix`) and the transforms of one head."""

    def __init__(self, config: Ros2Config) -> None:
        p = config.frame_prefix
        self.mechanics = config.mechanics
        self.base = p + config.base_frame
        self.pan = p + "neck_pan_link"
        self.tilt = p + "neck_tilt_link"
        self.eye = {side: f"{p}{side}_eye_link" for side in SIDES}
        self.optical = {side: f"{p}{side}_camera_optical_frame" for side in SIDES}

    def moving(self, joints_deg: Mapping[str, float]) -> list[Transform]:
        """The joints' transforms at these servo angles (degrees)."""
        mech = self.mechanics
        forward, up = mech.eye_offset_m
        half = mech.baseline_m / 2
        out = [Transform(self.base, self.pan, mech.pan_origin_m, about((0.0, 0.0, 1.0), math.radians(joints_deg["pan"]))),
               Transform(self.pan, self.tilt, mech.tilt_origin_m,
                         about((0.0, -1.0, 0.0), math.radians(joints_deg["tilt"])))]
        for side, y in (("left", half), ("right", -half)):
            out.append(Transform(self.tilt, self.eye[side], (forward, y, up),
                                 about((0.0, 0.0, -1.0), math.radians(joints_deg[f"{side}_eye"]))))
        return out

    def static(self) -> list[Transform]:
        """Each eye's camera optical frame, fixed to its eye."""
        return [Transform(self.eye[side], self.optical[side], (0.0, 0.0, 0.0), OPTICAL) for side in SIDES]
