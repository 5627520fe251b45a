"""A degraded service uses a few percent of a core at most: the service on the simulated head,
its servo process killed or its servo bus down, measured with the process's own CPU time
(per thread from /proc, so that the simulation's rendering can be told from the service).

The simulated cameras render a fish-eye view of the room for every frame whether the head is
degraded or not (about 15 % of a core each here); a real camera's capture costs next to
nothing. So the service's own cost is measured with the cameras stalled (a simulated fault:
no rendering), and, with them rendering, as the CPU of every thread but the cameras'.
"""
from __future__ import annotations

import dataclasses
import os
import signal
import threading
import time

import pytest

from headctl.service.control import SimFault
from headctl.service.daemon import Daemon
from headctl.service.parts import ServicePhase
from tests.conftest import sim_head_config, wait_until

pytestmark = pytest.mark.slow

MEASURE_S = 3.0
CORE_SHARE_MAX = 0.05
CAMERA_THREADS = ("camera-left", "camera-right")
TICK_S = 1.0 / os.sysconf("SC_CLK_TCK")


def thread_cpu_s() -> dict[str, float]:
    """CPU seconds of each of this process's threads, by thread name (native threads: [tid])."""
    names = {t.native_id: t.name for t in threading.enumerate()}
    out: dict[str, float] = {}
    for tid in os.listdir("/proc/self/task"):
        try:
            with open(f"/proc/self/task/{tid}/stat") as stat:
                fields = stat.read().rsplit(")", 1)[1].split()
        except OSError:  # ended meanwhile
            continue
        out[names.get(int(tid), f"[{tid}]")] = (int(fields[11]) + int(fields[12])) * TICK_S
    return out


def slow_to_restart(tmp_path):
    """The simulated head whose dead parts are restarted only after a minute: the service stays
    degraded while it is measured (restarts have their own tests)."""
    config = sim_head_config(tmp_path / "state")
    return dataclasses.replace(config, service=dataclasses.replace(
        config.service, restart_backoff_s=60.0, restart_backoff_max_s=60.0))


def degrade(daemon: Daemon, how: str) -> str:
    """Make the service degraded; the fault's key."""
    if how == "servo process killed":
        os.kill(daemon.control.snapshot().servo_loop["pid"], signal.SIGKILL)
        return "servo_loop"
    daemon.control.inject_fault(SimFault.BUS_DOWN)
    return "servo_bus"


def measure(daemon: Daemon) -> tuple[float, dict[str, float], int]:
    """(share of a core used by the process, share by thread, fixations tried) over MEASURE_S."""
    hub = daemon.parts.hub
    tried_before = hub.counts["fixation_refused"] + hub.counts["fixation_converged"]
    wall0, cpu0, threads0 = time.monotonic(), time.process_time(), thread_cpu_s()
    time.sleep(MEASURE_S)  # the window measured, not a wait for anything
    wall1, cpu1, threads1 = time.monotonic(), time.process_time(), thread_cpu_s()
    wall = wall1 - wall0
    shares = {name: (threads1[name] - threads0[name]) / wall for name in threads1 if name in threads0}
    tried = hub.counts["fixation_refused"] + hub.counts["fixation_converged"] - tried_before
    return (cpu1 - cpu0) / wall, shares, tried


@pytest.mark.parametrize("how", ["servo process killed", "servo bus down"])
def test_a_degraded_service_uses_under_5_percent_of_a_core(tmp_path, how):
    with Daemon(slow_to_restart(tmp_path)) as daemon:
        for side in ("left", "right"):  # the simulation's rendering out of the figure
            daemon.control.inject_fault(SimFault.CAMERA_STALL, camera=side)
        key = degrade(daemon, how)
        wait_until(lambda: key in daemon.control.snapshot().faults, 10.0, f"the {key} fault")
        time.sleep(1.0)  # past the back-off's first steps; what lasts is measured
        share, threads, tried = measure(daemon)
        snapshot = daemon.control.snapshot()
        print(f"{how}, cameras stalled: {100 * share:.1f} % of a core; fixations tried {tried}; "
              f"by thread {({k: round(100 * v, 1) for k, v in threads.items() if v})}")
        assert snapshot.state is ServicePhase.DEGRADED, snapshot.faults
        assert share < CORE_SHARE_MAX, threads
        assert tried <= MEASURE_S + 2  # about one a second, not thousands


def test_with_the_cameras_rendering_the_service_itself_stays_under_5_percent(tmp_path):
    with Daemon(slow_to_restart(tmp_path)) as daemon:
        key = degrade(daemon, "servo process killed")
        wait_until(lambda: key in daemon.control.snapshot().faults, 10.0, f"the {key} fault")
        time.sleep(1.0)
        share, threads, tried = measure(daemon)
        assert key in daemon.control.snapshot().faults, "the service healed while it was measured"
        cameras = sum(threads.get(name, 0.0) for name in CAMERA_THREADS)
        print(f"servo process killed, cameras rendering: {100 * share:.1f} % of a core, of which the simulated "
              f"cameras {100 * cameras:.1f} %; by thread {({k: round(100 * v, 1) for k, v in threads.items() if v})}")
        service = {name: s for name, s in threads.items() if name not in CAMERA_THREADS and not name.startswith("[")}
        assert sum(service.values()) < CORE_SHARE_MAX, service
        assert tried <= MEASURE_S + 2
