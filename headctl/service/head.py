"""The head: a servo bus and two cameras turned into what the fixation strategy needs.

`Head` implements `calib_free.gaze.fixation.GazeHead` over anything that reads and writes joint
angles (`JointBus`: a `drivers.servo.bus.ServoBus`, or the service's servo loop) and a source
of stereo pairs (`PairSource`). It works in poses (pan, tilt, vergence) with symmetric eyes
(`calib_free.kinematics`; `joints_of` and `pose_of` name the joints), clamps absolute moves to the joint and vergence limits, judges
"at rest" from the servos' own moving flags and positions, and delivers pairs exposed after
a given time. A pose asked for is where the encoders are to read at rest: a loaded servo's
proportional control rests short of its goal (the tilt droops under the head's weight), so the
goal sent is the pose less the offset at which the joints came to rest from their goals over
the last rests (`rest_offset`, learned as the head runs; no calibration). Without it every
move relative to a reading would lose the droop: a look's corrective steps of a pixel or two
would leave the target where it was.

What differs between the service and the experiments is given, not subclassed:
- `interrupt`: called before every bus access and every slice of waiting for frames; it
  raises `FixationInterrupted` to stop the fixation in progress (the service stopping, a
  client cancelling its look);
- `observer` (`HeadObserver`): told the phase of the fixation, saccade onset and end, and the
  frame-to-command latency of each vergence step (the service publishes them as events);
- `goals_in_force`: the goals the bus really drives to, where they can differ from those sent
  (the servo loop holds a faulted joint, or the present position on stale input);
- bus errors become `FixationInterrupted` (servo bus down, servo fault), so every way a
  fixation can end is one `FixationOutcome`.

Pairs come from the cameras' capture threads (`StereoPairSource`, the service) or, in the
simulated experiments, are rendered on demand at the clock's time (`RenderedPairSource`: no
frame is rendered while the head moves, which is what makes a 2,000-fixation run take a
minute rather than ten). With a `drivers.clock.ManualClock` the head runs faster than real
time: waiting for rest advances the clock instead of sleeping.
"""
from __future__ import annotations

import logging
from typing import Callable, Mapping, Protocol, runtime_checkable

import numpy as np

from calib_free.gaze.fixation import FixationInterrupted, FixationOutcome, HeadTimeoutError, PairTimeoutError
from calib_free.kinematics import eye_angles, vergence_of
from drivers.clock import SYSTEM_CLOCK, Clock
from drivers.errors import BusDownError, CameraError, CameraTimeoutError, DeviceStateError, DriverError
from drivers.servo.bus import BusState
from drivers.servo.config import JointConfig
from drivers.servo.joints import JOINTS
from drivers.cameras.stereo import StereoPair
from headctl.errors import ServoLoopStoppedError
from headctl.service.play import PlayCompensation

log = logging.getLogger(__name__)


def joints_of(pose: np.ndarray) -> dict[str, float]:
    """Joint angles {pan, tilt, left_eye, right_eye} of a pose (pan, tilt, vergence), eyes symmetric."""
    left_eye, right_eye = eye_angles(float(pose[2]))
    return {"pan": float(pose[0]), "tilt": float(pose[1]), "left_eye": left_eye, "right_eye": right_eye}


def pose_of(joints: Mapping[str, float]) -> np.ndarray:
    """The pose (pan, tilt, vergence) of joint angles."""
    return np.array([joints["pan"], joints["tilt"], vergence_of(joints["left_eye"], joints["right_eye"])])


class JointBus(Protocol):
    """Joint angles in and out: a `ServoBus`, or the service's servo loop."""

    def read_state(self) -> BusState: ...

    def write_goals(self, goals: Mapping[str, float]) -> dict[str, float]: ...


class PairSource(Protocol):
    def wait_pair(self, after_s: float, timeout_s: float) -> tuple[np.ndarray, np.ndarray]:
        """The first (left, right) pair exposed after `after_s`; PairTimeoutError if none came."""

    @property
    def last_exposure_s(self) -> float | None:
        """When the last pair given was exposed (monotonic), if known."""


@runtime_checkable
class PairTimes(Protocol):
    """A pair source that tells both timestamps of the last pair given: unsynchronised
    cameras expose their two images at different times (`StereoPairSource`)."""

    @property
    def last_pair_times_s(self) -> tuple[float, float] | None:
        """(left, right) timestamps of the last pair given (monotonic), if any."""


