"""The re-adaptation experiments' perturbations: wrappers of the head's bus and pairs."""
from __future__ import annotations

import dataclasses
from typing import Mapping

import numpy as np
import pytest

from calib_free.sim.experiments import Change
from drivers.clock import ManualClock
from drivers.servo.bus import BusState, JointState
from headctl.experiments.online import sim_config
from headctl.experiments.perturbations import PanReadingOffset, TransformedPairs, perturb
from headctl.service.head import Head


class StillBus:
    """A bus whose servos are at their goals at once and never move."""

    def __init__(self, clock: ManualClock) -> None:
        self.clock = clock
        self.positions = {"pan": 1.0, "tilt": 2.0, "left_eye": 3.0, "right_eye": -3.0}
        self.written: list[dict[str, float]] = []

    def read_state(self) -> BusState:
        return BusState(self.clock.monotonic(), {j: JointState(p, 0.0, False, True, 0, 35.0, 12.0)
                                                 for j, p in self.positions.items()})

    def write_goals(self, goals: Mapping[str, float]) -> dict[str, float]:
        self.written.append(dict(goals))
        self.positions.update(goals)
        return dict(goals)


class CountingPairs:
    last_exposure_s = 4.5

    def wait_pair(self, after_s: float, timeout_s: float) -> tuple[np.ndarray, np.ndarray]:
        return np.arange(6).reshape(3, 2), np.arange(6, 12).reshape(3, 2)


def test_the_pan_reading_is_offset_and_goals_are_written_as_given():
    bus = StillBus(ManualClock())
    offset = PanReadingOffset(bus, 10.0)
    assert offset.read_state().positions == {**bus.positions, "pan": 11.0}
    assert offset.write_goals({"pan": 5.0, "tilt": 1.0}) == {"pan": 15.0, "tilt": 1.0}  # as it will read them
    assert bus.written == [{"pan": 5.0, "tilt": 1.0}]
    assert offset.write_goals({"left_eye": 2.0}) == {"left_eye": 2.0}


def test_pairs_are_transformed_and_their_exposure_passed_on():
    pairs = TransformedPairs(CountingPairs(), np.flipud)
    left, right = pairs.wait_pair(0.0, 1.0)
    np.testing.assert_array_equal(left, np.flipud(np.arange(6).reshape(3, 2)))
    np.testing.assert_array_equal(right, np.flipud(np.arange(6, 12).reshape(3, 2)))
    assert pairs.last_exposure_s == 4.5


def test_perturb_wraps_the_heads_parts_and_the_head_settles_on_the_wrapped_bus():
    clock = ManualClock()
    bus, pairs = StillBus(clock), CountingPairs()
    joints = {name: dataclasses.replace(joint, backlash_deg=0.0)  # goals as asked: no play to take up
              for name, joint in sim_config().servo_bus.joints.items()}
    head = Head(bus, pairs, joints, clock=clock)
    head.move_to(np.array([1.0, 2.0, 6.0]))
    head.wait_settled(1.0)
    perturb(head, Change(10, vertical_prism=True))
    assert isinstance(head.pairs, TransformedPairs) and head.bus is bus
    perturb(head, Change(10, motor_offset_deg=(10.0, 0.0, 0.0)))
    assert isinstance(head.bus, PanReadingOffset)
    head.wait_settled(1.0)  # the goal written before the offset is not waited for on the offset readings
    assert head.read_pose()[0] == pytest.approx(11.0)
    head.move_to(head.read_pose() + np.array([5.0, 0.0, 0.0]))
    head.wait_settled(1.0)
    assert bus.positions["pan"] == pytest.approx(16.0)  # 5 commanded from the reading, 15 done
    with pytest.raises(ValueError, match="do not model"):
        perturb(head, Change(10, swap_eyes=True))
