"""The servo loop in a process of its own (headctl.service.servo_io.process), on the simulated head."""
from __future__ import annotations

import dataclasses
import os
import signal
import subprocess
import sys
import multiprocessing
import textwrap

import numpy as np
import pytest

from drivers.errors import DriverError, JointLimitError, ServoHardwareError
from drivers.servo.bus import BusState
from drivers.sim.servo_mechanics import ServoMechanicsConfig
from headctl.config.head import load_config
from headctl.service.servo_io.process import ServoLoopProcess
from headctl.service.servo_io.shared import SIZE, SharedState
from tests.conftest import wait_until
from tests.support import ROOT, SIM_IDEAL

pytestmark = pytest.mark.timeout(120)


@pytest.fixture(scope="module")
def servo():
    """One servo process on the simulated head's servos for the module's tests."""
    changes: list[int] = []
    process = ServoLoopProcess(load_config(SIM_IDEAL), on_fault_change=lambda: changes.append(1)).start()
    process.changes = changes  # type: ignore[attr-defined]
    yield process
    process.stop()


def test_states_flow_and_goals_are_written_through_the_bus_limits(servo):
    state = servo.fresh_state()
    assert set(state.joints) == {"pan", "tilt", "left_eye", "right_eye"} and state.time_s > 0
    sent = servo.request_goals({"pan": 55.0, "tilt": 5.0})  # pan beyond its limit (40): the bus clamps it
    assert sent == {"pan": 40.0, "tilt": 5.0}
    assert servo.goals()["pan"] == 40.0
    wait_until(lambda: abs(servo.true_position("pan") - 40.0) < 0.05, 5.0, "pan at its limit")
    wait_until(lambda: abs(servo.fresh_state()["pan"].position - 40.0) < 0.05, 5.0, "the state read back")
    timing = servo.timing()
    assert timing["rate_hz"] == 100.0 and timing["cycles"] > 10 and timing["period_p50_ms"] == pytest.approx(10, abs=2)
    assert servo.is_alive() and servo.describe("tilt") == "joint tilt (id 2) on sim-servo-bus(sim:head)"


def test_errors_cross_the_process_boundary_with_their_kind(servo):
    with pytest.raises(JointLimitError, match="not a finite angle"):
        servo.request_goals({"pan": float("nan")})
    servo.inject_hardware_error("tilt", 0x01)  # input voltage: torque stays on, the joint is held
    wait_until(lambda: "tilt" in servo.faults, 5.0, "the fault reported by the child")
    assert servo.faults["tilt"] == ("input voltage out of range",) and servo.changes
    with pytest.raises(ServoHardwareError, match=r"joint tilt \(id 2\).*held after a hardware error"):
        servo.request_goals({"tilt": 3.0})
    wait_until(lambda: "tilt" not in servo.faults, 10.0, "rebooted by the bus's recovery policy after 1 s")
    assert servo.request_goals({"tilt": 3.0}) == {"tilt": 3.0}


def test_torque_off_and_on_again(servo):
    servo.set_torque(False)
    wait_until(lambda: not any(j.torque_on for j in servo.fresh_state().joints.values()), 5.0, "torque off")
    assert not servo.torque_enabled
    with pytest.raises(ServoHardwareError, match="torque off"):
        servo.request_goals({"pan": 0.0})
    servo.set_torque(True)
    assert servo.torque_enabled and all(j.torque_on for j in servo.fresh_state().joints.values())


def test_a_silent_service_gets_the_present_position_held():
    config = load_config(SIM_IDEAL)
    config = dataclasses.replace(config, service=dataclasses.replace(config.service, input_timeout_s=0.2))
    process = ServoLoopProcess(config).start()
    try:
        process.request_goals({"pan": -40.0})  # a long move (about 0.3 s), then silence
        wait_until(lambda: process.goals().get("pan", -40.0) != -40.0, 5.0, "the goal replaced by a hold")
        held = process.goals()["pan"]
        assert -40.0 < held < 0.0
        wait_until(lambda: not process.latest_state().moving, 5.0, "the head at rest")
        assert process.true_position("pan") == pytest.approx(held, abs=2.0)
    finally:
        process.stop()


