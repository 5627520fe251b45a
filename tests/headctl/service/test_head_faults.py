"""Faults a real head meets, on the simulated head while the service runs:

- a brown-out (its servo loop in a process of its own): every servo silent, then back with RAM
  defaults and an Input Voltage error; reported as a fault while it lasts, healed without a
  person (settings again, goals := present, torque);
- the wall clock stepped (NTP, a person setting the date): control timing is on the monotonic
  clock, so nothing stalls and nothing fires early; only the times shown to people (events,
  looks, checkpoints) follow the wall clock.
"""
from __future__ import annotations

import dataclasses
import threading
import time

import numpy as np
import pytest

from calib_free.map.adapter import Sample
from calib_free.map.file import write_map
from headctl.service.control import SimFault
from headctl.service.daemon import Daemon
from headctl.service.looks import LookKind, LookRequest, LookState
from tests.conftest import sim_head_config, wait_until

pytestmark = pytest.mark.timeout(180)


def test_a_brown_out_is_reported_while_it_lasts_and_healed_without_a_person(tmp_path):
    daemon = Daemon(sim_head_config(tmp_path / "state")).start()
    try:
        control = daemon.control
        assert control.inject_fault(SimFault.POWER_LOSS) == "power_loss"
        fault = wait_until(lambda: control.snapshot().faults.get("servo_reads"), 10, "the failing reads reported")
        assert "no servo answered (the servos have no power)" in fault
        assert control.snapshot().as_dict()["state"] == "degraded"
        control.inject_fault(SimFault.POWER_BACK, bits=0x01)  # back with an Input Voltage error
        status = wait_until(lambda: (s := control.snapshot().as_dict())["state"] == "running"
                            and s["servo_loop"]["power_losses"] == 1 and s, 20, "running again")
        assert all(joint["torque_on"] and not joint["hardware_errors"] for joint in status["joints"].values())
        assert any("lost power and came back" in event["message"] and "torque restored" in event["message"]
                   for event in status["events"])
        look = control.look(LookRequest(LookKind.ANGLES, (3.0, -2.0, 6.0)))
        wait_until(lambda: look.state.finished, 30, "a look after the brown-out")
        assert look.state is LookState.DONE, (look.outcome, look.detail)
        assert control.snapshot().as_dict()["servo_loop"]["power_losses"] == 1
    finally:
        daemon.stop()


# The wall clock's offset from the real one, in hours, changing every third of a second:
# forward by hours, back by more than it went forward, and so on.
STEPS_H = (0.0, 3.0, -5.0, 11.0, -26.0, 0.5)
INTERVAL_S = 1.0
RUN_S = 6.0


def test_stepping_the_wall_clock_forward_and_back_stalls_nothing_and_fires_nothing_early(tmp_path, monkeypatch):
    config = sim_head_config(tmp_path / "state")
    # The servo loop as a thread, so that the stepped clock reaches it too; checkpoints on time only.
    config = dataclasses.replace(config, service=dataclasses.replace(
        config.service, servo_process=False, checkpoint_every=1_000_000, checkpoint_interval_s=INTERVAL_S))
    daemon = Daemon(config).start()
    try:
        running = daemon.parts.running
        cp, loop, adapter = running.checkpointer, running.loop, running.adapter
        saved_at: list[float] = []
        lock = threading.Lock()

        def recording_writer(gm, path):  # when each save starts: the interval counts from there
            with lock:
                saved_at.append(time.monotonic())
            write_map(gm, path)

        cp.writer = recording_writer
        real_time = time.time
        monkeypatch.setattr(time, "time",
                            lambda: real_time() + 3600.0 * STEPS_H[int(time.monotonic() * 3) % len(STEPS_H)])
        cycles_before, started = loop.timing()["cycles"], time.monotonic()
        look = daemon.control.look(LookRequest(LookKind.ANGLES, (4.0, -3.0, 6.0)))
        i = 0
        while time.monotonic() - started < RUN_S:  # the map keeps changing: a checkpoint is due every interval
            adapter.submit(Sample(np.array([100.0 + i % 50, 120.0, -5.0]), np.array([0.1, 0.05, -0.05]), 1.0))
            i += 1
            time.sleep(0.05)
        elapsed = time.monotonic() - started
        cycles = loop.timing()["cycles"] - cycles_before
        assert cycles >= 0.8 * elapsed * config.service.servo_rate_hz, (cycles, elapsed)  # the loop kept its rate
        assert loop.timing()["period_p50_ms"] == pytest.approx(1e3 / config.service.servo_rate_hz, abs=2.0)
        with lock:
            gaps = np.diff(saved_at)
        assert len(saved_at) >= RUN_S / INTERVAL_S - 2, saved_at  # checkpoints kept coming ...
        assert gaps.min() >= INTERVAL_S - 0.01 and gaps.max() <= INTERVAL_S + 0.6, gaps  # ... on their interval
        wait_until(lambda: look.state.finished, 30, "the look to finish")
        assert look.state is LookState.DONE, (look.outcome, look.detail)
        assert look.finished_s is not None and look.started_s is not None  # wall-clock stamps, for people
        assert not daemon.control.snapshot().faults
    finally:
        daemon.stop()
