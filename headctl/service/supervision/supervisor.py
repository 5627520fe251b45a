"""The supervisor thread: systemd's STATUS and WATCHDOG, fault events, restarts, stalled cameras.

Every `interval_s` (a quarter of a second, or a third of systemd's watchdog interval) it
sends the status line when it changed, publishes faults as they come and go, restarts the
parts that died under the service's one restart policy (`restarts.Restarts`), pets the
watchdog while the servo loop is alive or its restart is scheduled, and restarts the stream
of a camera that failed or has sent nothing for `service.camera_stall_s` (the backends reopen
a lost device themselves; this covers a silent stall and a stream that gave up), at most once
per that time per camera. Once the policy gives up it pets the watchdog no more and calls
`on_give_up` once (the daemon stops and exits `restarts.EXIT_GAVE_UP`).
"""
from __future__ import annotations

import logging
import math
import threading
from collections.abc import Callable

from drivers.cameras.camera import StreamHealth
from drivers.errors import DriverError
from headctl.service.fixation_thread import FixationCounts
from headctl.service.parts import ServiceParts
from headctl.service.supervision.restarts import Restarts
from headctl.service.servo_io.loop import join_thread
from headctl.service.servo_io.process import ServoLoopProcess
from headctl.service.status import FaultWatcher, service_state
from headctl.service.supervision.systemd import SystemdNotifier

log = logging.getLogger(__name__)

STATUS_LINE_EVERY_S = 1.0  # systemd's STATUS at most this often
WATCHDOG_LOOP_S = 1.0  # the servo loop must have cycled this recently for WATCHDOG=1


def status_line(parts: ServiceParts, faults: dict[str, str]) -> str:
    running = parts.running
    counts = running.fixation.counts() if running is not None else FixationCounts(done=0, taught=0, refused={})
    adaptations = running.adapter.progress.adaptations if running is not None else 0
    line = (f"{service_state(parts, faults)}: {counts['done']} fixations, {counts['taught']} taught, "
            f"{adaptations} adaptations")
    return line + (f"; {next(iter(faults.values()))}" if faults else "")


class Supervisor(threading.Thread):
    def __init__(self, parts: ServiceParts, notifier: SystemdNotifier, faults: FaultWatcher,
                 restarts: Restarts | None = None, on_give_up: Callable[[str], None] | None = None) -> None:
        super().__init__(name="supervisor", daemon=True)
        self.parts = parts
        self.notifier = notifier
        self.faults = faults
        self.restarts = restarts
        self.on_give_up = on_give_up
        self._gave_up = False
        self.clock = parts.clock
        watchdog_s = notifier.watchdog_s
        self.interval_s = min(0.25, watchdog_s / 3) if watchdog_s else 0.25  # faults reach clients this fast
        self._stop_event = threading.Event()
        self._last_line = ""
        self._last_line_s = -math.inf
        self._camera_restart_s: dict[str, float] = {}
        self.error: BaseException | None = None

    def stop(self, timeout_s: float = 2.0) -> None:
        self._stop_event.set()
        join_thread(self, timeout_s)

    def run(self) -> None:
        try:
            while not self._stop_event.wait(self.interval_s):
                self.tick()
        except Exception as err:  # reported through the status, never lost
            self.error = err
            log.exception("%s failed", self.name)

    def tick(self) -> None:
        """One round of supervision (the thread's; a test may call it on a manual clock)."""
        restarts = self.restarts
        if restarts is not None:
            restarts.tick()
            if restarts.gave_up and not self._gave_up:
                self._gave_up = True
                if self.on_give_up is not None:
                    self.on_give_up(restarts.give_up_reason or "")
        faults = self.faults.check()
        fields: dict[str, str | int] = {}
        now = self.clock.monotonic()
        line = status_line(self.parts, faults)
        if line != self._last_line and now - self._last_line_s >= STATUS_LINE_EVERY_S:
            fields["status"] = line
            self._last_line, self._last_line_s = line, now
        running = self.parts.running
        if running is not None:  # a map changed but not adapted since (loaded, reset) is saved on time too
            running.checkpointer.maybe_on_time(now)
            running.magnification_file.maybe_save()
        if self.notifier.watchdog_s and self.healthy():
            fields["watchdog"] = 1
        if fields:
            self.notifier.notify(**fields)
        self.watch_cameras()

    def healthy(self) -> bool:
        """What keeps systemd from restarting the service: a live servo loop, or one whose
        restart is scheduled; never once the restart policy gave up."""
        running, restarts = self.parts.running, self.restarts
        if running is None or (restarts is not None and restarts.gave_up):
            return False
        loop = running.loop
        if loop.is_alive() and self.clock.monotonic() - loop.last_cycle_s < WATCHDOG_LOOP_S:
            return True
        return restarts is not None and restarts.pending(ServoLoopProcess.name)

    def watch_cameras(self) -> None:
        devices = self.parts.devices
        if devices is None:
            return
        stall_s = self.parts.config.service.camera_stall_s
        now = self.clock.monotonic()
        for side, camera in devices.cameras.items():
            latest = camera.latest()
            age = now - (latest.time_s if latest is not None else self.parts.started_s)
            failed = camera.health is StreamHealth.FAILED
            if not (failed or age > stall_s) or now - self._camera_restart_s.get(side, -math.inf) < stall_s:
                continue
            self._camera_restart_s[side] = now
            self.parts.camera_restarts[side] += 1
            log.warning("camera %s: %s; restarting its stream (restart %d)", side,
                        "the stream failed" if failed else f"no frame for {age:.1f} s",
                        self.parts.camera_restarts[side])
            try:
                camera.disable()
                camera.enable()
            except (DriverError, OSError) as err:
                log.error("camera %s: restart failed: %s", side, err)