def test_a_bus_that_cannot_open_is_the_buss_error_at_start(tmp_path):
    config = load_config(ROOT / "configs" / "xm430-u2d2-aravis.yaml")
    missing = dataclasses.replace(config.servo_bus, port=str(tmp_path / "no-such-port"))
    with pytest.raises(DriverError, match="no-such-port"):
        ServoLoopProcess(dataclasses.replace(config, servo_bus=missing)).start(timeout_s=60)


def test_the_child_stops_when_the_service_dies(tmp_path):
    """The service killed: its pipe closes, and the servo process leaves the servos in the safe
    state and exits by itself."""
    script = textwrap.dedent("""
        import os, sys
        from headctl.config.head import load_config
        from headctl.service.servo_io.process import ServoLoopProcess
        process = ServoLoopProcess(load_config()).start()
        print(process._process.pid, flush=True)
        sys.stdin.readline()
        os._exit(0)  # no stop(): as a kill would leave it
    """)
    parent = subprocess.Popen([sys.executable, "-c", script], cwd=ROOT, stdin=subprocess.PIPE,
                              stdout=subprocess.PIPE, text=True)
    try:
        child_pid = int(parent.stdout.readline())
        assert os.path.exists(f"/proc/{child_pid}")
        parent.stdin.write("\n")
        parent.stdin.flush()
        assert parent.wait(30) == 0

        def gone() -> bool:
            try:
                return open(f"/proc/{child_pid}/stat").read().split(") ")[1][0] == "Z"  # exited, not yet reaped
            except OSError:
                return True
        wait_until(gone, 10.0, "the orphaned servo process to exit")
    finally:
        parent.kill()


def _write_forever(raw, stop) -> None:
    block = SharedState(raw)
    values = np.zeros(SIZE)
    n = 0.0
    while not stop.is_set():
        n += 1.0
        values[:] = n
        block.write(values)


def test_the_shared_block_is_never_read_torn():
    """A writer in another process (as the servo process is), writing as fast as it can."""
    block = SharedState.create()
    context = multiprocessing.get_context("spawn")
    stop = context.Event()
    writer = context.Process(target=_write_forever, args=(block.raw, stop), daemon=True)
    writer.start()
    try:
        wait_until(lambda: block.values[1] > 0, 30.0, "the writer writing")
        reads: list[np.ndarray] = []

        def read_more() -> bool:  # until the writer has written 100 times meanwhile (it may run seldom)
            reads.extend(block.read()[1:] for _ in range(2000))
            return len({float(r[0]) for r in reads}) > 100

        wait_until(read_more, 60.0, "100 of the writer's writes read")
    finally:
        stop.set()
        writer.join(10)
    assert all(np.all(r == r[0]) for r in reads)  # every copy from one write


def test_a_killed_child_is_replaced_where_the_servos_are_with_torque_as_switched():
    from headctl.errors import ServoLoopStoppedError

    process = ServoLoopProcess(load_config(SIM_IDEAL)).start()
    try:
        process.request_goals({"pan": 20.0})
        wait_until(lambda: abs(process.fresh_state()["pan"].position - 20.0) < 0.1 and
                   not process.latest_state().moving, 10.0, "pan at 20 deg")
        process.set_torque(False)  # switched off through the API: stays off in the new child
        old_pid = process.pid
        os.kill(old_pid, signal.SIGKILL)
        wait_until(lambda: process.failure(), 5.0, "the death noticed")
        assert f"servo process {old_pid} exited (code -9)" in (process.failure() or "")
        with pytest.raises(ServoLoopStoppedError):  # nothing is queued for a child not running
            process.request_goals({"pan": 0.0})
        detail = process.restart()
        assert detail == {"old_pid": old_pid, "exit_code": -9, "new_pid": process.pid} and process.pid != old_pid
        assert process.failure() is None and process.is_alive() and process.restarts == 1
        state = process.fresh_state()
        assert state["pan"].position == pytest.approx(20.0, abs=0.1)  # the simulated servos did not jump
        assert not process.torque_enabled and not state["pan"].torque_on
        process.set_torque(True)  # goal := present, then torque on: still no jump
        wait_until(lambda: process.fresh_state()["pan"].torque_on, 5.0, "torque on")
        assert process.goals().get("pan", 20.0) == pytest.approx(20.0, abs=0.1)  # none written, or the hold
        assert process.fresh_state()["pan"].position == pytest.approx(20.0, abs=0.1)
    finally:
        process.stop()


