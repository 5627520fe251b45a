"""The daemon's parts in-process: the servo loop, map restore and checkpoints, sd_notify, the state-directory lock."""
from __future__ import annotations

import os
import socket
import subprocess
import sys
import threading
import time

import numpy as np
import pytest

from calib_free import GazeMap
from calib_free.adapter import MapAdapter, Sample
from drivers.errors import BusDownError, ServoHardwareError
from drivers.servo_bus import JOINTS, ServoBusConfig
from drivers.sim_servo import SimulatedServoBus
from headctl.config import load_config
from headctl.control import LookQueue, LookRequest
from headctl.daemon import (Checkpointer, Interrupt, LookCancelledError, LoopBus, ServoLoop, ShutdownError,
                            StateDirLock, SystemdNotifier, restore_map)
from headctl.errors import HeadctlError


def wait_until(predicate, timeout_s=5.0, what="condition"):
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        value = predicate()
        if value:
            return value
        time.sleep(0.005)
    raise AssertionError(f"timed out after {timeout_s} s waiting for {what}")


@pytest.fixture
def sim_bus():
    config = ServoBusConfig.from_mapping({
        "backend": "sim", "port": "sim:test",
        "joints": {j: {"id": i, "min_angle": -20, "max_angle": 20, "profile_velocity": 200,
                       "profile_acceleration": 2000} for i, j in enumerate(JOINTS, 1)}})
    bus = SimulatedServoBus(config)
    bus.open()
    bus.enable()
    yield bus
    bus.close()


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
    bus = LoopBus(loop, Interrupt(threading.Event()))
    sent = bus.write_goals({"pan": 50.0, "tilt": 5.0})  # pan beyond its limit: the bus clamps it
    assert sent == {"pan": 20.0, "tilt": 5.0}
    wait_until(lambda: abs(sim_bus.true_position("pan") - 20.0) < 0.01, what="pan at its limit")
    state = bus.read_state()
    assert abs(state["tilt"].position - 5.0) < 0.01 and state.time_s >= 0


def test_stale_input_holds_the_present_position(sim_bus):
    loop = ServoLoop(sim_bus, rate_hz=100.0, input_timeout_s=0.05)
    loop.start()
    try:
        bus = LoopBus(loop, Interrupt(threading.Event()))
        bus.write_goals({"pan": -20.0})  # a 0.15 s move, then silence from the controller
        wait_until(lambda: abs(loop.goals()["pan"] - (-20.0)) > 0.5, timeout_s=2.0, what="goal replaced by a hold")
        held = loop.goals()["pan"]
        wait_until(lambda: not sim_bus.read_state()["pan"].moving, timeout_s=2.0, what="pan stopped")
        assert abs(sim_bus.true_position("pan") - held) < 2.0
        assert sim_bus.true_position("pan") > -19.0  # stopped short of the stale goal
    finally:
        loop.stop()


def test_bus_down_pauses_motion_and_the_loop_resumes_after_reopening(loop, sim_bus):
    bus = LoopBus(loop, Interrupt(threading.Event()))
    sim_bus.inject_bus_down()
    wait_until(lambda: loop.down_reason, what="bus down noticed")
    with pytest.raises(BusDownError):
        bus.write_goals({"pan": 3.0})
    sim_bus.restore_bus()
    wait_until(lambda: loop.down_reason is None, timeout_s=3.0, what="bus back")
    assert bus.write_goals({"pan": 3.0}) == {"pan": 3.0}
    wait_until(lambda: abs(sim_bus.true_position("pan") - 3.0) < 0.01, what="motion resumed")


def test_a_servo_hardware_error_holds_the_joint_until_a_reboot_clears_it(sim_bus):
    loop = ServoLoop(sim_bus, rate_hz=100.0)
    loop.REBOOT_AFTER_S = 0.3
    loop.start()
    try:
        bus = LoopBus(loop, Interrupt(threading.Event()))
        sim_bus.inject_hardware_error("tilt", 0x01)  # input voltage: the torque stays on
        wait_until(lambda: "tilt" in loop.faults, what="fault seen")
        assert loop.faults["tilt"] == ("input voltage out of range",)
        before = sim_bus.true_position("tilt")
        with pytest.raises(ServoHardwareError, match=r"joint tilt \(id 2\) .* held after a hardware error"):
            bus.write_goals({"pan": 2.0, "tilt": 5.0})
        assert bus.write_goals({"pan": 2.0}) == {"pan": 2.0}  # the other joints still move
        wait_until(lambda: abs(sim_bus.true_position("pan") - 2.0) < 0.01, what="pan moved")
        assert abs(sim_bus.true_position("tilt") - before) < 0.01
        # reboot_on_hardware_error: the loop reboots the servo, the error clears, the joint is free.
        wait_until(lambda: "tilt" not in loop.faults, timeout_s=3.0, what="tilt rebooted")
        assert bus.write_goals({"tilt": 5.0}) == {"tilt": 5.0}
        wait_until(lambda: abs(sim_bus.true_position("tilt") - 5.0) < 0.01, what="tilt moved")
    finally:
        loop.stop()


def test_a_stopping_daemon_aborts_the_fixation_in_progress(loop):
    abort = threading.Event()
    bus = LoopBus(loop, Interrupt(abort))
    abort.set()
    with pytest.raises(ShutdownError):
        bus.read_state()
    with pytest.raises(ShutdownError):
        bus.write_goals({"pan": 1.0})


