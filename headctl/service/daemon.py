"""The service for one head: `Daemon(config, front_end=...).run()`, its front end the HTTP API, is
`headctl run`.

`start()` builds the head from its config and starts its threads, each with one job:

- `camera-left`, `camera-right`: the cameras' capture threads (latest frame + history);
- `servo-io` (`servo_loop.ServoLoop`): one read and one write of the bus per period;
- `fixation` (`fixation_thread.FixationThread`): clients' looks, else exploratory fixations
  on the `Head` (whose bus is the servo loop and whose pairs come from the capture threads);
- `gaze-adapter` (`calib_free.map.adapter.MapAdapter`): learns from the taught fixations, with
  atomic checkpoints (`persistence.Checkpointer`);
- the front end, when one is given (`FrontEnd`; `headctl run` gives the HTTP control API and
  dashboard): serving `control.ServiceControl` from before the head starts until after it
  stopped;
- `supervisor` (`supervisor.Supervisor`): systemd's status and watchdog, fault events,
  stalled cameras, and restarting the parts that died under one policy (`restarts`): the
  servo process, the fixation thread, the adapter thread, the front end. Once the service
  gives up, `run()` stops it and returns `restarts.EXIT_GAVE_UP`.

`stop()` finishes the fixation in progress, saves the map, leaves the servos in the
configured safe state and closes every device; it is idempotent. `run()` starts, waits for
SIGTERM/SIGINT (or `request_stop()`), and stops. A `Daemon` is also a context manager.
"""
from __future__ import annotations

import contextlib
import functools
import logging
import sys
import threading
import time
from collections.abc import Callable
from types import FrameType
from typing import Protocol

from calib_free.correspondence import search as correspondence
from calib_free.map.adapter import MapAdapter, Sample
from calib_free.map.gaze_map import AdaptResult
from drivers.clock import SYSTEM_CLOCK, Clock
from drivers.errors import DriverError
from drivers.cameras.stereo import StereoPair
from headctl.config.head import HeadConfig
from headctl.errors import HeadctlError
from headctl.service.head import StereoPairSource
from headctl.service.build import HeadDevices, build_head
from headctl.service.control import HeadService, ServiceControl
from headctl.log_limit import RepeatLimiter
from headctl.service.events import EventHub, EventLog
from headctl.service.exposure import ExposureHold
from headctl.service.fixation_thread import FixationThread, HeadEvents, Interrupt
from headctl.service.fixation_trace import TracingController
from headctl.service.servo_io.hardware_faults import HardwareFaults
from headctl.service.looks import LookQueue
from headctl.service.parts import LearningLog, MapOrigin, RunningParts, ServiceParts, ServicePhase
from headctl.service.persistence import (Checkpointer, MagnificationFile, StateDirLock, restore_magnification,
                                         restore_map, write_atomically)
from headctl.service.supervision.restarts import EXIT_GAVE_UP, Restartable, RestartRecord, Restarts, RestartSettings
from headctl.service.servo_io.loop import ServoIO, ServoLoop
from headctl.service.servo_io.process import ServoLoopProcess
from headctl.service.status import FaultWatcher
from headctl.service.tracking import Tracking
from headctl.service.supervision.supervisor import Supervisor, status_line
from headctl.service.supervision.systemd import SystemdNotifier

log = logging.getLogger(__name__)


class FrontEnd(Protocol):
    """A way in to the running service (the HTTP control API), serving while its context is
    entered: `url` is where clients reach it; a front end that stopped on its own (`error`,
    or not `is_alive()`) is the service's `api` fault."""

    @property
    def url(self) -> str: ...

    @property
    def error(self) -> BaseException | None: ...

    def is_alive(self) -> bool: ...


# Makes the front end over the service's control facade; entering the context starts serving.
FrontEndFactory = Callable[[HeadService], contextlib.AbstractContextManager[FrontEnd]]


