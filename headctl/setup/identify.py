"""Which joint each servo turns, and which way: read off the images while it moves a little.

`SafeProbing` moves servos by id (`drivers.servo.probe.ServoProbe`) only under a torque
limit, a velocity limit and a timeout (`MotionSafety`), and leaves each servo it touched
holding where it is, torque as it was, whatever ends it (an error, an interruption).
`identify` moves one servo at a time a few degrees and back while it takes a stereo pair at
rest before and after, and measures how each image moved (`image_shift`: phase correlation
of the central part); `classify` names the joint from that motion:

* both images shifting horizontally together: the neck pan; vertically together: the tilt;
* one image shifting horizontally, the other still: that eye;
* nothing visible, or a motion like none of those: reported, never guessed; two servos
  that move the images alike are both reported.

The sign follows the head's conventions (docs/architecture.md, "Conventions of the method"):
+ pan turns the head to its left, so the scene moves right in both images (+x); + tilt
turns it up, so the scene moves down (+y); an eye angle is + toward the head's right, so the
scene moves left (-x) in that eye's image. A joint's `direction` is +1 when a positive
servo step turns it the + way.
"""
from __future__ import annotations

import enum
import logging
import math
import threading
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Protocol

import cv2
import numpy as np

from drivers.clock import Clock
from drivers.errors import ServoError
from drivers.servo.probe import FoundServo, MotionSafety, ServoProbe, ServoStatus
from headctl.errors import HeadctlError

log = logging.getLogger(__name__)

POLL_S = 0.02             # how often a moving servo is read
SETTLE_TOLERANCE_DEG = 0.5
# A servo that carries a load (the tilt under the head's weight) rests short of its goal by its
# position loop's steady error (the X-series' default gains have no integral term), and its
# reading wobbles by a tick or two: at rest (not moving, two readings this close) within
# LOADED_TOLERANCE_DEG of the goal, it has arrived.
LOADED_TOLERANCE_DEG = 2.0
REST_JITTER_DEG = 0.3
MIN_SHIFT_PX = 1.0        # below this an image did not move
MIN_RESPONSE = 0.05       # phase correlation peaks below this are noise
# Scene motion (image x, y) per + joint degree, as signs: see the module docstring.
SCENE_SIGN = {"pan": (1, 0), "tilt": (0, 1), "left_eye": (-1, 0), "right_eye": (-1, 0)}


class Interrupted(HeadctlError):
    """The person asked to stop (Ctrl-C): every servo touched was left holding."""


class Finding(enum.StrEnum):
    IDENTIFIED = "identified"
    NOTHING_VISIBLE = "moves nothing visible"
    UNATTRIBUTED = "image motion like no joint"
    ALIKE = "moves the images like another servo"
    DID_NOT_MOVE = "did not move"


class PairSource(Protocol):
    def wait_pair(self, after_s: float, timeout_s: float) -> tuple[np.ndarray, np.ndarray]:
        """The first (left, right) pair exposed after `after_s`."""


@dataclass(frozen=True)
class Shift:
    """How an image moved between two frames (px, x right, y down) and how sure (0-1)."""

    dx: float
    dy: float
    response: float

    @property
    def size(self) -> float:
        return math.hypot(self.dx, self.dy)


@dataclass(frozen=True)
class ServoFinding:
    """What probing one servo found. `left`/`right`: the image shifts per + servo degree."""

    servo: FoundServo
    start: ServoStatus
    outcome: Finding
    joint: str | None = None
    direction: int | None = None
    step_deg: float = 0.0
    left: Shift | None = None
    right: Shift | None = None
    px_per_deg: float | None = None
    detail: str = ""


def _grey(image: np.ndarray) -> np.ndarray:
    return image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)


