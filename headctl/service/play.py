"""Taking up the joints' play: goals sent beyond their targets in the direction of approach.

A servo's gears leave play between the shaft its encoder reads and the joint the camera turns
with (an XM430's is about 0.25 deg, the width of a foveal pixel). Moving one way, the joint
trails the shaft by half the play; after a reversal the shaft turns through the whole play
before the joint moves at all. So a move relative to a reading lands short by the play at
every reversal, and a look's first saccade, or a vergence step, lands a pixel off where it
was aimed half the time. No map of the image and the pose can learn that: it depends on the
way the joint came.

`PlayCompensation` sends each goal half the play beyond its target in the direction the joint
approaches it from, so that the joint itself comes to rest at the target whichever way it came,
and reads the joint as the encoder less that half play: what the head reports is where the
joint is, not where the shaft is. A joint that a load keeps on one flank of its play (a tilt
carrying the head's weight) has no reversal to take up and is given no play
(`servo_bus.joints.<joint>.backlash_deg`, docs/config.md). The play is the servo's datasheet
figure, not a calibration: nothing is measured on the head.
"""
from __future__ import annotations

from typing import Callable, Mapping

# A target this close to the last one is the same target: the joint keeps its direction.
SAME_TARGET_DEG = 1e-6


class PlayCompensation:
    """Goals beyond their targets by half each joint's play, and readings back to the joints.

    `play_deg`: each joint's whole play (0 or missing: none); `limits`: each joint's
    (min, max) angle, which no goal sent passes (at a limit the joint rests short of its
    target by up to half its play)."""

    def __init__(self, play_deg: Mapping[str, float], limits: Mapping[str, tuple[float, float]]) -> None:
        self.half_play = {joint: play / 2.0 for joint, play in play_deg.items() if play > 0}
        self.limits = dict(limits)
        self._approach: dict[str, float] = {}  # +1 or -1: the way each joint last came to its target
        self._target: dict[str, float] = {}

    def reset(self) -> None:
        """Forget the joints' directions (another bus, whose joints may have moved)."""
        self._approach.clear()
        self._target.clear()

    def goals(self, targets: Mapping[str, float], positions: Callable[[], Mapping[str, float]]) -> dict[str, float]:
        """The goals to send for joint `targets`. A joint's direction of approach is from its
        last target; the first time, from where `positions()` (the encoders now) puts it."""
        goals = dict(targets)
        now: Mapping[str, float] | None = None
        for joint, half in self.half_play.items():
            if joint not in targets:
                continue
            target = float(targets[joint])
            last = self._target.get(joint)
            if last is None:
                now = positions() if now is None else now
                last = float(now[joint])
            if abs(target - last) > SAME_TARGET_DEG:
                self._approach[joint] = 1.0 if target > last else -1.0
            self._target[joint] = target
            low, high = self.limits[joint]
            goals[joint] = min(max(target + self._approach.get(joint, 0.0) * half, low), high)
        return goals

    def joints(self, positions: Mapping[str, float]) -> dict[str, float]:
        """Where the joints are, from the encoders' `positions`: each joint's reading less half
        its play in the direction it last came (a joint not moved yet: as read)."""
        return {joint: float(positions[joint]) - self._approach.get(joint, 0.0) * self.half_play.get(joint, 0.0)
                for joint in self.limits if joint in positions}