class _FixationPart:
    """The fixation thread as a `Restartable`: a dead one is replaced by a new thread over the
    same controller, head and look queue, its counts carried over."""

    name = "fixation"
    counts = True

    def __init__(self, parts: ServiceParts, make: Callable[[], FixationThread]) -> None:
        self.parts, self.make = parts, make

    def failure(self) -> str | None:
        running = self.parts.running
        if running is None or running.fixation.is_alive() or running.fixation.abort.is_set():
            return None
        return f"fixation thread died: {running.fixation.error!r}"

    def restart(self) -> dict[str, object]:
        running = self.parts.running
        assert running is not None
        old, new = running.fixation, self.make()
        new.carry_over(old)
        new.start()
        running.fixation = new
        return {"fixations": new.done}


class _AdapterPart:
    """The adapter thread as a `Restartable` (`MapAdapter.restart`: its queue and map kept)."""

    name = "gaze-adapter"
    counts = True

    def __init__(self, adapter: MapAdapter) -> None:
        self.adapter = adapter

    def failure(self) -> str | None:
        return None if self.adapter.is_alive() else f"adapter thread died: {self.adapter.error!r}"

    def restart(self) -> dict[str, object]:
        self.adapter.restart()
        return {"adaptations": self.adapter.progress.adaptations}


class _ServoThreadPart:
    """The servo loop as a thread of this process (`service.servo_process: false`, or a test's
    manual clock) as a `Restartable`: a thread cannot be started twice and the loop's bus is in
    an unknown state, so each restart fails; its failures run into the give-up rule, and systemd
    starts the unit again."""

    name = "servo-io"
    counts = True

    def __init__(self, loop: ServoLoop) -> None:
        self.loop = loop

    def failure(self) -> str | None:
        if self.loop.is_alive() or self.loop.stopping:
            return None
        return f"servo loop thread died: {self.loop.error!r}"

    def restart(self) -> dict[str, object]:
        raise HeadctlError("a servo loop thread is not restarted in place (service.servo_process: true makes it "
                           "a process that is)")


class _FrontEndPart:
    """The front end as a `Restartable`: one that stopped serving is closed and made again."""

    name = "api-server"
    counts = True

    def __init__(self, daemon: "Daemon") -> None:
        self.daemon = daemon

    def failure(self) -> str | None:
        faults = self.daemon._front_end_faults()
        return faults.get("api")

    def restart(self) -> dict[str, object]:
        self.daemon._restart_front_end()
        return {"url": self.daemon.parts.api_url}


