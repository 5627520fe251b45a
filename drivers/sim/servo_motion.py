"""The simulated servos' motion: a trapezoidal velocity profile toward the goal, and the trace of it.

`ProfileAxis` is the motion model the simulated bus and the Dynamixel emulator share (an
X-series servo in position mode with a velocity-based profile). `GearedAxis` is the same
profile seen through a servo's mechanics (`drivers.sim.servo_mechanics`): the shaft droops under
a load, and the output beyond it has play; `AxisState` is its state at rest (a servo process
restarted on the simulated head builds its servos from it). `JointTrace` records the motion
model's state of the four joints at every change of course and at reads into a short ring, and
`joints_at` replays the model from it: where the joints were at a past time (a simulated
frame's exposure, rendered later).
"""
from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from drivers.servo.joints import JOINTS

# Integration step of the motion model: fine enough that a profile ends within a
# millisecond of the analytic one, coarse enough that a 10 s jump of a ManualClock costs
# a few thousand steps.
_STEP_S = 0.001
# The trace of the joints' true motion: a row each time the motion changes course (goals
# written, torque, a hold) and at each read, at least 2 ms apart (a read sooner after the
# newest row is not kept, a change replaces it), so 128 rows span over a second at the servo
# loop's 100 Hz, longer than a simulated frame waits for its rendering.
TRACE_SAMPLES = 128
_TRACE_SPACING_S = 0.002
# Each joint's fields: the profile's state, then where the output is (the true joint angle:
# beyond the play, with the droop), the play and the droop at horizontal (0 and 0: the ideal servo, replayed as a
# plain profile).
TRACE_FIELDS = ("position", "velocity", "goal", "max_velocity", "max_acceleration", "output", "backlash", "sag")
_PROFILE_FIELDS = 5
TRACE_WIDTH = 1 + len(TRACE_FIELDS) * len(JOINTS)  # time, then each joint's fields in JOINTS order
# A replay never runs past this many seconds beyond its row (a bound on its cost; the servo
# loop writes goals every 10 ms, so past rows are a cycle apart).
_REPLAY_MAX_S = 0.1


class ProfileAxis:
    """One joint moving toward its goal under a velocity and an acceleration limit.

    Unit-agnostic (degrees for the simulator, ticks for the emulator). A limit of
    `math.inf` means unlimited. Not thread-safe: its owner serialises access.
    """

    def __init__(self, position: float, time_s: float, max_velocity: float = math.inf,
                 max_acceleration: float = math.inf) -> None:
        self.position = float(position)
        self.velocity = 0.0
        self.goal = float(position)
        self.max_velocity = max_velocity
        self.max_acceleration = max_acceleration
        self.time_s = time_s

    @property
    def moving(self) -> bool:
        return self.position != self.goal or self.velocity != 0.0

    def set_goal(self, goal: float) -> None:
        self.goal = float(goal)

    def hold(self) -> None:
        """Stop where the axis is now (torque off, watchdog, reboot)."""
        self.goal = self.position
        self.velocity = 0.0

    def advance_to(self, time_s: float) -> None:
        """Move the model forward to `time_s` (earlier times are ignored)."""
        dt_total = time_s - self.time_s
        if dt_total <= 0.0:
            return
        self.time_s = time_s
        remaining = dt_total
        while remaining > 0.0 and self.moving:
            dt = min(_STEP_S, remaining)
            remaining -= dt
            self._step(dt)

    def _step(self, dt: float) -> None:
        distance = self.goal - self.position
        direction = math.copysign(1.0, distance) if distance else -math.copysign(1.0, self.velocity)
        accel = self.max_acceleration
        # The fastest speed from which the axis can still stop at the goal.
        stop_speed = math.sqrt(2.0 * accel * abs(distance)) if math.isfinite(accel) else math.inf
        target_v = direction * min(self.max_velocity, stop_speed)
        if math.isinf(target_v):
            self.position, self.velocity = self.goal, 0.0
            return
        max_dv = accel * dt
        self.velocity += min(max(target_v - self.velocity, -max_dv), max_dv)
        new_position = self.position + self.velocity * dt
        if (self.goal - new_position) * direction <= 0.0:
            # Reached (or would pass) the goal: settle exactly on it.
            self.position, self.velocity = self.goal, 0.0
            return
        self.position = new_position


@dataclass(frozen=True)
class AxisState:
    """A geared axis's mechanical state, all a servo at rest has beyond its config: where its
    position controller holds (`position`) and where the output is (`output`); the shaft follows
    from the position and the load, and `output` minus the shaft is where the output sits in
    the play. Degrees, in one frame: the servo's inside `GearedAxis`, the joint's between
    processes (`mapped` turns one into the other)."""

    position: float
    output: float

    def mapped(self, angle: Callable[[float], float]) -> "AxisState":
        """The same state in another frame: `angle` maps an angle of this one to it (an affine
        map, `WiredServo.joint_angle` or `servo_angle`, so the play's offset maps alike)."""
        return AxisState(angle(self.position), angle(self.output))


