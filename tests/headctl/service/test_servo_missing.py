"""A servo missing at start, or leaving the bus while the service runs, on the simulated
head: the service starts `degraded` naming it (joint, id, port), fixations and looks pause,
commands naming the joint fail with that reason while the other joints go on, and the
service is `running` again once the servo answers."""
from __future__ import annotations

import dataclasses

import pytest

from drivers.errors import ServoCommError
from drivers.servo.config import WiredServo
from headctl.config.head import HeadConfig
from headctl.service.control import SimFault
from headctl.service.daemon import Daemon
from headctl.service.looks import LookKind, LookRequest, LookState
from tests.conftest import sim_head_config, wait_until

pytestmark = pytest.mark.timeout(180)


def _with_servo_off_the_bus(config: HeadConfig, joint: str, **service: object) -> HeadConfig:
    """The simulated head wired as its joints say, `joint`'s servo off the bus at start."""
    bus = config.servo_bus
    wiring = {jc.servo_id: WiredServo(j, jc.direction, jc.zero_offset, off_bus=j == joint)
              for j, jc in bus.joints.items()}
    return dataclasses.replace(config, servo_bus=dataclasses.replace(bus, wiring=wiring),
                               service=dataclasses.replace(config.service, **service))


@pytest.mark.parametrize("servo_process", [True, False], ids=["servo process", "servo thread"])
def test_a_servo_missing_at_start_degrades_the_service_naming_it_and_is_picked_up(tmp_path, servo_process):
    config = _with_servo_off_the_bus(sim_head_config(tmp_path / "state"), "left_eye", servo_process=servo_process)
    daemon = Daemon(config).start()  # not an exit: the other joints go on
    try:
        control, port = daemon.control, config.servo_bus.port
        fault = wait_until(lambda: control.snapshot().faults.get("servo_missing:left_eye"), 10, "the missing servo")
        assert fault.startswith(f"servo missing: joint left_eye (id {config.servo_bus.joints['left_eye'].servo_id})")
        assert port in fault
        status = control.snapshot().as_dict()
        assert status["state"] == "degraded" and "left_eye" not in status["joints"] and status["pose"] is None
        wait_until(lambda: "servo missing: joint left_eye" in control.snapshot().as_dict()["fixation"]["state"],
                   10, "fixations paused naming the joint")
        look = control.look(LookRequest(LookKind.ANGLES, (3.0, -2.0, 6.0)))
        wait_until(lambda: look.state.finished, 10, "the look refused")
        assert look.state is LookState.FAILED and "servo missing: joint left_eye" in look.detail
        loop = daemon.parts.running.loop
        with pytest.raises(ServoCommError, match=r"servo missing: joint left_eye \(id 3\).*nothing sent"):
            loop.request_goals({"pan": 1.0, "left_eye": 1.0})
        assert loop.request_goals({"pan": 1.0}) == {"pan": 1.0}  # the other joints go on
        control.inject_fault(SimFault.SERVO_ADD, joint="left_eye")
        status = wait_until(lambda: (s := control.snapshot().as_dict())["state"] == "running" and s, 20,
                            "running again once it answers")
        assert "servo_missing:left_eye" not in status["faults"] and status["joints"]["left_eye"]["torque_on"]
        look = control.look(LookRequest(LookKind.ANGLES, (3.0, -2.0, 6.0)))
        wait_until(lambda: look.state.finished, 30, "a look once it is back")
        assert look.state is LookState.DONE, (look.outcome, look.detail)
    finally:
        daemon.stop()


def test_a_servo_that_leaves_the_bus_while_running_is_reported_and_picked_up(tmp_path):
    daemon = Daemon(sim_head_config(tmp_path / "state")).start()
    try:
        control = daemon.control
        control.inject_fault(SimFault.SERVO_REMOVE, joint="tilt")
        fault = wait_until(lambda: control.snapshot().faults.get("servo_missing:tilt"), 10, "the servo missing")
        assert "joint tilt (id 2)" in fault and control.snapshot().as_dict()["state"] == "degraded"
        control.inject_fault(SimFault.SERVO_ADD, joint="tilt")
        status = wait_until(lambda: (s := control.snapshot().as_dict())["state"] == "running" and s, 20,
                            "running again")
        assert status["joints"]["tilt"]["torque_on"]
        assert any("answers again" in event["message"] for event in status["events"])
    finally:
        daemon.stop()