class Daemon:
    """The service for one head; see the module docstring. `front_end`: how to make its front
    end (None: the service has none, as with `api.enabled: false`)."""

    def __init__(self, config: HeadConfig, clock: Clock = SYSTEM_CLOCK, *,
                 front_end: FrontEndFactory | None = None) -> None:
        self.config = config
        self.clock = clock
        hub = EventHub()
        self.parts = ServiceParts(config=config, clock=clock, hub=hub, warnings=EventLog(limiter=RepeatLimiter(config.logging.repeat_summary_s, clock)),
                                  looks=LookQueue(config.api.max_queued_looks), learning=LearningLog(clock),
                                  started_s=clock.monotonic(), hardware=HardwareFaults(hub))
        self.notifier = SystemdNotifier()
        self._make_front_end = front_end
        self.front_end: FrontEnd | None = None  # once serving
        self.control = ServiceControl(self.parts, self._front_end_faults)
        self.faults = FaultWatcher(self.parts, self.parts.hub, self._front_end_faults)
        self.stop_requested = threading.Event()
        self._abort = threading.Event()  # stops the fixation in progress, for good
        self._stack = contextlib.ExitStack()
        self._front_stack = contextlib.ExitStack()  # the front end's own, so that it can be made again
        self._supervisor: Supervisor | None = None
        self.restarts = Restarts(RestartSettings.of(config.service), clock, on_restart=self._restarted)
        self.exit_code = 0  # what `run()` returns: EXIT_GAVE_UP once the service gave up
        self._lifecycle = threading.Lock()
        # The servo loop in a process of its own, unless the config says otherwise or time is
        # not the system's (a test's manual clock cannot cross into another process).
        self._servo_process = config.service.servo_process and clock is SYSTEM_CLOCK

    @property
    def phase(self) -> ServicePhase:
        return self.parts.phase

    @property
    def api_url(self) -> str | None:
        return self.parts.api_url

    def _front_end_faults(self) -> dict[str, str]:
        front = self.front_end
        if front is not None and self.parts.phase is ServicePhase.RUNNING and (front.error is not None
                                                                              or not front.is_alive()):
            return {"api": f"control API stopped: {front.error!r}"}
        return {}

    # -- lifecycle ----------------------------------------------------------------------------
    def __enter__(self) -> "Daemon":
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def start(self) -> "Daemon":
        """Build the head and start every thread; returns once the service runs. On failure
        whatever was started is stopped again and the error raised."""
        with self._lifecycle:
            if self.parts.phase is not ServicePhase.STARTING:
                raise HeadctlError(f"the service is {self.parts.phase}: a Daemon starts once")
            try:
                self._start()
            except BaseException:
                self._stop()
                raise
        return self

    def _start(self) -> None:
        cfg, clock, parts, stack = self.config, self.clock, self.parts, self._stack
        # A thread waiting for the GIL gets it after this long (CPython's default is 5 ms): the
        # servo loop's timer would otherwise wait behind Python-level work of the other threads.
        sys.setswitchinterval(cfg.service.switch_interval_ms / 1000.0)
        cfg.state_dir.mkdir(parents=True, exist_ok=True)
        stack.callback(self.notifier.close)
        logging.getLogger().addHandler(parts.warnings)
        stack.callback(logging.getLogger().removeHandler, parts.warnings)
        stack.enter_context(StateDirLock(cfg.lock_path))
        if self._make_front_end is not None:
            self._start_front_end(self._make_front_end)
        self.notifier.notify(status="starting: restoring the gaze map")
        gm, source, problems = restore_map(cfg)
        parts.map_origin = MapOrigin(source, problems, gm.adaptations, list(gm.recent_errors))
        magnification, lens_problems = restore_magnification(cfg.magnification_path)
        parts.map_origin.problems.extend(lens_problems)
        self.notifier.notify(status="starting: compiling the gaze map's inner loops")
        compile_s = gm.warm_up() + correspondence.warm_up()
        (log.info if compile_s > 1.0 else log.debug)("gaze map and correspondence inner loops ready in %.1f s",
                                                     compile_s)

        loop: ServoIO
        if self._servo_process:
            # The child opens and enables the bus; the cameras of a simulated head render the
            # servos it simulates.
            self.notifier.notify(status="starting: the servo process")
            process = ServoLoopProcess(cfg, on_fault_change=self._fault_changed, clock=clock).start()
            stack.callback(process.stop)
            loop = process
            devices = stack.enter_context(HeadDevices.cameras_of(cfg, process, clock))
        else:
            devices = stack.enter_context(HeadDevices.build(cfg, clock))
            assert devices.bus is not None
            devices.bus.enable()
            thread = ServoLoop(devices.bus, cfg.service.servo_rate_hz, cfg.service.input_timeout_s,
                               realtime_priority=cfg.service.realtime_priority, on_fault_change=self._fault_changed,
                               clock=clock)
            thread.start()
            stack.callback(thread.stop)
            loop = thread
        parts.devices = devices
        pair = stack.enter_context(StereoPair(devices.cameras["left"], devices.cameras["right"],
                                              cfg.cameras.tolerance_s))
        for camera in devices.cameras.values():
            camera.enable()
        adapter = MapAdapter(gm, on_adapted=self._on_adapted)
        checkpointer = Checkpointer(adapter, cfg.map_path, cfg.service.checkpoint_every, clock=clock,
                                    interval_s=cfg.service.checkpoint_interval_s)
        adapter.start()
        stack.callback(adapter.stop)
        interrupt = Interrupt(self._abort)
        head_events = HeadEvents(parts.hub)
        head = build_head(cfg, loop, StereoPairSource(pair, clock=clock, interrupt=interrupt), clock,
                          interrupt=interrupt, observer=head_events, goals_in_force=loop.goals)
        controller = TracingController(head, adapter, parts.fixation_taps, cfg.fixation.params,
                                       seed=None if not cfg.simulated else cfg.gaze_map.seed,
                                       clock=clock.monotonic, learner=adapter)
        tracking = Tracking(head, adapter, adapter.map.params.disparity_range, cfg.tracking.params,
                            frame_period_s=1.0 / (cfg.cameras.left.fps or 30.0), publish=parts.hub.publish,
                            clock=clock)
        make_fixation = functools.partial(FixationThread, controller, head, interrupt, parts.looks, parts.hub,
                                          self._paused_reason, explore=cfg.fixation.explore,
                                          rate_hz=cfg.fixation.rate_hz, clock=clock, tracking=tracking,
                                          exposure=ExposureHold(devices.cameras.values()),
                                          magnification=magnification)
        fixation = make_fixation()
        parts.running = RunningParts(devices, pair, loop, adapter, checkpointer, head, head_events, fixation,
                                     MagnificationFile(cfg.magnification_path, magnification))
        fixation.start()
        stack.callback(self._stop_fixation)
        watched: list[Restartable] = [_FixationPart(parts, make_fixation), _AdapterPart(adapter)]
        watched.insert(0, loop if isinstance(loop, ServoLoopProcess) else _ServoThreadPart(loop))
        if self.front_end is not None:
            watched.append(_FrontEndPart(self))
        self.restarts.watch(watched)
        parts.phase = ServicePhase.RUNNING
        self._supervisor = Supervisor(parts, self.notifier, self.faults, self.restarts, self._give_up)
        self._supervisor.start()
        log.info("headctl running: %s, state in %s, API %s", cfg.path, cfg.state_dir,
                 parts.api_url or "off (api.enabled: false)")
        self.notifier.notify(ready=1, status=status_line(parts, self.faults.check()))

    def _stop_fixation(self) -> None:
        if self.parts.running is not None:  # the thread running now (a restart replaces it)
            self.parts.running.fixation.stop()

    def _start_front_end(self, make: FrontEndFactory) -> None:
        """Serve from now on; its URL in the status and in `api_url_path` (for local clients)."""
        cfg = self.config
        self._stack.callback(lambda: self._front_stack.close())
        self._serve(make)
        self._stack.callback(cfg.api_url_path.unlink, missing_ok=True)  # before the front end stops

    def _serve(self, make: FrontEndFactory) -> None:
        front = self.front_end = self._front_stack.enter_context(make(self.control))
        self.parts.api_url = front.url
        write_atomically(self.config.api_url_path, front.url + "\n")

    def _restart_front_end(self) -> None:
        """A new front end in place of one that stopped serving (the supervisor's restart)."""
        assert self._make_front_end is not None
        self._front_stack.close()
        self._front_stack = contextlib.ExitStack()
        self._serve(self._make_front_end)

    def _restarted(self, record: RestartRecord) -> None:
        """A part restarted by the supervisor: counted, and told as an event."""
        self.parts.restarts[record.part] += 1
        kind = "servo_process_restarted" if record.part == ServoLoopProcess.name else "part_restarted"
        self.parts.hub.publish(kind, part=record.part, cause=record.cause, restarts=record.restarts,
                               **record.detail)
        self.faults.check()

    def _give_up(self, reason: str) -> None:
        """Too many failures (`restarts`): stop, leaving the servos in the safe state as far as
        possible, and exit `EXIT_GAVE_UP` for systemd to restart the unit."""
        self.exit_code = EXIT_GAVE_UP
        self.parts.hub.publish("service_gave_up", reason=reason, exit_code=EXIT_GAVE_UP)
        self.notifier.notify(status=f"giving up: {reason}")
        self.stop_requested.set()

    def _fault_changed(self) -> None:
        self.faults.check()  # the servo loop's bus went down or came back, a joint faulted or cleared

    def _paused_reason(self) -> str | None:
        running = self.parts.running
        if running is None:
            return "starting"
        if running.loop.down_reason is not None:
            return "servo bus down"
        if not running.loop.is_alive():
            return "servo loop down"
        if running.loop.missing:
            return "servo missing: " + "; ".join(running.loop.missing.values())
        if not running.loop.torque_enabled:
            return "torque off"
        return None

    def _on_adapted(self, sample: Sample, result: AdaptResult) -> None:
        running = self.parts.running
        if running is None:
            return
        adaptations = running.adapter.progress.adaptations
        self.parts.learning.add(adaptations, sample, result, time.time())
        running.checkpointer.maybe(adaptations)

    def stop(self) -> None:
        """Stop every thread, save the map, leave the servos in the safe state, close the devices.
        Idempotent."""
        with self._lifecycle:
            self._stop()

    def _stop(self) -> None:
        if self.parts.phase is ServicePhase.STOPPED:
            return
        started = self.clock.monotonic()
        self.parts.phase = ServicePhase.STOPPING
        self.notifier.notify(stopping=1, status="stopping: finishing the fixation, saving the gaze map")
        if self._supervisor is not None:
            self._supervisor.stop()
        running = self.parts.running
        try:
            if running is not None:
                budget_s = self.config.service.shutdown_timeout_s
                running.fixation.stop(timeout_s=min(2.0, budget_s / 2))
                running.adapter.wait_idle(timeout_s=0.5)
                running.adapter.stop(timeout_s=0.5)
                running.checkpointer.save()
                running.magnification_file.save()
                self._safe_state(running)
        finally:
            self._stack.close()
            self.parts.running = None
            self.parts.phase = ServicePhase.STOPPED
        log.info("shutdown took %.2f s", self.clock.monotonic() - started)

    def _safe_state(self, running: RunningParts) -> None:
        loop, bus = running.loop, running.devices.bus
        safe_state = self.config.service.safe_state
        if isinstance(loop, ServoLoopProcess):  # the child leaves its bus in the safe state
            loop.stop(timeout_s=min(3.0, self.config.service.shutdown_timeout_s), safe_state=safe_state)
            return
        assert isinstance(loop, ServoLoop) and bus is not None
        state = loop.latest_state()
        if state is not None and loop.down_reason is None and loop.is_alive():
            try:
                loop.request_goals({j: s.position for j, s in state.joints.items() if s.torque_on}, timeout_s=0.5)
            except (DriverError, HeadctlError) as err:
                log.warning("could not hold the present position at shutdown: %s", err)
        loop.stop()
        if safe_state == "torque_off":
            try:
                bus.disable()
            except DriverError as err:
                log.warning("could not turn torque off at shutdown: %s", err)

    # -- running as a process -------------------------------------------------------------------
    def request_stop(self, signum: int | None = None, frame: FrameType | None = None) -> None:
        if signum is not None:
            log.info("signal %d: stopping", signum)
        self.stop_requested.set()

    def run(self, install_signals: bool = True) -> int:
        """Start, run until SIGTERM/SIGINT or `request_stop()`, stop; the exit code."""
        if install_signals:
            import signal

            signal.signal(signal.SIGTERM, self.request_stop)
            signal.signal(signal.SIGINT, self.request_stop)
        self.start()
        try:
            while not self.stop_requested.wait(0.5):
                pass
        finally:
            self.stop()
        if self.exit_code:
            log.critical("headctl stopped: it gave up (%s); exit code %d", self.restarts.give_up_reason,
                         self.exit_code)
        else:
            log.info("headctl stopped")
        return self.exit_code
