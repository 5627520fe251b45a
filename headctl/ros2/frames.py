"""The head's frames for tf2, from its nominal geometry (`ros2.mechanics`).

    <base> -> neck_pan_link (about z by pan) -> neck_tilt_link (about -y by tilt: + raises)
           -> left_eye_link, right_eye_link (about -z by the eye's angle: + toward the right)
           -> left_camera_optical_frame, right_camera_optical_frame (z forward, x right, y down)

ROS's axes are the head model's (x forward, y left, z up), so a joint's published angle in
radians is its servo angle, and a URDF of these joints takes the axes above. The joint
transforms change with the joints and go on `/tf`; the optical frames are fixed to their eyes
and go on `/tf_static`. Nominal geometry only: the learned gaze map needs none of it.
"""
from __future__ import annotations

import math
from collections.abc import Mapping

from headctl.config.ros2 import Ros2Config
try:
    from headctl.ros2 import messages as m
except ImportError:  # no cyclonedds: the same messages from rosbags' typestore (a recording needs no DDS)
    from headctl.ros2 import bagtypes as m  # type: ignore[no-redef]

# eye link (x forward, y left, z up) -> optical frame (z forward, x right, y down)
OPTICAL = m.Quaternion(x=-0.5, y=0.5, z=-0.5, w=0.5)
SIDES = ("left", "right")


def _about(axis: tuple[float, float, float], angle_rad: float) -> m.Quaternion:
    s = math.sin(angle_rad / 2)
    return m.Quaternion(x=axis[0] * s, y=axis[1] * s, z=axis[2] * s, w=math.cos(angle_rad / 2))


class HeadFrames:
    """The frame ids and the transforms of one head (prefixed by `ros2.frame_prefix`)."""

    def __init__(self, config: Ros2Config) -> None:
        p = config.frame_prefix
        self.mechanics = config.mechanics
        self.base = p + config.base_frame
        self.pan = p + "neck_pan_link"
        self.tilt = p + "neck_tilt_link"
        self.eye = {side: f"{p}{side}_eye_link" for side in SIDES}
        self.optical = {side: f"{p}{side}_camera_optical_frame" for side in SIDES}

    def _tf(self, parent: str, child: str, xyz: tuple[float, float, float], rotation: m.Quaternion,
            stamp: m.Time) -> m.TransformStamped:
        return m.TransformStamped(header=m.Header(stamp=stamp, frame_id=parent), child_frame_id=child,
                                  transform=m.Transform(translation=m.Vector3(*xyz), rotation=rotation))

    def moving(self, joints_deg: Mapping[str, float], stamp: m.Time) -> m.TFMessage:
        """The joints' transforms at these servo angles (degrees): `/tf`."""
        mech = self.mechanics
        forward, up = mech.eye_offset_m
        half = mech.baseline_m / 2
        out = [self._tf(self.base, self.pan, mech.pan_origin_m,
                        _about((0.0, 0.0, 1.0), math.radians(joints_deg["pan"])), stamp),
               self._tf(self.pan, self.tilt, mech.tilt_origin_m,
                        _about((0.0, -1.0, 0.0), math.radians(joints_deg["tilt"])), stamp)]
        for side, y in (("left", half), ("right", -half)):
            out.append(self._tf(self.tilt, self.eye[side], (forward, y, up),
                                _about((0.0, 0.0, -1.0), math.radians(joints_deg[f"{side}_eye"])), stamp))
        return m.TFMessage(transforms=out)

    def static(self, stamp: m.Time) -> m.TFMessage:
        """Each eye's camera optical frame: `/tf_static`."""
        return m.TFMessage(transforms=[self._tf(self.eye[side], self.optical[side], (0.0, 0.0, 0.0), OPTICAL, stamp)
                                       for side in SIDES])