def test_cancelling_a_look_interrupts_only_that_look(loop):
    interrupt = Interrupt(threading.Event())
    bus = LoopBus(loop, interrupt)
    looks = LookQueue()
    first = looks.submit(LookRequest("angles", (1.0, 0.0, 6.0)))
    second = looks.submit(LookRequest("angles", (2.0, 0.0, 6.0)))
    job = looks.take()
    assert job is first
    with interrupt.during(job):
        bus.read_state()  # not cancelled: the bus answers
        assert looks.cancel(job.id) is job and job.state == "running" and not job.done.is_set()
        with pytest.raises(LookCancelledError, match=f"look {job.id} stopped: cancelled by a client"):
            bus.write_goals({"pan": 1.0})
    bus.read_state()  # outside the look the cancellation no longer applies
    with interrupt.during(looks.take()):
        bus.write_goals({"pan": 2.0})  # the next look runs
    assert second.state == "running"


# --- persistence --------------------------------------------------------------------------
def _config(tmp_path):
    return load_config().with_state_dir(tmp_path)


def test_restore_starts_fresh_then_loads_what_was_saved(tmp_path):
    config = _config(tmp_path)
    gm, source, problems = restore_map(config)
    assert source == "new" and not problems
    gm.adapt((160, 120, -10), (1.0, 2.0, -1.0))
    gm.save(config.map_path)
    again, source, problems = restore_map(config)
    assert source == str(config.map_path) and again.adaptations == 1 and not problems
    assert np.allclose(again.command((100, 100, 0)), gm.command((100, 100, 0)))


def test_a_corrupt_map_is_reported_moved_aside_and_the_previous_one_used(tmp_path):
    config = _config(tmp_path)
    gm, _, _ = restore_map(config)
    gm.save(config.map_path)
    gm.adapt((160, 120, -10), (1.0, 2.0, -1.0))
    gm.save(config.map_path)  # the first save is now .prev
    config.map_path.write_bytes(b"not a map")
    restored, source, problems = restore_map(config)
    assert source == f"{config.map_path}.prev" and restored.adaptations == 0
    assert len(problems) == 1 and "not a readable gaze map file" in problems[0]
    assert (tmp_path / "gaze_map.npz.bad").read_bytes() == b"not a map"
    assert GazeMap.load(config.map_path).adaptations == 0  # a good main file again


def test_a_map_for_other_parameters_is_refused(tmp_path):
    config = _config(tmp_path)
    GazeMap.for_image(640, 480).save(config.map_path)
    gm, source, problems = restore_map(config)
    assert source == "new" and "saved for other map parameters" in problems[0]


def test_checkpoints_every_n_adaptations_are_loadable(tmp_path):
    config = _config(tmp_path)
    gm, _, _ = restore_map(config)
    done = []
    with MapAdapter(gm) as adapter:
        cp = Checkpointer(adapter, config.map_path, every=2)
        adapter.on_adapted = lambda s, r: (done.append(r), cp.maybe(adapter.map.adaptations))
        for i in range(5):
            adapter.submit(Sample(np.array([100.0 + i, 120.0, -5.0]), np.array([1.0, 0.5, -0.5]), 1.0))
        assert adapter.wait_idle(10)
    assert cp.count == 2 and cp.last_adaptations == 4
    assert GazeMap.load(config.map_path).adaptations == 4
    assert GazeMap.load(f"{config.map_path}.prev").adaptations == 2


# --- systemd, the state-directory lock -------------------------------------------------------------------
def test_sd_notify_datagrams_reach_the_notify_socket(tmp_path):
    path = str(tmp_path / "notify")
    with socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM) as server:
        server.bind(path)
        notifier = SystemdNotifier({"NOTIFY_SOCKET": path, "WATCHDOG_USEC": "3000000",
                                    "WATCHDOG_PID": str(os.getpid())})
        assert notifier.enabled and notifier.watchdog_s == 3.0
        notifier.notify(ready=1, status="running: 0 fixations")
        assert server.recv(4096) == b"READY=1\nSTATUS=running: 0 fixations"
        notifier.close()
        notifier.close()
    assert not SystemdNotifier({}).enabled
    assert SystemdNotifier({"WATCHDOG_USEC": "100", "WATCHDOG_PID": "1"}).watchdog_s is None  # not ours


def test_one_daemon_per_state_directory_and_the_lock_dies_with_its_holder(tmp_path):
    path = tmp_path / "headctl.lock"
    with StateDirLock(path):
        with pytest.raises(HeadctlError, match=f"another headctl daemon \\(pid {os.getpid()}\\)"):
            StateDirLock(path).__enter__()
    with StateDirLock(path) as lock:  # released: free again
        lock.close()
        lock.close()  # idempotent
    # A holder killed with -9 leaves the file but not the lock.
    holder = subprocess.Popen([sys.executable, "-c", "import fcntl, os, sys, time; fd = os.open(sys.argv[1], "
                               "os.O_RDWR | os.O_CREAT); fcntl.flock(fd, fcntl.LOCK_EX); print('held', flush=True); "
                               "time.sleep(60)", str(path)], stdout=subprocess.PIPE, text=True)
    assert holder.stdout.readline().strip() == "held"
    with pytest.raises(HeadctlError, match="another headctl daemon"):
        StateDirLock(path).__enter__()
    holder.kill()
    holder.wait(5)
    with StateDirLock(path):
        assert path.read_text().strip() == str(os.getpid())
