"""The head's frames for tf2: the frame tree of `headctl.ros2.geometry` as tf2 messages.

ROS's axes are the head model's (x forward, y left, z up), so a joint's published angle in
radians is its servo angle, and a URDF of these joints takes the axes of the tree. The joint
transforms change with the joints and go on `/tf`; the optical frames are fixed to their eyes
and go on `/tf_static`.
"""
from __future__ import annotations

from collections.abc import Mapping

from headctl.config.ros2 import Ros2Config
from headctl.ros2.geometry import SIDES, FrameTree, Transform
try:
    from headctl.ros2 import messages as m
except ImportError:  # no cyclonedds: the same messages from rosbags' typestore (a recording needs no DDS)
    from headctl.ros2 import bagtypes as m  # type: ignore[no-redef]

__all__ = ["SIDES", "HeadFrames"]


def _tf(t: Transform, stamp: m.Time) -> m.TransformStamped:
    x, y, z, w = t.rotation
    return m.TransformStamped(header=m.Header(stamp=stamp, frame_id=t.parent), child_frame_id=t.child,
                              transform=m.Transform(translation=m.Vector3(*t.translation_m),
                                                    rotation=m.Quaternion(x=x, y=y, z=z, w=w)))


class HeadFrames:
    """The frame ids of one head (prefixed by `ros2.frame_prefix`) and its transforms as tf2 messages."""

    def __init__(self, config: Ros2Config) -> None:
        self.tree = tree = FrameTree(config)
        self.mechanics = tree.mechanics
        self.base, self.pan, self.tilt = tree.base, tree.pan, tree.tilt
        self.eye, self.optical = tree.eye, tree.optical

    def moving(self, joints_deg: Mapping[str, float], stamp: m.Time) -> m.TFMessage:
        """The joints' transforms at these servo angles (degrees): `/tf`."""
        return m.TFMessage(transforms=[_tf(t, stamp) for t in self.tree.moving(joints_deg)])

    def static(self, stamp: m.Time) -> m.TFMessage:
        """Each eye's camera optical frame: `/tf_static`."""
        return m.TFMessage(transforms=[_tf(t, stamp) for t in self.tree.static()])