class HeadObserver(Protocol):
    """What the head tells about the fixation in progress (called on the fixation's thread)."""

    def phase(self, phase: str) -> None: ...

    def saccade_onset(self, pose_before: np.ndarray, goal: np.ndarray) -> None: ...

    def saccade_done(self, pose: np.ndarray, goal: np.ndarray, duration_s: float) -> None: ...

    def vergence_commanded(self, frame_to_command_s: float) -> None: ...


def vergence_limits(joints: Mapping[str, JointConfig],
                    vergence_range: tuple[float, float] | None = None) -> tuple[float, float]:
    """The vergence the eye joints' limits allow (symmetric eyes), within `vergence_range`."""
    v_low = max(2 * joints["left_eye"].min_angle, -2 * joints["right_eye"].max_angle)
    v_high = min(2 * joints["left_eye"].max_angle, -2 * joints["right_eye"].min_angle)
    if vergence_range is not None:
        v_low, v_high = max(v_low, vergence_range[0]), min(v_high, vergence_range[1])
    if v_low >= v_high:
        raise ValueError(f"no vergence is possible within the eye joints' limits and {vergence_range}")
    return v_low, v_high


def _interrupted(err: BaseException) -> FixationInterrupted:
    """A bus error as the way the fixation in progress ends."""
    if isinstance(err, (BusDownError, TimeoutError)):  # the bus gone, or no fresh state in time
        return FixationInterrupted(FixationOutcome.BUS_DOWN, str(err))
    if isinstance(err, ServoLoopStoppedError):
        return FixationInterrupted(FixationOutcome.SHUTDOWN, str(err))
    return FixationInterrupted(FixationOutcome.SERVO_FAULT, str(err))  # a hardware error, a limit refused, torque off


