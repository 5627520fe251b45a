"""A geometric model of the stereo head (paper section III-A), for simulation and experiments.

Frames. World and head: x forward, y to the head's left, z up (metres). Joint angles in
degrees (the conventions of `calib_free.kinematics`):
  - pan: + turns the head to its left (about z);
  - tilt: + turns the head up (about the panned y axis);
  - eyes: each yaws about the tilted z axis through its own optical centre; an eye angle is
    + toward the head's RIGHT, so that with theta_l = +v/2 and theta_r = -v/2 the vergence
    v = theta_l - theta_r is + when the eyes converge.
The eyes sit at +-baseline/2 on the head's y axis, offset from the tilt axis by
`eye_offset_m` (forward, up). Each camera looks through a `FisheyeLens`.

A pose is (pan, tilt, vergence) in degrees; a motor command m is a relative pose change
(dpan, dtilt, dverg). Image positions r = (x, y, d): x, y in the left image, d = x_r - x_l.

`FixationSampler` draws random fixation commands in motor space: the fixated world point
(where the optical axes cross after the command) projected into the pre-fixation images
gives r, and (r, m) is a training pair, as in the paper's simulation. `Perturbation`
switches on the paper's disturbances: baseline change, vertical prism, swapped eyes,
pan encoder offset, motor gain error.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np

from calib_free.kinematics import eye_angles
from calib_free.lens import FisheyeLens

# Camera (x right, y down, z forward) from eye (x forward, y left, z up).
_CAM_FROM_EYE = np.array([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]])


def _rot_z(angle_rad: float) -> np.ndarray:
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _rot_y(angle_rad: float) -> np.ndarray:
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


class Surroundings(Protocol):
    """What the head can fixate: the first surface a ray meets (world, metres)."""

    def first_surface(self, origin: np.ndarray, direction: np.ndarray) -> np.ndarray | None:
        """The first point along the ray from `origin` in the unit `direction`; None if none."""


@dataclass(frozen=True)
class JointLimits:
    """Absolute joint ranges in degrees (the comparable model of issue 2)."""

    pan: tuple[float, float] = (-40.0, 40.0)
    tilt: tuple[float, float] = (-25.0, 25.0)
    vergence: tuple[float, float] = (3.0, 20.0)

    @property
    def low(self) -> np.ndarray:
        return np.array([self.pan[0], self.tilt[0], self.vergence[0]])

    @property
    def high(self) -> np.ndarray:
        return np.array([self.pan[1], self.tilt[1], self.vergence[1]])

    def clamp(self, pose: np.ndarray) -> np.ndarray:
        clamped: np.ndarray = np.clip(pose, self.low, self.high)
        return clamped

    def contains(self, pose: np.ndarray) -> bool:
        return bool(np.all(pose >= self.low - 1e-9) and np.all(pose <= self.high + 1e-9))


@dataclass
class Perturbation:
    """The paper's disturbances of the head, all off by default.

    `motor_offset_deg` and `motor_gain` act on executed motion: the head really moves
    gain * m + offset when the controller commands (and believes it executed) m. A pan
    encoder offset of +10 deg (paper fig. 9) is motor_offset_deg = (10, 0, 0): the
    controller adds its offset reading to every relative pan goal.
    """

    baseline_delta_m: float = 0.0
    vertical_prism: bool = False
    swap_eyes: bool = False
    motor_offset_deg: tuple[float, float, float] = (0.0, 0.0, 0.0)
    motor_gain: tuple[float, float, float] = (1.0, 1.0, 1.0)

    def executed(self, command: np.ndarray) -> np.ndarray:
        """The motion the head really makes for a commanded relative move."""
        motion: np.ndarray = np.asarray(self.motor_gain) * command + np.asarray(self.motor_offset_deg)
        return motion

    def command_for(self, motion: np.ndarray) -> np.ndarray:
        """The command that makes the head really move by `motion` (inverse of `executed`)."""
        command: np.ndarray = (np.asarray(motion) - np.asarray(self.motor_offset_deg)) / np.asarray(self.motor_gain)
        return command


@dataclass
class HeadModel:
    """Kinematics and optics of the 4-DoF head."""

    lens_left: FisheyeLens
    lens_right: FisheyeLens
    baseline_m: float = 0.060
    eye_offset_m: tuple[float, float] = (0.02, 0.06)
    limits: JointLimits = field(default_factory=JointLimits)
    perturbation: Perturbation = field(default_factory=Perturbation)

    @classmethod
    def default(cls, width: int = 320, height: int = 240, lens: str = "foveated", **kwargs: Any) -> "HeadModel":
        fisheye = FisheyeLens.named(lens, width, height)
        return cls(lens_left=fisheye, lens_right=fisheye, **kwargs)

    @property
    def width(self) -> int:
        return self.lens_left.width

    @property
    def height(self) -> int:
        return self.lens_left.height

    @property
    def effective_baseline_m(self) -> float:
        return self.baseline_m + self.perturbation.baseline_delta_m

    # -- kinematics --------------------------------------------------------------------
    def head_rotation(self, pose: np.ndarray) -> np.ndarray:
        pan, tilt = np.radians(pose[0]), np.radians(pose[1])
        rotation: np.ndarray = _rot_z(pan) @ _rot_y(-tilt)  # + tilt raises the forward axis
        return rotation

    def eye_frames(self, pose: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
        """[(R, c)] for the left and right eye at a symmetric pose (pan, tilt, vergence)."""
        return self.eye_frames_from_joints(pose[0], pose[1], *eye_angles(pose[2]))

    def eye_frames_from_joints(self, pan: float, tilt: float, left_eye: float,
                               right_eye: float) -> list[tuple[np.ndarray, np.ndarray]]:
        """[(R, c)] for the left and right eye: camera-from-world rotation and optical centre.

        Joint angles in degrees; eye angles + toward the head's right (see the module doc).
        """
        head = self.head_rotation(np.array([pan, tilt]))
        forward, up = self.eye_offset_m
        half = self.effective_baseline_m / 2
        frames = []
        for side, theta in ((+1.0, left_eye), (-1.0, right_eye)):
            centre = head @ np.array([forward, side * half, up])
            eye_rotation = head @ _rot_z(-np.radians(theta))
            frames.append((_CAM_FROM_EYE @ eye_rotation.T, centre))
        return frames

    def fixation_point(self, pose: np.ndarray) -> np.ndarray | None:
        """Where the two optical axes cross (world, metres), or None if they do not converge."""
        half_verg = np.radians(pose[2]) / 2
        if half_verg <= 1e-6:
            return None
        forward, up = self.eye_offset_m
        distance = (self.effective_baseline_m / 2) / np.tan(half_verg)
        point: np.ndarray = self.head_rotation(pose) @ np.array([forward + distance, 0.0, up])
        return point

    def vergence_fixating(self, pan_tilt: np.ndarray, surroundings: Surroundings) -> float | None:
        """The vergence whose fixation point at (pan, tilt) is the first surface straight ahead
        (along the head's forward axis midway between the eyes); None if no surface is there."""
        rotation = self.head_rotation(np.asarray(pan_tilt, dtype=float))
        forward, up = self.eye_offset_m
        origin = rotation @ np.array([forward, 0.0, up])
        point = surroundings.first_surface(origin, rotation[:, 0])
        if point is None:
            return None
        distance = float(np.linalg.norm(point - origin))
        return float(np.degrees(2.0 * np.arctan2(self.effective_baseline_m / 2, distance)))

    # -- optics ------------------------------------------------------------------------
    def project(self, points: np.ndarray, pose: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Left pixels, right pixels (N, 2) and seen-by-both mask (N,) of world points (N, 3).

        The perturbation applies here: a vertical prism flips each image upside down; swapped
        eyes exchange the left and right images.
        """
        pts = np.atleast_2d(np.asarray(points, dtype=float))
        out = []
        for (rotation, centre), lens in zip(self.eye_frames(pose), (self.lens_left, self.lens_right)):
            uv, seen = lens.project((pts - centre) @ rotation.T)
            if self.perturbation.vertical_prism:
                uv = uv.copy()
                uv[:, 1] = (lens.height - 1) - uv[:, 1]
            out.append((uv, seen))
        if self.perturbation.swap_eyes:
            out.reverse()
        (uv_l, seen_l), (uv_r, seen_r) = out
        return uv_l, uv_r, seen_l & seen_r

    def image_position(self, points: np.ndarray, pose: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """r = (x, y, d) (N, 3) of world points in the images taken at `pose`, and the seen mask."""
        uv_l, uv_r, seen = self.project(points, pose)
        return np.column_stack([uv_l[:, 0], uv_l[:, 1], uv_r[:, 0] - uv_l[:, 0]]), seen

    def landing_error_px(self, target: np.ndarray, pose_after: np.ndarray) -> float:
        """Distance of `target` from the left fovea (image centre) at `pose_after`, in pixels.

        A target behind the camera or outside the view counts as the distance of the (clipped)
        projection, which is large; the caller decides what that means.
        """
        uv_l, _, _ = self.project(target[None, :], pose_after)
        cx, cy = self.lens_left.principal_point
        return float(np.hypot(uv_l[0, 0] - cx, uv_l[0, 1] - cy))


@dataclass
class FixationSample:
    """One (r, m) pair: where the fixated point was in the pre-fixation images, and the command."""

    position: np.ndarray  # r = (x, y, d)
    command: np.ndarray  # m = (dpan, dtilt, dverg) as the controller knows it
    target: np.ndarray  # the fixated world point
    pose_before: np.ndarray


class FixationSampler:
    """Random fixation commands in motor space and the (r, m) pairs they give.

    The head carries its pose from one fixation to the next. Each step picks a uniformly
    random absolute pose within the joint limits, commands the relative move m, and moves the
    head by what the (perturbed) motors really do. A fixated point not seen by both eyes
    before the move, or whose disparity is outside `disparity_range`, gives no sample (the
    real system would find no correspondence), and the sampler draws again.

    With `surroundings` the vergence is not drawn: each pose fixates the first surface straight
    ahead (`HeadModel.vergence_fixating`), as a head looking at the things around it does; a
    pose whose vergence for that surface is outside the limits is drawn again.
    """

    def __init__(self, head: HeadModel, disparity_range: tuple[float, float] = (-60.0, 60.0),
                 seed: int | None = 0, start_pose: np.ndarray | None = None,
                 surroundings: Surroundings | None = None) -> None:
        self.head = head
        self.disparity_range = disparity_range
        self.rng = np.random.default_rng(seed)
        self.surroundings = surroundings
        mid = (head.limits.low + head.limits.high) / 2
        self.pose = np.array(start_pose if start_pose is not None else mid, dtype=float)
        if start_pose is None and surroundings is not None:  # verged on what is straight ahead
            vergence = head.vergence_fixating(self.pose[:2], surroundings)
            if vergence is not None:
                self.pose[2] = float(np.clip(vergence, *head.limits.vergence))

    def _pose_to_reach(self) -> np.ndarray | None:
        """A uniformly random pose within the limits; with `surroundings`, its vergence the one
        fixating them (None if that is outside the limits or nothing is there)."""
        limits = self.head.limits
        reached: np.ndarray = self.rng.uniform(limits.low, limits.high)
        if self.surroundings is not None:
            vergence = self.head.vergence_fixating(reached[:2], self.surroundings)
            if vergence is None or not limits.vergence[0] <= vergence <= limits.vergence[1]:
                return None
            reached[2] = vergence
        return reached

    def draw(self, move: bool = True, max_tries: int = 10_000) -> FixationSample:
        """The next usable (r, m) pair; with move=False the head stays where it is (a probe)."""
        for _ in range(max_tries):
            # Draw where the head really goes, then the command that takes it there through
            # the (perturbed) motors: the pair stays exact even near the joint limits.
            reached = self._pose_to_reach()
            if reached is None:
                continue
            command = self.head.perturbation.command_for(reached - self.pose)
            target = self.head.fixation_point(reached)
            if target is None:
                continue
            r, seen = self.head.image_position(target[None, :], self.pose)
            ok = seen[0] and self.disparity_range[0] <= r[0, 2] <= self.disparity_range[1]
            sample = FixationSample(r[0], command, target, self.pose.copy())
            if move:
                self.pose = reached
            if ok:
                return sample
        raise RuntimeError(f"no visible fixation target in {max_tries} draws: check the head model and limits")

    def execute(self, command: np.ndarray) -> np.ndarray:
        """Move the head by `command` as the (perturbed) motors do, within the joint limits."""
        self.pose = self.head.limits.clamp(self.pose + self.head.perturbation.executed(np.asarray(command)))
        return self.pose


def with_perturbation(head: HeadModel, **changes: Any) -> HeadModel:
    """A copy of `head` with some perturbation fields changed."""
    return dataclasses.replace(head, perturbation=dataclasses.replace(head.perturbation, **changes))