def image_shift(before: np.ndarray, after: np.ndarray) -> Shift:
    """How the scene moved from `before` to `after`: phase correlation of the central half of
    each image (where a fish-eye lens magnifies least unevenly)."""
    a, b = _grey(before), _grey(after)
    h, w = a.shape
    crop = (slice(h // 4, h // 4 + h // 2), slice(w // 4, w // 4 + w // 2))
    ca, cb = a[crop].astype(np.float32), b[crop].astype(np.float32)
    window = cv2.createHanningWindow((ca.shape[1], ca.shape[0]), cv2.CV_32F)
    (dx, dy), response = cv2.phaseCorrelate(ca, cb, window)
    return Shift(float(dx), float(dy), float(response))


def classify(left: Shift, right: Shift) -> tuple[Finding, str | None, int | None, str]:
    """(finding, joint, direction, detail) for image shifts per + servo degree, scaled so
    that MIN_SHIFT_PX is the smallest motion that counts."""
    moved = {side: s.size >= MIN_SHIFT_PX and s.response >= MIN_RESPONSE for side, s in (("left", left),
                                                                                         ("right", right))}
    seen = (f"left image ({left.dx:+.1f}, {left.dy:+.1f}) px, right image ({right.dx:+.1f}, {right.dy:+.1f}) px")
    if not any(moved.values()):
        return Finding.NOTHING_VISIBLE, None, None, f"{seen}: neither image moved"

    def horizontal(s: Shift) -> bool:
        return abs(s.dx) > 2.0 * abs(s.dy)

    def vertical(s: Shift) -> bool:
        return abs(s.dy) > 2.0 * abs(s.dx)

    if all(moved.values()):
        ratio = left.size / right.size
        if not 0.5 <= ratio <= 2.0:
            return Finding.UNATTRIBUTED, None, None, f"{seen}: both moved, by unlike amounts"
        if horizontal(left) and horizontal(right) and left.dx * right.dx > 0:
            return Finding.IDENTIFIED, "pan", _sign(left.dx + right.dx), f"{seen}: both horizontally together"
        if vertical(left) and vertical(right) and left.dy * right.dy > 0:
            return Finding.IDENTIFIED, "tilt", _sign(left.dy + right.dy), f"{seen}: both vertically together"
        return Finding.UNATTRIBUTED, None, None, f"{seen}: both moved, not together along one axis"
    side = "left" if moved["left"] else "right"
    shift = left if side == "left" else right
    if horizontal(shift):
        return Finding.IDENTIFIED, f"{side}_eye", -_sign(shift.dx), f"{seen}: the {side} image only, horizontally"
    return Finding.UNATTRIBUTED, None, None, f"{seen}: the {side} image only, not horizontally"


def _sign(x: float) -> int:
    return 1 if x > 0 else -1


@dataclass
class _Touched:
    torque_on: bool


class SafeProbing:
    """Moves of servos by id under `safety`, each undone on exit: every servo touched is left
    holding where it is (goal := present), its motion settings restored, torque as it was.
    `interrupt` (set by Ctrl-C) ends any wait with `Interrupted`. A context manager."""

    def __init__(self, probe: ServoProbe, clock: Clock, safety: MotionSafety = MotionSafety(),
                 interrupt: threading.Event | None = None) -> None:
        self.probe = probe
        self.clock = clock
        self.safety = safety
        self.interrupt = interrupt or threading.Event()
        self._touched: dict[int, _Touched] = {}

    def check(self) -> None:
        if self.interrupt.is_set():
            raise Interrupted("interrupted")

    def take(self, servo_id: int) -> ServoStatus:
        """Limit the servo's motion and hold it with torque on where it is (no jump)."""
        self.check()
        status = self.probe.status(servo_id)
        if servo_id not in self._touched:
            self._touched[servo_id] = _Touched(status.torque_on)
        self.probe.limit_motion(servo_id, self.safety)
        self.probe.write_goal(servo_id, status.position_deg)
        if not status.torque_on:
            self.probe.set_torque(servo_id, True)
        return status

    def move(self, servo_id: int, goal_deg: float, timeout_s: float | None = None) -> ServoStatus:
        """Move to `goal_deg` (servo frame) and wait until it rests there; on a timeout the
        servo is held where it got to and `ServoError` raised naming it."""
        self.check()
        start = self.probe.status(servo_id)
        if timeout_s is None:
            travel_s = abs(goal_deg - start.position_deg) / self.safety.velocity_dps
            timeout_s = 2.0 * travel_s + 2.0 * self.safety.velocity_dps / self.safety.acceleration_dps2 + 1.0
        self.probe.write_goal(servo_id, goal_deg)
        deadline_s = self.clock.monotonic() + timeout_s
        previous: ServoStatus | None = None
        while True:
            self.clock.sleep(POLL_S)
            try:
                self.check()
            except Interrupted:
                self._hold(servo_id)
                raise
            status = self.probe.status(servo_id)
            if arrived(status, previous, goal_deg):
                self.probe.keep_alive(servo_id)
                return status
            previous = status
            if self.clock.monotonic() > deadline_s:
                self._hold(servo_id)
                raise ServoError(f"id {servo_id} on {self.probe.name}: did not reach {goal_deg:.1f} deg within "
                                 f"{timeout_s:.1f} s (at {status.position_deg:.1f} deg, torque limited to "
                                 f"{self.safety.torque_fraction:.0%}): held where it is")

    def _hold(self, servo_id: int) -> None:
        status = self.probe.status(servo_id)
        self.probe.write_goal(servo_id, min(max(status.position_deg, status.min_deg), status.max_deg))
        self.probe.keep_alive(servo_id)

    def release(self, servo_id: int) -> None:
        """Hold the servo where it is, settings restored, torque as it was before `take`."""
        touched = self._touched.pop(servo_id, None)
        if touched is None:
            return
        status = self.probe.status(servo_id)
        if status.torque_on:
            self.probe.write_goal(servo_id, min(max(status.position_deg, status.min_deg), status.max_deg))
        self.probe.restore_motion(servo_id)
        if status.torque_on != touched.torque_on:
            self.probe.set_torque(servo_id, touched.torque_on)

    def close(self) -> None:
        """Release every servo still taken (errors logged, the others still released)."""
        for servo_id in list(self._touched):
            try:
                self.release(servo_id)
            except (ServoError, OSError) as err:
                log.error("id %d on %s: could not be released: %s", servo_id, self.probe.name, err)
                self._touched.pop(servo_id, None)

    def __enter__(self) -> "SafeProbing":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def arrived(status: ServoStatus, previous: ServoStatus | None, goal_deg: float) -> bool:
    """A servo moved to `goal_deg` has arrived: still and on it, or at rest (still, as at the
    read before) within a loaded servo's steady error of it."""
    if status.moving:
        return False
    error = abs(status.position_deg - goal_deg)
    if error <= SETTLE_TOLERANCE_DEG:
        return True
    return (error <= LOADED_TOLERANCE_DEG and previous is not None and not previous.moving
            and abs(status.position_deg - previous.position_deg) <= REST_JITTER_DEG)


@dataclass
class Identification:
    """Every servo's finding, and which servo turns each joint (only those identified once)."""

    findings: list[ServoFinding] = field(default_factory=list)

    @property
    def joints(self) -> dict[str, ServoFinding]:
        return {f.joint: f for f in self.findings if f.outcome is Finding.IDENTIFIED and f.joint is not None}

    def missing(self, joints: Sequence[str]) -> list[str]:
        return [joint for joint in joints if joint not in self.joints]


def pair_after(pairs: PairSource, clock: Clock, timeout_s: float) -> tuple[np.ndarray, np.ndarray]:
    return pairs.wait_pair(clock.monotonic(), timeout_s)


def identify(probing: SafeProbing, pairs: PairSource, servos: Sequence[FoundServo], *, step_deg: float = 3.0,
             frame_timeout_s: float = 2.0, say: Callable[[str], None] = lambda text: None) -> Identification:
    """Probe each servo in turn (see the module docstring); servos that share a joint are
    marked `ALIKE`."""
    result = Identification()
    for servo in servos:
        result.findings.append(_probe_one(probing, pairs, servo, step_deg, frame_timeout_s, say))
    by_joint: dict[str, list[int]] = {}
    for i, f in enumerate(result.findings):
        if f.outcome is Finding.IDENTIFIED and f.joint is not None:
            by_joint.setdefault(f.joint, []).append(i)
    for joint, indices in by_joint.items():
        if len(indices) > 1:
            ids = ", ".join(str(result.findings[i].servo.servo_id) for i in indices)
            for i in indices:
                f = result.findings[i]
                result.findings[i] = ServoFinding(
                    f.servo, f.start, Finding.ALIKE, None, None, f.step_deg, f.left, f.right, f.px_per_deg,
                    f"ids {ids} all move the images as the {joint} does; not guessed")
    return result


def _probe_one(probing: SafeProbing, pairs: PairSource, servo: FoundServo, step_deg: float, frame_timeout_s: float,
               say: Callable[[str], None]) -> ServoFinding:
    start = probing.take(servo.servo_id)
    step = step_deg if start.position_deg + step_deg <= start.max_deg else -step_deg
    if not start.min_deg <= start.position_deg + step <= start.max_deg:
        probing.release(servo.servo_id)
        return ServoFinding(servo, start, Finding.DID_NOT_MOVE, detail="no room within its own limits to move")
    say(f"  id {servo.servo_id}: moving {step:+.1f} deg and back")
    before = pair_after(pairs, probing.clock, frame_timeout_s)
    try:
        moved = probing.move(servo.servo_id, start.position_deg + step)
    except ServoError as err:
        probing.release(servo.servo_id)
        return ServoFinding(servo, start, Finding.DID_NOT_MOVE, step_deg=step, detail=str(err))
    after = pair_after(pairs, probing.clock, frame_timeout_s)
    probing.move(servo.servo_id, start.position_deg)
    probing.release(servo.servo_id)
    actual = moved.position_deg - start.position_deg
    left, right = image_shift(before[0], after[0]), image_shift(before[1], after[1])
    per_deg = [Shift(s.dx / actual, s.dy / actual, s.response) for s in (left, right)]
    # Judged on the whole step's motion (MIN_SHIFT_PX is in pixels moved), signed per + degree.
    whole = [Shift(s.dx * math.copysign(1, actual), s.dy * math.copysign(1, actual), s.response)
             for s in (left, right)]
    outcome, joint, direction, detail = classify(whole[0], whole[1])
    px_per_deg = None
    if joint is not None:
        px_per_deg = (per_deg[0].size + per_deg[1].size) / 2 if joint in ("pan", "tilt") \
            else (per_deg[0] if joint == "left_eye" else per_deg[1]).size
    return ServoFinding(servo, start, outcome, joint, direction, actual, per_deg[0], per_deg[1], px_per_deg, detail)
