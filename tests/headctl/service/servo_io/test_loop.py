"""The servo loop (headctl.service.servo_io.loop) in-process, and the head interrupted over it."""
from __future__ import annotations

import dataclasses
import threading

import numpy as np
import pytest

from calib_free.gaze.fixation import FixationInterrupted, FixationOutcome
from drivers.clock import ManualClock
from drivers.errors import BusDownError, ServoHardwareError
from drivers.servo.bus import JOINTS
from drivers.servo.config import ServoBusConfig
from drivers.sim.servos import SimulatedServoBus
from headctl.service.head import Head
from headctl.service.fixation_thread import Interrupt
from headctl.service.looks import LookKind, LookQueue, LookRequest
from headctl.service.servo_io.loop import ServoLoop
from tests.conftest import wait_until

BUS_CONFIG = {"backend": "sim", "port": "sim:test",
              "joints": {j: {"id": i, "min_angle": -20, "max_angle": 20, "profile_velocity": 200,
                             "profile_acceleration": 2000} for i, j in enumerate(JOINTS, 1)}}


@pytest.fixture
def sim_bus():
    bus = SimulatedServoBus(ServoBusConfig.from_mapping(BUS_CONFIG))
    bus.open()
    bus.enable()
    yield bus
    bus.close()


class NoPairs:
    last_exposure_s = None

    def wait_pair(self, after_s, timeout_s):
        raise AssertionError("no pair is needed here")


def head_over(loop, interrupt):
    """The head the fixation thread uses: the servo loop as its bus, interrupted by `interrupt`."""
    return Head(loop, NoPairs(), loop.bus.config.joints, interrupt=interrupt, goals_in_force=loop.goals)


@pytest.fixture
def loop(sim_bus):
    loop = ServoLoop(sim_bus, rate_hz=100.0, input_timeout_s=0.3)
    loop.start()
    yield loop
    loop.stop()


def test_the_loop_runs_at_its_rate_and_writes_goals_through_the_bus_limits(loop, sim_bus):
    wait_until(lambda: loop.cycles >= 20, what="20 cycles")
    timing = loop.timing()
    assert 9.0 < timing["period_p50_ms"] < 11.0
    bus = loop  # what the head sees as its bus
    sent = bus.write_goals({"pan": 50.0, "tilt": 5.0})  # pan beyond its limit: the bus clamps it
    assert sent == {"pan": 20.0, "tilt": 5.0}
    wait_until(lambda: abs(sim_bus.true_position("pan") - 20.0) < 0.01, what="pan at its limit")
    state = bus.read_state()
    assert abs(state["tilt"].position - 5.0) < 0.01 and state.time_s >= 0


def test_stale_input_holds_the_present_position_on_a_manual_clock():
    clock = ManualClock()
    sim_bus = SimulatedServoBus(ServoBusConfig.from_mapping(BUS_CONFIG), clock=clock)
    with sim_bus:
        sim_bus.enable()
        loop = ServoLoop(sim_bus, rate_hz=100.0, input_timeout_s=0.05, clock=clock)  # stepped here, no thread

        def step(seconds):
            loop.step()
            clock.advance(seconds)

        writer = threading.Thread(target=loop.request_goals, args=({"pan": -20.0},))  # a 0.15 s move
        writer.start()
        while writer.is_alive():  # the writer waits for the next cycle
            step(0.0)
            writer.join(0.001)
        assert loop.goals()["pan"] == -20.0
        for _ in range(8):  # then silence from the controller, 80 ms
            step(0.01)
        held = loop.goals()["pan"]
        assert held > -19.0  # the goal is now where the joint was when the input went stale
        for _ in range(100):
            step(0.01)
        assert not sim_bus.read_state()["pan"].moving
        assert abs(sim_bus.true_position("pan") - held) < 2.0 and sim_bus.true_position("pan") > -19.0