class Head:
    """A `GazeHead` over a joint bus and a pair source; see the module docstring."""

    REST_POSE_KEPT_S = 0.5  # a rest's mean pose stands for the pose this long (torque may go off)

    def __init__(self, bus: JointBus, pairs: PairSource, joints: Mapping[str, JointConfig], *,
                 clock: Clock = SYSTEM_CLOCK, vergence_range: tuple[float, float] | None = None,
                 interrupt: Callable[[], None] | None = None, observer: HeadObserver | None = None,
                 goals_in_force: Callable[[], Mapping[str, float]] | None = None,
                 settle_s: float = 0.05, tolerance_deg: float = 0.3, steady_deg: float = 0.3,
                 short_tolerance_deg: float = 1.0, short_settle_s: float = 0.15, poll_s: float = 0.01) -> None:
        self._bus = bus
        self.pairs = pairs
        self.clock = clock
        self.interrupt = interrupt
        self.observer = observer
        self.goals_in_force = goals_in_force
        self.settle_s = settle_s
        # At rest: no servo reports motion and the pose stays within `steady_deg` (a reading
        # wobbles by a tick, 0.09 deg, an eye pair's vergence by two) for `settle_s` within
        # `tolerance_deg` of the goal, or for `short_settle_s` within `short_tolerance_deg` of
        # it: a loaded servo rests short of its goal (the tilt droops under the head's weight),
        # and the longer wait tells a servo that stopped short from one that has not started.
        self.tolerance_deg = tolerance_deg
        self.steady_deg = steady_deg
        self.short_tolerance_deg = short_tolerance_deg
        self.short_settle_s = short_settle_s
        self.poll_s = poll_s
        v_low, v_high = vergence_limits(joints, vergence_range)
        self.pose_low = np.array([joints["pan"].min_angle, joints["tilt"].min_angle, v_low])
        self.pose_high = np.array([joints["pan"].max_angle, joints["tilt"].max_angle, v_high])
        self._goal: np.ndarray | None = None
        # (when, the mean pose) of the last rest, until a goal is sent or REST_POSE_KEPT_S pass
        self._rest_pose: tuple[float, np.ndarray] | None = None
        # The last rest as the bus reads it: (its mean pose, the goals it rested at, the time from
        # which it was at rest), until a goal is sent; a head still resting there need not wait
        # for rest again.
        self._last_rest: tuple[np.ndarray, np.ndarray | None, float] | None = None
        # Where the joints come to rest relative to their goals (pan, tilt, vergence), averaged
        # over the last rests: a loaded servo's proportional control rests short of its goal by
        # a load-dependent offset (the tilt droops under the head's weight) that the encoder
        # reads. A rest is judged "at goal" against the goal plus this offset, so a drooping
        # tilt is not made to wait the longer `short_settle_s` at every saccade and vergence step.
        self.rest_offset = np.zeros(3)
        self._saccade: tuple[float, np.ndarray] | None = None  # (onset, goal) until at rest
        self.phase = "idle"
        # Goals beyond their targets by half each joint's play, readings back to the joints.
        self.play = PlayCompensation({name: joint.backlash_deg for name, joint in joints.items()},
                                     {name: (joint.min_angle, joint.max_angle) for name, joint in joints.items()})

    @property
    def bus(self) -> JointBus:
        return self._bus

    @bus.setter
    def bus(self, bus: JointBus) -> None:
        """Drive another bus (one wrapping this, say): the goal written to the old one is
        forgotten, its readings may not be this one's."""
        self._bus = bus
        self._goal = None
        self._rest_pose = None
        self._last_rest = None
        self.rest_offset = np.zeros(3)
        self.play.reset()

    # -- the bus, interruptible ------------------------------------------------------------
    def _check(self) -> None:
        if self.interrupt is not None:
            self.interrupt()

    def _read_state(self) -> BusState:
        self._check()
        try:
            return self.bus.read_state()
        except (DriverError, ServoLoopStoppedError, TimeoutError) as err:
            raise _interrupted(err) from err

    def _write_goals(self, targets: Mapping[str, float]) -> dict[str, float]:
        """Send the goals that bring the joints to `targets` (beyond them by half their play);
        returns the goals the bus sent, as the encoders are to read them."""
        self._check()
        self._rest_pose = self._last_rest = None  # the head may move
        try:
            return self.bus.write_goals(self.play.goals(targets, lambda: self._read_state().positions))
        except (DriverError, ServoLoopStoppedError, TimeoutError) as err:
            raise _interrupted(err) from err

    def set_phase(self, phase: str) -> None:
        """What the head is doing, for the status ("saccade", "fine vergence", "idle", ...)."""
        self.phase = phase
        if self.observer is not None:
            self.observer.phase(phase)

    # -- GazeHead ----------------------------------------------------------------------------
    def read_pose(self) -> np.ndarray:
        """The pose now; at rest (after `wait_settled`, before the next goal), the mean of the
        readings while the head held still: a reading wobbles by a tick (0.09 deg), and the
        executed command is the difference of two poses."""
        if self._rest_pose is not None and self.clock.monotonic() - self._rest_pose[0] <= self.REST_POSE_KEPT_S:
            return self._rest_pose[1].copy()
        return self.pose_from(self._read_state().positions)

    def pose_from(self, positions: Mapping[str, float]) -> np.ndarray:
        """(pan, tilt, vergence) of the joints at the encoders' `positions` (less the play)."""
        return pose_of(self.play.joints(positions))

    def move_to(self, pose: np.ndarray) -> np.ndarray:
        """A saccade: pan, tilt and vergence together to `pose`, clamped to the limits; the goals
        sent are the pose less `rest_offset` (clamped again), so that the joints come to rest
        at the pose. Returns where they are to rest."""
        self.set_phase("saccade")
        before = self.read_pose() if self.observer is not None else None
        goal = self.follow_to(pose)
        self._saccade = (self.clock.monotonic(), goal)
        if self.observer is not None and before is not None:
            self.observer.saccade_onset(before, goal)
        return goal

    def follow_to(self, pose: np.ndarray) -> np.ndarray:
        """A pursuit's goal, sent at once: pan, tilt and vergence toward `pose`, clamped to the
        limits, the goals less `rest_offset` and with the play taken up, as `move_to`'s, so that
        a track's head is where its goals say (no droop below them, no play behind them). No
        saccade is timed and the phase stays. Returns where the joints are to come to."""
        wanted = np.clip(np.asarray(pose, dtype=float), self.pose_low, self.pose_high)
        # The servo bus checks each joint's limits again: no goal outside them is ever sent
        # (a bus whose readings are off may be sent a goal beyond them).
        aimed = np.clip(wanted - self.rest_offset, self.pose_low, self.pose_high)
        self._goal = pose_of(self._write_goals(joints_of(aimed)))
        goal: np.ndarray = aimed + self.rest_offset
        return goal

    def verge_to(self, vergence: float) -> float:
        """Move the eyes alone (symmetrically) to `vergence`, clamped, their goals less the
        vergence's `rest_offset` as `move_to`'s; pan and tilt get no goal."""
        self.set_phase("fine vergence")
        v = float(np.clip(vergence, self.pose_low[2], self.pose_high[2]))
        aimed = float(np.clip(v - self.rest_offset[2], self.pose_low[2], self.pose_high[2]))
        left_eye, right_eye = eye_angles(aimed)
        sent = self._write_goals({"left_eye": left_eye, "right_eye": right_eye})
        exposed_s = self.pairs.last_exposure_s
        if self.observer is not None and exposed_s is not None:
            # From the exposure of the pair this step reacts to until its goal was on the bus.
            self.observer.vergence_commanded(self.clock.monotonic() - exposed_s)
        goal = self._goal if self._goal is not None else pose_of(self._read_state().positions)
        self._goal = np.array([goal[0], goal[1], vergence_of(sent["left_eye"], sent["right_eye"])])
        return aimed + float(self.rest_offset[2])

    def wait_settled(self, timeout_s: float, same_rest: bool = False) -> float:
        """Block until the servos report no motion and hold still near their goal for `settle_s`.
        A head that has been sent no goal since its last rest, still resting there (one reading:
        no servo moving, the pose within `steady_deg` of that rest's, the same goals in force),
        is still at rest: the next fixation need not wait `settle_s` again. It returns the time
        now, not the old rest's, so that a pair waited for after it is exposed after whatever
        changed since (an exposure locked for the fixation, a camera stalled); with `same_rest`,
        from a caller that knows nothing changed (a look's corrective fixation, under the look's
        one exposure lock), that rest's own time, so that the pair it was judged in will do."""
        if self.phase in ("idle", "choosing target"):
            self.set_phase("at rest")
        if self.goals_in_force is not None:
            # "At goal" means at the goals the bus really drives to: a goal no servo is driven
            # to (a joint held after a hardware error, a hold on stale input) is never reached.
            goals = self.goals_in_force()
            self._goal = pose_of(goals) if all(j in goals for j in JOINTS) \
                else None
        last = self._last_rest
        if last is not None:
            rest_pose_raw, rest_goal, rested_s = last
            state = self._read_state()
            same_goal = (rest_goal is None and self._goal is None) or (
                rest_goal is not None and self._goal is not None and np.array_equal(rest_goal, self._goal))
            if same_goal and not state.moving and np.all(np.abs(pose_of(state.positions) - rest_pose_raw)
                                                         <= self.steady_deg):
                return rested_s if same_rest else self.clock.monotonic()
            self._last_rest = None
        started_s = self.clock.monotonic()
        deadline = started_s + timeout_s
        rest_since: float | None = None
        rest_pose = np.zeros(3)
        held: list[np.ndarray] = []  # the poses read since the head held still
        raw: list[np.ndarray] = []  # ... as the bus reads them, as its goals are
        next_poll_s = self.clock.monotonic()
        while True:
            state = self._read_state()
            pose = pose_of(state.positions)
            off = np.zeros(3) if self._goal is None else np.abs(pose - self._goal - self.rest_offset)
            at_goal = bool(np.all(off <= self.tolerance_deg))
            if not state.moving and np.all(off <= self.short_tolerance_deg):
                if rest_since is None or np.any(np.abs(pose - rest_pose) > self.steady_deg):
                    rest_since, rest_pose, held, raw = state.time_s, pose, [self.pose_from(state.positions)], [pose]
                else:
                    held.append(self.pose_from(state.positions))
                    raw.append(pose)
                    if state.time_s - rest_since >= (self.settle_s if at_goal else self.short_settle_s):
                        break
            else:
                rest_since = None
            if self.clock.monotonic() >= deadline:
                raise HeadTimeoutError(f"the head did not come to rest within {timeout_s} s "
                                       f"(moving: {state.moving}, at goal: {at_goal})")
            self._check()
            # Polls `poll_s` apart: a bus whose read waits for the servo loop's next state
            # (the service's) is read again at once, so that no state is missed.
            now_s = self.clock.monotonic()
            next_poll_s = max(next_poll_s + self.poll_s, now_s)
            self.clock.sleep(next_poll_s - now_s)
        self._rest_pose = (self.clock.monotonic(), np.mean(held, axis=0))
        assert rest_since is not None  # the loop ends only at a rest
        if log.isEnabledFor(logging.DEBUG):
            log.debug("at rest after %.3f s (still from %.3f s), %s (off %s deg)", self.clock.monotonic() - started_s,
                      rest_since - started_s, "at goal" if at_goal else "short of goal", np.round(off, 2).tolist())
        self._last_rest = (np.mean(raw, axis=0), None if self._goal is None else self._goal.copy(), rest_since)
        if self._goal is not None:
            limit = self.short_tolerance_deg - self.tolerance_deg
            self.rest_offset = np.clip(0.5 * (self.rest_offset + np.mean(raw, axis=0) - self._goal), -limit, limit)
        if self._saccade is not None:
            onset_s, goal = self._saccade
            self._saccade = None
            if self.observer is not None:
                self.observer.saccade_done(self.pose_from(state.positions), goal, rest_since - onset_s)
        return rest_since

    def wait_pair(self, after_s: float, timeout_s: float) -> tuple[np.ndarray, np.ndarray]:
        self._check()
        phase = self.phase
        if ":" not in phase:
            self.set_phase(f"{phase}: waiting for frames")
        try:
            left, right = self.pairs.wait_pair(after_s, timeout_s)
        finally:
            self.set_phase(phase)
        return left, right


