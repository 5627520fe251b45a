"""A target the map sends beyond the pan or tilt limits is refused before the head moves."""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from calib_free.errors import OutOfRangeError
from headctl.errors import InvalidRequestError
from headctl.service.control import ServiceControl

LOW, HIGH = np.array([-40.0, -25.0, -3.0]), np.array([40.0, 25.0, 20.0])


class FixedMap:
    """A map whose every command is `command` (relative pan, tilt, vergence), or none at all."""

    def __init__(self, command: tuple[float, float, float] | None) -> None:
        self._command = command

    def command(self, position, pose=None) -> np.ndarray:
        if self._command is None:
            raise OutOfRangeError("d=99 is outside the disparity range")
        return np.array(self._command)


def running(command: tuple[float, float, float] | None) -> SimpleNamespace:
    return SimpleNamespace(head=SimpleNamespace(pose_low=LOW, pose_high=HIGH), adapter=FixedMap(command))


def test_a_target_the_map_sends_beyond_the_pan_limit_is_refused_naming_it():
    with pytest.raises(InvalidRequestError) as err:
        ServiceControl._check_reach(running((12.0, 1.0, 0.0)), (300.0, 120.0, 4.0), np.array([33.0, 0.0, 6.0]))
    assert err.value.field == "x"
    assert "pan 45.0 outside [-40, 40] deg" in str(err.value) and "(300, 120)" in str(err.value)
    assert "tilt" not in str(err.value)
    # Turning the head first would not help: the pose that fixates a point is one pose.
    assert "turn the robot" in str(err.value) and "angles look" not in str(err.value)


def test_a_tilt_beyond_its_limit_from_below_is_refused_too():
    with pytest.raises(InvalidRequestError, match=r"tilt -27\.5 outside \[-25, 25\] deg"):
        ServiceControl._check_reach(running((0.0, -7.5, 0.0)), (160.0, 230.0, 0.0), np.array([0.0, -20.0, 6.0]))


def test_a_target_within_the_margin_or_outside_the_map_is_left_to_the_look():
    # At the limit to within less than a servo's tick: the head gets there, the look is tried.
    ServiceControl._check_reach(running((7.03, 0.0, 0.0)), (300.0, 120.0, 4.0), np.array([33.0, 0.0, 6.0]))
    ServiceControl._check_reach(running((0.0, -4.97, 0.0)), (160.0, 230.0, 0.0), np.array([0.0, -20.0, 6.0]))
    ServiceControl._check_reach(running(None), (300.0, 120.0, 99.0), np.array([33.0, 0.0, 6.0]))


def test_a_goal_a_fraction_of_a_degree_beyond_is_refused():
    # The benchmark's looks sent 0.13 deg beyond the pan limit ended 8.8 px off the fovea.
    with pytest.raises(InvalidRequestError, match=r"pan -40\.1 outside \[-40, 40\] deg"):
        ServiceControl._check_reach(running((-7.13, 0.0, 0.0)), (20.0, 120.0, 0.0), np.array([-33.0, 0.0, 6.0]))