PLAY_DEG, SAG_DEG = 0.5, 0.35
# Up, then back down: each output ends at the upper end of its play (the tilt's on its downhill
# flank, as a loaded joint always is).
UP = {"pan": 10.0, "tilt": 8.0, "left_eye": 10.0, "right_eye": 0.0}
DOWN = {"pan": 6.0, "tilt": 4.0, "left_eye": 6.0, "right_eye": -4.0}


def _geared_head():
    """The simulated head with play and the tilt's droop alone: readings exact, no dead band."""
    config = load_config(SIM_IDEAL)
    mechanics = ServoMechanicsConfig(backlash_deg=PLAY_DEG, sag_deg_at_horizontal=SAG_DEG)
    return dataclasses.replace(config, servo_bus=dataclasses.replace(config.servo_bus, mechanics=mechanics))


def _resting(process: ServoLoopProcess) -> dict[str, tuple[float, float]]:
    """Once the head rests: each joint's (true output, reading)."""
    def at_rest() -> BusState | None:
        state = process.fresh_state()
        return None if any(j.moving for j in state.joints.values()) else state

    state = wait_until(at_rest, 10.0, "the head at rest")
    return {joint: (process.true_position(joint), state[joint].position) for joint in state.joints}


def _lags(process: ServoLoopProcess, step_deg: float) -> dict[str, float]:
    """Each joint moved `step_deg` from where it reads: how far its output fell short."""
    start = _resting(process)
    process.request_goals({joint: reading + step_deg for joint, (_, reading) in start.items()})
    end = _resting(process)
    return {joint: step_deg - (end[joint][0] - start[joint][0]) for joint in start}


def _reverse_then_step(kill: bool) -> tuple[dict, dict, dict, dict]:
    """The head moved up and back, torque off (as a restart leaves it), the child killed and
    restarted if `kill`, torque on again, then a small step on down and one back up: the head at
    rest before and after, and each step's lags."""
    process = ServoLoopProcess(_geared_head()).start()
    try:
        for goals in (UP, DOWN):
            process.request_goals(goals)
            _resting(process)
        process.set_torque(False)
        before = _resting(process)
        if kill:
            os.kill(process.pid, signal.SIGKILL)
            wait_until(lambda: process.failure(), 5.0, "the death noticed")
            process.restart()
        after = _resting(process)
        process.set_torque(True)  # goal := present: the tilt sinks by its droop, with or without a restart
        return before, after, _lags(process, -0.2), _lags(process, 0.2)
    finally:
        process.stop()


def test_a_killed_child_leaves_the_simulated_servos_play_and_droop_as_they_were():
    before, after, on, back = _reverse_then_step(kill=True)
    for joint in before:
        assert after[joint] == pytest.approx(before[joint], abs=1e-6)  # the output and the shaft not moved
    for joint in ("pan", "left_eye", "right_eye"):
        assert before[joint][0] - before[joint][1] == pytest.approx(PLAY_DEG / 2)  # at the upper end of the play
        assert on[joint] == pytest.approx(0.0, abs=1e-6)  # on down: the shaft pushes the output at once
        assert back[joint] == pytest.approx(0.2, abs=1e-6)  # back up by less than the play: the output stays
    _, _, unbroken_on, unbroken_back = _reverse_then_step(kill=False)
    assert on == pytest.approx(unbroken_on, abs=1e-6) and back == pytest.approx(unbroken_back, abs=1e-6)
