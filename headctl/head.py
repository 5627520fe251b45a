"""The head as the fixation strategy sees it: `calib_free.fixation.GazeHead` over the drivers.

`DriverHead` turns a `drivers.servo_bus.ServoBus` (four joints) and a source of stereo
pairs into poses (pan, tilt, vergence) with symmetric eyes (left = +v/2, right = -v/2),
absolute moves clamped to the joint and vergence limits, "at rest" from the servos' own
moving flags and positions, and pairs exposed after a given time.

Pairs come from the cameras' capture threads (`StereoPairSource`, the service) or, in the
simulated experiments, straight from the renderer at the simulated clock's time
(`RenderedPairSource`: no frame is rendered while the head moves, which is what makes a
2,000-fixation run take a minute rather than ten).

With a `drivers.clock.ManualClock` the head runs faster than real time: waiting for rest
advances the clock instead of sleeping.
"""
from __future__ import annotations

import logging
import time
from typing import Callable, Protocol

import numpy as np

from calib_free.fixation import HeadTimeoutError, PairTimeoutError
from calib_free.sim import joints_of, pose_of
from drivers.camera import StereoPair
from drivers.clock import Clock, ManualClock
from drivers.errors import CameraTimeoutError
from drivers.servo_bus import ServoBus

log = logging.getLogger(__name__)

ImageTransform = Callable[[np.ndarray], np.ndarray]


class PairSource(Protocol):
    def wait_pair(self, after_s: float, timeout_s: float) -> tuple[np.ndarray, np.ndarray]: ...


class StereoPairSource:
    """Pairs from the cameras' capture threads."""

    def __init__(self, pair: StereoPair) -> None:
        self.pair = pair

    def wait_pair(self, after_s: float, timeout_s: float) -> tuple[np.ndarray, np.ndarray]:
        try:
            frames = self.pair.wait_pair(after_s, timeout_s)
        except CameraTimeoutError as err:
            raise PairTimeoutError(f"no stereo pair exposed after t={after_s:.3f} s: {err}") from err
        return frames.left.image, frames.right.image


class RenderedPairSource:
    """Pairs rendered on demand at the clock's time from the joints' true positions (simulation)."""

    def __init__(self, render: Callable[[dict[str, float]], tuple[np.ndarray, np.ndarray]],
                 joint_positions: Callable[[], dict[str, float]], clock: Clock,
                 noise_std: float = 0.0, seed: int = 0) -> None:
        self.render = render
        self.joint_positions = joint_positions
        self.clock = clock
        self.noise_std = noise_std  # sensor noise, grey levels: a flat wall must not match itself
        self._rng = np.random.default_rng(seed)

    def _noisy(self, image: np.ndarray) -> np.ndarray:
        if self.noise_std <= 0:
            return image
        noisy = image.astype(np.float32) + self._rng.normal(0.0, self.noise_std, image.shape).astype(np.float32)
        return np.clip(noisy, 0, 255).astype(np.uint8)

    def wait_pair(self, after_s: float, timeout_s: float) -> tuple[np.ndarray, np.ndarray]:
        now = self.clock.monotonic()
        if now < after_s:
            if not isinstance(self.clock, ManualClock):
                time.sleep(after_s - now)
            else:
                self.clock.advance(after_s - now)
        left, right = self.render(self.joint_positions())
        return self._noisy(left), self._noisy(right)


class DriverHead:
    """A `GazeHead` over a servo bus and a pair source."""

    def __init__(self, bus: ServoBus, pairs: PairSource, *, clock: Clock,
                 vergence_range: tuple[float, float] | None = None, settle_s: float = 0.05,
                 tolerance_deg: float = 0.3, poll_s: float = 0.01) -> None:
        self.bus = bus
        self.pairs = pairs
        self.clock = clock
        self.settle_s = settle_s
        self.tolerance_deg = tolerance_deg
        self.poll_s = poll_s
        self.image_transform: ImageTransform | None = None  # e.g. a prism: np.flipud
        # The paper's fig. 9 defect: added to the pan angle read (not to the goals written), so
        # every pan goal computed from a reading lands that much further.
        self.pan_reading_offset_deg = 0.0
        joints = bus.config.joints
        v_low = max(2 * joints["left_eye"].min_angle, -2 * joints["right_eye"].max_angle)
        v_high = min(2 * joints["left_eye"].max_angle, -2 * joints["right_eye"].min_angle)
        if vergence_range is not None:
            v_low, v_high = max(v_low, vergence_range[0]), min(v_high, vergence_range[1])
        if v_low >= v_high:
            raise ValueError(f"no vergence is possible within the eye joints' limits and {vergence_range}")
        self.pose_low = np.array([joints["pan"].min_angle, joints["tilt"].min_angle, v_low])
        self.pose_high = np.array([joints["pan"].max_angle, joints["tilt"].max_angle, v_high])
        self._goal: np.ndarray | None = None


    def read_pose(self) -> np.ndarray:
        return self.pose_from(self.bus.read_state().positions)

    def pose_from(self, positions: dict[str, float]) -> np.ndarray:
        """(pan, tilt, vergence) as this head reads joint positions (with the pan reading offset)."""
        pose = pose_of(positions)
        pose[0] += self.pan_reading_offset_deg
        return pose

    def move_to(self, pose: np.ndarray) -> np.ndarray:
        goal = np.clip(np.asarray(pose, dtype=float), self.pose_low, self.pose_high)
        # The servo bus checks each joint's limits again: no goal outside them is ever sent
        # (with a pan reading offset the goal computed from the reading may lie beyond).
        sent = self.bus.write_goals(joints_of(goal))
        self._goal = pose_of(sent)
        return goal

    def verge_to(self, vergence: float) -> float:
        """Move the eyes alone (symmetrically) to `vergence`, clamped; pan and tilt get no goal."""
        v = float(np.clip(vergence, self.pose_low[2], self.pose_high[2]))
        sent = self.bus.write_goals({"left_eye": v / 2, "right_eye": -v / 2})
        goal = self._goal if self._goal is not None else pose_of(self.bus.read_state().positions)
        self._goal = np.array([goal[0], goal[1], sent["left_eye"] - sent["right_eye"]])
        return v

    def _sleep(self, seconds: float) -> None:
        if isinstance(self.clock, ManualClock):
            self.clock.advance(seconds)
        else:
            self.clock.sleep(seconds)

    def wait_settled(self, timeout_s: float) -> float:
        """Block until the servos report no motion, at their goal, for `settle_s`."""
        deadline = self.clock.monotonic() + timeout_s
        rest_since: float | None = None
        while True:
            state = self.bus.read_state()
            at_goal = self._goal is None or bool(np.all(
                np.abs(pose_of(state.positions) - self._goal) <= self.tolerance_deg))
            if not state.moving and at_goal:
                rest_since = state.time_s if rest_since is None else rest_since
                if state.time_s - rest_since >= self.settle_s:
                    return rest_since
            else:
                rest_since = None
            if self.clock.monotonic() >= deadline:
                raise HeadTimeoutError(f"the head did not come to rest within {timeout_s} s "
                                       f"(moving: {state.moving}, at goal: {at_goal})")
            self._sleep(self.poll_s)

    def wait_pair(self, after_s: float, timeout_s: float) -> tuple[np.ndarray, np.ndarray]:
        left, right = self.pairs.wait_pair(after_s, timeout_s)
        if self.image_transform is not None:
            left, right = self.image_transform(left), self.image_transform(right)
        return left, right