class StereoPairSource:
    """Pairs from the cameras' capture threads, waited for in short slices so that `interrupt`
    can stop the wait (a stopping service is not held up by a stalled camera)."""

    def __init__(self, pair: StereoPair, *, clock: Clock = SYSTEM_CLOCK,
                 interrupt: Callable[[], None] | None = None, slice_s: float = 0.1) -> None:
        self.pair = pair
        self.clock = clock
        self.interrupt = interrupt
        self.slice_s = slice_s
        self._last_exposure_s: float | None = None
        self._last_times_s: tuple[float, float] | None = None

    @property
    def last_exposure_s(self) -> float | None:
        return self._last_exposure_s

    @property
    def last_pair_times_s(self) -> tuple[float, float] | None:
        return self._last_times_s

    def wait_pair(self, after_s: float, timeout_s: float) -> tuple[np.ndarray, np.ndarray]:
        deadline = self.clock.monotonic() + timeout_s
        while True:
            if self.interrupt is not None:
                self.interrupt()
            remaining = deadline - self.clock.monotonic()
            try:
                frames = self.pair.wait_pair(after_s, max(0.0, min(self.slice_s, remaining)))
            except CameraTimeoutError as err:
                if remaining <= self.slice_s:
                    raise PairTimeoutError(f"no stereo pair exposed after t={after_s:.3f} s: {err}") from err
                continue
            except (CameraError, DeviceStateError) as err:  # failed, or being restarted: no pair
                raise PairTimeoutError(f"no stereo pair exposed after t={after_s:.3f} s: {err}") from err
            self._last_exposure_s = max(frames.left.time_s, frames.right.time_s)
            self._last_times_s = (frames.left.time_s, frames.right.time_s)
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
        self._last_exposure_s: float | None = None

    @property
    def last_exposure_s(self) -> float | None:
        return self._last_exposure_s

    def _noisy(self, image: np.ndarray) -> np.ndarray:
        if self.noise_std <= 0:
            return image
        noisy = image.astype(np.float32) + self._rng.normal(0.0, self.noise_std, image.shape).astype(np.float32)
        return np.clip(noisy, 0, 255).astype(np.uint8)

    def wait_pair(self, after_s: float, timeout_s: float) -> tuple[np.ndarray, np.ndarray]:
        now = self.clock.monotonic()
        if now < after_s:
            self.clock.sleep(after_s - now)
        self._last_exposure_s = self.clock.monotonic()
        left, right = self.render(self.joint_positions())
        return self._noisy(left), self._noisy(right)

