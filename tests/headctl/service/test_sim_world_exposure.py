"""The simulated world tells where the joints were at a frame's exposure: in this process
(the simulated bus's trace) and across the servo process's shared memory."""
from __future__ import annotations

import pytest

from drivers.clock import ManualClock
from drivers.errors import CameraError
from drivers.sim.camera import TimedPoseSource
from headctl.config.head import load_config
from headctl.service.build import HeadDevices
from headctl.service.servo_io.process import ServoLoopProcess
from tests.support import SIM_IDEAL
from tests.conftest import wait_until

pytestmark = pytest.mark.timeout(60)


def test_the_worlds_pose_sources_give_the_joints_at_a_past_time_and_fail_when_stalled():
    clock = ManualClock()
    devices = HeadDevices.build(load_config(SIM_IDEAL), clock)
    assert devices.world is not None and devices.bus is not None
    with devices:
        devices.bus.enable()
        devices.bus.write_goals({"pan": 20.0})
        for _ in range(5):
            clock.advance(0.01)
            devices.bus.read_state()  # as the servo loop does
        midway = devices.world.true_joints()["pan"]
        for _ in range(100):
            clock.advance(0.01)
            devices.bus.read_state()
        left = devices.world.pose_source("left")
        assert isinstance(left, TimedPoseSource)
        assert left()["pan"] == pytest.approx(20.0)
        assert left.at(0.05)["pan"] == pytest.approx(midway, abs=0.03) and 0.5 < midway < 19.0
        devices.world.stalled.add("left")
        with pytest.raises(CameraError, match="camera left: stalled"):
            left.at(0.05)
        assert devices.world.pose_source("right").at(0.05)["pan"] == pytest.approx(midway, abs=0.03)


def test_the_servo_process_publishes_where_the_joints_were():
    servo = ServoLoopProcess(load_config(SIM_IDEAL)).start()
    try:
        before = servo.fresh_state()
        servo.request_goals({"pan": 30.0})
        states = []
        wait_until(lambda: states.append(servo.fresh_state()) or not states[-1]["pan"].moving, 5.0,
                   "the pan move over")
        moving = [state for state in states if 0.5 < state["pan"].position < 29.5]
        assert len(moving) >= 3
        # Asked after the move, the trace has the joint where the states read during it had it.
        # A state's time is the middle of its read, which a descheduled child can move by a
        # millisecond or two (0.5 deg at this speed); a trace a cycle off would be 2.4 deg off.
        for state in moving:
            assert servo.true_joints_at(state.time_s)["pan"] == pytest.approx(state["pan"].position, abs=0.5)
        assert servo.true_joints_at(before.time_s)["pan"] == pytest.approx(before["pan"].position, abs=1e-9)
        assert states[-1]["pan"].position == 30.0
        assert servo.true_joints_at(states[-1].time_s + 0.02)["pan"] == pytest.approx(30.0, abs=1e-9)
    finally:
        servo.stop()