class GearedAxis(ProfileAxis):
    """A `ProfileAxis` (the position the servo's controller holds) seen through the servo's
    mechanics: `shaft` is where the output shaft is (the profile's position, displaced by
    `load`, the droop under a load at that position, in the axis's frame), which the encoder
    reads; `output` is what the shaft turns beyond a play of `backlash` (degrees, the whole
    width): it moves only when the shaft pushes it at one end of the play, and under a load it
    rests on the flank the load pushes it to. With neither, `output` is the profile's position.
    """

    def __init__(self, position: float, time_s: float, max_velocity: float = math.inf,
                 max_acceleration: float = math.inf, *, backlash: float = 0.0,
                 load: Callable[[float], float] | None = None, output: float | None = None) -> None:
        super().__init__(position, time_s, max_velocity, max_acceleration)
        self.backlash = backlash
        self.load = load
        self.output = self.shaft
        if output is not None:
            self.output = output
        self._follow()

    @property
    def shaft(self) -> float:
        return self.position + self.load(self.position) if self.load is not None else self.position

    @property
    def state(self) -> AxisState:
        """The mechanical state now (this axis's frame); `output=` and the position rebuild it."""
        return AxisState(self.position, self.output)

    def _step(self, dt: float) -> None:
        super()._step(dt)
        self._follow()

    def _follow(self) -> None:
        """The output after the shaft's latest step: dragged at one end of the play, or on the
        load's flank."""
        shaft = self.shaft
        half = self.backlash / 2.0
        if self.load is not None:
            pull = self.load(self.position)
            if pull:
                self.output = shaft + math.copysign(half, pull)
                return
        self.output = min(max(self.output, shaft - half), shaft + half)


class JointTrace:
    """The joints' true motion at past times: rows of the motion model's state (time, then for
    each joint in `JOINTS` order the `TRACE_FIELDS`: its position, velocity, goal, velocity and
    acceleration limits, output, play and droop; degrees, joint frame), as an array that can live in shared memory (`rows`; unused rows
    have a NaN time), a ring of the last `size`.

    `at(time_s)` replays the motion model (`ProfileAxis`) from the last row at or before
    `time_s`: exact as long as every change of course is a row (the bus records one at each);
    before the oldest row, the oldest position. Not thread-safe: its owner serialises access
    (a reader in another process copies `rows` under its own lock)."""

    def __init__(self, size: int = TRACE_SAMPLES) -> None:
        self.rows = np.full((size, TRACE_WIDTH), np.nan)
        self._next = 0

    def add(self, time_s: float, axes: Mapping[str, Sequence[float]], change: bool = False) -> None:
        """A row of each joint's `TRACE_FIELDS` at `time_s`; the first five alone stand for an
        ideal servo (its output at its position, no play, no droop). Within 2 ms of the newest
        row, a `change` of course replaces it and a plain sample is not kept."""
        newest = self.rows[(self._next - 1) % len(self.rows)]
        if time_s - newest[0] < _TRACE_SPACING_S:
            if not change:
                return
            row = newest
        else:
            row = self.rows[self._next]
            self._next = (self._next + 1) % len(self.rows)
        row[0] = time_s
        for j, joint in enumerate(JOINTS):
            fields = tuple(axes.get(joint, (math.nan,) * _PROFILE_FIELDS))
            if len(fields) == _PROFILE_FIELDS:
                fields += (fields[0], 0.0, 0.0)
            row[1 + j * len(TRACE_FIELDS):1 + (j + 1) * len(TRACE_FIELDS)] = fields

    def at(self, time_s: float) -> dict[str, float] | None:
        return joints_at(self.rows, time_s)


def joints_at(rows: np.ndarray, time_s: float) -> dict[str, float] | None:
    """The joint angles at `time_s` from `JointTrace` rows (in any order); None without a row."""
    times = rows[:, 0]
    known = np.isfinite(times)
    if not known.any():
        return None
    before = known & (times <= time_s)
    output_field = TRACE_FIELDS.index("output")
    if not before.any():  # older than the trace: the oldest position known
        row = rows[np.flatnonzero(known)[np.argmin(times[known])]]
        return {joint: float(row[1 + j * len(TRACE_FIELDS) + output_field]) for j, joint in enumerate(JOINTS)}
    row = rows[np.flatnonzero(before)[np.argmax(times[before])]]
    joints = {}
    for j, joint in enumerate(JOINTS):
        position, velocity, goal, max_velocity, max_acceleration, out, backlash, sag = \
            row[1 + j * len(TRACE_FIELDS):1 + (j + 1) * len(TRACE_FIELDS)]
        if not (backlash or sag):  # the ideal servo: the profile alone
            axis = ProfileAxis(position, row[0], max_velocity, max_acceleration)
            axis.velocity, axis.goal = float(velocity), float(goal)
            axis.advance_to(min(time_s, row[0] + _REPLAY_MAX_S))
            joints[joint] = axis.position
            continue
        geared = GearedAxis(position, row[0], max_velocity, max_acceleration, backlash=float(backlash),
                            load=tilt_droop(float(sag)), output=float(out))
        geared.velocity, geared.goal = float(velocity), float(goal)
        geared.advance_to(min(time_s, row[0] + _REPLAY_MAX_S))
        joints[joint] = geared.output
    return joints


def tilt_droop(sag_deg_at_horizontal: float) -> Callable[[float], float] | None:
    """The tilt's droop at a tilt angle (joint frame, degrees; negative: down, as tilt + is up):
    the gravity torque of a centre of mass ahead of the tilt axis goes with cos(tilt). None
    without a droop."""
    if not sag_deg_at_horizontal:
        return None
    return lambda tilt_deg: -sag_deg_at_horizontal * math.cos(math.radians(tilt_deg))