def test_bus_down_pauses_motion_and_the_loop_resumes_after_reopening(loop, sim_bus):
    bus = loop
    sim_bus.inject_bus_down()
    wait_until(lambda: loop.down_reason, what="bus down noticed")
    with pytest.raises(BusDownError):
        bus.write_goals({"pan": 3.0})
    sim_bus.restore_bus()
    wait_until(lambda: loop.down_reason is None, timeout_s=3.0, what="bus back")
    assert bus.write_goals({"pan": 3.0}) == {"pan": 3.0}
    wait_until(lambda: abs(sim_bus.true_position("pan") - 3.0) < 0.01, what="motion resumed")


def test_a_servo_hardware_error_holds_the_joint_until_a_reboot_clears_it(sim_bus):
    # The bus's recovery policy reboots an error that leaves torque on once it lasted persist_s.
    sim_bus.recovery.limits = dataclasses.replace(sim_bus.recovery.limits, persist_s=0.3)
    loop = ServoLoop(sim_bus, rate_hz=100.0)
    loop.start()
    try:
        bus = loop
        sim_bus.inject_hardware_error("tilt", 0x01)  # input voltage: the torque stays on
        wait_until(lambda: "tilt" in loop.faults, what="fault seen")
        assert loop.faults["tilt"] == ("input voltage out of range",)
        before = sim_bus.true_position("tilt")
        with pytest.raises(ServoHardwareError, match=r"joint tilt \(id 2\) .* held after a hardware error"):
            bus.write_goals({"pan": 2.0, "tilt": 5.0})
        assert bus.write_goals({"pan": 2.0}) == {"pan": 2.0}  # the other joints still move
        wait_until(lambda: abs(sim_bus.true_position("pan") - 2.0) < 0.01, what="pan moved")
        assert abs(sim_bus.true_position("tilt") - before) < 0.01
        # reboot_on_hardware_error: the bus reboots the servo, the error clears, the joint is free.
        wait_until(lambda: "tilt" not in loop.faults, timeout_s=3.0, what="tilt rebooted")
        assert bus.write_goals({"tilt": 5.0}) == {"tilt": 5.0}
        wait_until(lambda: abs(sim_bus.true_position("tilt") - 5.0) < 0.01, what="tilt moved")
    finally:
        loop.stop()


def test_a_stopping_service_aborts_the_fixation_in_progress(loop):
    abort = threading.Event()
    head = head_over(loop, Interrupt(abort))
    head.read_pose()
    abort.set()
    for action in (head.read_pose, lambda: head.move_to(np.zeros(3)), lambda: head.wait_settled(1.0)):
        with pytest.raises(FixationInterrupted) as err:
            action()
        assert err.value.outcome is FixationOutcome.SHUTDOWN


def test_cancelling_a_look_interrupts_only_that_look(loop):
    interrupt = Interrupt(threading.Event())
    head = head_over(loop, interrupt)
    looks = LookQueue()
    first = looks.submit(LookRequest(LookKind.ANGLES, (1.0, 0.0, 6.0)))
    second = looks.submit(LookRequest(LookKind.ANGLES, (2.0, 0.0, 6.0)))
    job = looks.take()
    assert job is first
    with interrupt.during(job):
        head.read_pose()  # not cancelled: the bus answers
        assert looks.cancel(job.id) is job and job.state == "running" and not job.done.is_set()
        with pytest.raises(FixationInterrupted, match=f"look {job.id} stopped: cancelled by a client") as err:
            head.move_to(np.array([1.0, 0.0, 6.0]))
        assert err.value.outcome is FixationOutcome.CANCELLED
    head.read_pose()  # outside the look the cancellation no longer applies
    with interrupt.during(looks.take()):
        head.move_to(np.array([2.0, 0.0, 6.0]))  # the next look runs
    assert second.state == "running"


def test_bus_errors_end_a_fixation_with_one_outcome(loop, sim_bus):
    head = head_over(loop, Interrupt(threading.Event()))
    sim_bus.inject_bus_down()
    with pytest.raises(FixationInterrupted) as err:
        head.move_to(np.zeros(3))
    assert err.value.outcome is FixationOutcome.BUS_DOWN


