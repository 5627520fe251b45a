"""The head's frame tree (`headctl.ros2.geometry`) against the head model's conventions: pan
+ turns the head left, tilt + raises it, an eye + turns it toward the head's right; each optical
frame looks along its eye (z forward, x right, y down); the eyes a baseline apart. Plain numbers:
no DDS and no message library needed."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from headctl.config.ros2 import Ros2Config, Ros2Mechanics
from headctl.ros2.geometry import FrameTree, Transform

ZERO = {"pan": 0.0, "tilt": 0.0, "left_eye": 0.0, "right_eye": 0.0}


def rotation(q: tuple[float, float, float, float]) -> np.ndarray:
    x, y, z, w = q
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def pose_in_base(tree: FrameTree, joints: dict[str, float], frame: str) -> tuple[np.ndarray, np.ndarray]:
    """The rotation and origin of `frame` in the base frame, composed along the tree."""
    by_child: dict[str, Transform] = {t.child: t for t in tree.moving(joints) + tree.static()}
    r, p = np.eye(3), np.zeros(3)
    chain = []
    while frame != tree.base:
        chain.append(by_child[frame])
        frame = by_child[frame].parent
    for t in reversed(chain):
        p = p + r @ np.asarray(t.translation_m)
        r = r @ rotation(t.rotation)
    return r, p


@pytest.mark.parametrize("joints, forward", [
    (ZERO, (1, 0, 0)),
    ({**ZERO, "pan": 90.0}, (0, 1, 0)),                       # pan + turns left (+y)
    ({**ZERO, "tilt": 90.0}, (0, 0, 1)),                      # tilt + raises (+z)
    ({**ZERO, "left_eye": 90.0, "right_eye": 90.0}, (0, -1, 0)),  # eyes + turn right (-y)
])
def test_each_optical_frame_looks_where_its_joints_point(joints: dict[str, float], forward: tuple[int, ...]) -> None:
    tree = FrameTree(Ros2Config())
    for side in ("left", "right"):
        r, _ = pose_in_base(tree, joints, tree.optical[side])
        np.testing.assert_allclose(r[:, 2], forward, atol=1e-12)  # the optical z axis: the line of sight
        if joints == ZERO:
            np.testing.assert_allclose(r[:, 0], (0, -1, 0), atol=1e-12)  # x right
            np.testing.assert_allclose(r[:, 1], (0, 0, -1), atol=1e-12)  # y down


def test_the_eyes_are_a_baseline_apart_left_on_the_left() -> None:
    mechanics = Ros2Mechanics(baseline_m=0.1, eye_offset_m=(0.03, 0.05), tilt_origin_m=(0.0, 0.0, 0.2))
    tree = FrameTree(dataclasses.replace(Ros2Config(), mechanics=mechanics, frame_prefix="h1/"))
    _, left = pose_in_base(tree, ZERO, tree.optical["left"])
    _, right = pose_in_base(tree, ZERO, tree.optical["right"])
    np.testing.assert_allclose(left, (0.03, 0.05, 0.25), atol=1e-12)
    np.testing.assert_allclose(left - right, (0.0, 0.1, 0.0), atol=1e-12)
    assert tree.optical["left"] == "h1/left_camera_optical_frame" and tree.base == "h1/base_link"
