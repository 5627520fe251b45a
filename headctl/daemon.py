"""The service: `headctl run` builds the head from its config and keeps it learning.

Threads, each with one job (DESIGN.md, "Service shape"):

- `camera-left`, `camera-right`: the cameras' own capture threads (latest frame + history).
- `servo-io` (`ServoLoop`): at a fixed rate (default 100 Hz) one `read_state()` and one
  `write_goals()` of the latest goals; the only thread that talks to the bus while the
  daemon runs. Goals outside the limits are clamped or refused by the bus itself. When the
  controller falls silent for `service.input_timeout_s` the loop holds the present position;
  while the bus is down it writes nothing and the service is "degraded".
- `fixation` (`FixationThread`): exploratory fixations (`calib_free.fixation`) on a
  `DriverHead` whose bus is the loop (`LoopBus`) and whose pairs come from the capture
  threads (`StereoPairSource`); taught fixations go to the adapter.
- `gaze-adapter` (`calib_free.adapter.MapAdapter`): learns from a bounded queue;
  checkpoints the map atomically every `service.checkpoint_every` adaptations.
- `api-server` (`headctl.api.ApiServer`): the HTTP control API, event stream, metrics,
  eye streams and dashboard; clients' looks go to the fixation thread through a queue
  (`headctl.control.LookQueue`), events come from the threads through `EventHub`.

The main thread handles SIGTERM/SIGINT and systemd's notifications (READY, STATUS,
WATCHDOG, STOPPING), which are written to `$NOTIFY_SOCKET` directly (`SystemdNotifier`).
"""
from __future__ import annotations

import collections
import contextlib
import dataclasses
import fcntl
import logging
import math
import os
import re
import signal
import socket
import sys
import threading
import time
from pathlib import Path
from typing import Any, Callable, Iterator, Mapping

import numpy as np

from calib_free import GazeMap
from calib_free.adapter import MapAdapter, Sample
from calib_free.correspondence import as_grey_float, horizontal_offset
from calib_free.errors import MapFileError
from calib_free.fixation import FixationController, FixationRecord, HeadTimeoutError, PairTimeoutError
from calib_free.gaze_map import AdaptResult
from calib_free.sim import pose_of
from drivers.camera import Camera, StereoPair, StreamHealth, create_camera
from drivers.errors import (BusDownError, CameraError, CameraTimeoutError, DeviceStateError, DriverError,
                            JointLimitError, ServoHardwareError)
from drivers.servo_bus import AUTO_REBOOT_HOLDOFF_S, JOINTS, BusState, ServoBus, create_servo_bus
from headctl.config import HeadConfig, is_loopback
from headctl.control import (CANCELLED, DONE, FAILED, ControlError, EventHub, InvalidRequestError, LookJob, LookQueue,
                             LookRequest, NotFoundError, UnavailableError, plain)
from headctl.errors import HeadctlError
from headctl.head import DriverHead, StereoPairSource

log = logging.getLogger(__name__)

REFUSED_BUS_DOWN = "servo bus down"
REFUSED_SERVO_FAULT = "servo fault"
REFUSED_SHUTDOWN = "aborted at shutdown"
REFUSED_CANCELLED = "look cancelled"
PAIR_MAX_AGE_S = 0.5  # a target's disparity is measured only in a pair this recent
# A match this good or better gives a target's disparity; below, the patch is likely matched to
# something else (a distinctly textured patch scores 0.8-1 on the simulated head).
MIN_DISPARITY_NCC = 0.6
MAP_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9._-]{0,100}\.npz")


class ShutdownError(HeadctlError):
    """The daemon is stopping: the fixation in progress is aborted."""


class LookCancelledError(HeadctlError):
    """A client cancelled the look in progress (or a newer look replaced it)."""


class Interrupt:
    """Why the head's work in progress must stop: the daemon stopping (for good), or a client
    cancelling the look in progress (that look only). `LoopBus` and `AbortablePairSource` check
    it before every bus access and every slice of waiting for frames, so a fixation stops
    within one servo cycle or one frame slice; the motion already sent is completed (the
    servos hold the last goal), no further saccade or vergence step is sent."""

    def __init__(self, stop: threading.Event) -> None:
        self.stop = stop
        self._look: LookJob | None = None

    def check(self) -> None:
        if self.stop.is_set():
            raise ShutdownError("the daemon is stopping")
        look = self._look
        if look is not None and look.cancel_requested.is_set():
            raise LookCancelledError(f"look {look.id} stopped: {look.cancel_detail}")

    @contextlib.contextmanager
    def during(self, job: LookJob) -> Iterator[None]:
        """Cancelling `job` interrupts what runs inside this block."""
        self._look = job
        try:
            yield
        finally:
            self._look = None


class StaleStateError(HeadctlError, TimeoutError):
    """The servo loop produced no fresh state in time."""


def join_thread(thread: threading.Thread, timeout_s: float) -> None:
    """Wait for a thread asked to stop (not from itself); a warning if it does not."""
    if thread.is_alive() and threading.current_thread() is not thread:
        thread.join(timeout_s)
        if thread.is_alive():
            log.warning("%s did not stop within %.1f s", thread.name, timeout_s)


def _percentiles(values: Any, qs: tuple[float, ...]) -> list[float | None]:
    arr = np.asarray(list(values), dtype=float)
    return [float(np.percentile(arr, q)) if len(arr) else None for q in qs]


# --- the servo I/O loop ------------------------------------------------------------------------
class _WriteRequest:
    def __init__(self, goals: Mapping[str, float]) -> None:
        self.goals = dict(goals)
        self.done = threading.Event()
        self.sent: dict[str, float] | None = None
        self.error: BaseException | None = None


class _LoopAction:
    """A call to run on the loop thread between two cycles (the bus has one user)."""

    def __init__(self, fn: Callable[[ServoBus], Any]) -> None:
        self.fn = fn
        self.done = threading.Event()
        self.result: Any = None
        self.error: BaseException | None = None


class ServoLoop(threading.Thread):
    """One read and one write per cycle at a fixed rate; the bus's only user while it runs."""

    REBOOT_AFTER_S = 1.0  # a hardware error that leaves torque on persists this long: reboot

    def __init__(self, bus: ServoBus, rate_hz: float = 100.0, input_timeout_s: float = 0.5,
                 history: int = 6000, realtime_priority: int = 0,
                 on_fault_change: Callable[[], None] | None = None) -> None:
        super().__init__(name="servo-io", daemon=True)
        self.bus = bus
        self.on_fault_change = on_fault_change  # the bus went down or came back, a joint faulted or cleared
        self.realtime_priority = realtime_priority
        self.period_s = 1.0 / rate_hz
        self.input_timeout_s = input_timeout_s
        self._stop_event = threading.Event()
        self._cond = threading.Condition()
        self._state: BusState | None = None
        self._state_seq = 0
        self._goals: dict[str, float] = {}  # the latest-value slot: what each cycle writes
        self._requests: list[_WriteRequest] = []
        self._last_input_s = time.monotonic()
        self._holding = False
        self.down_reason: str | None = None
        self.faults: dict[str, tuple[str, ...]] = {}
        self.error: BaseException | None = None
        self._fault_since: dict[str, float] = {}  # faulted joints held, since when
        self._last_reboot_s: dict[str, float] = {}
        self.read_errors = 0
        self.write_errors = 0
        self.bus_down_count = 0
        self.last_read_error = ""
        self.torque_enabled = True  # as the daemon enabled the bus; `set_torque` changes it
        self._actions: list[_LoopAction] = []
        self.last_read_s = time.monotonic()
        self.cycles = 0
        self.overruns = 0
        self.periods_s: collections.deque[float] = collections.deque(maxlen=history)
        self._timing_cache: tuple[float, dict[str, float | None]] | None = None
        self.last_cycle_s = time.monotonic()

    # -- what the controller calls (through LoopBus) ----------------------------------------
    def touch(self) -> None:
        self._last_input_s = time.monotonic()

    def fresh_state(self, timeout_s: float = 1.0) -> BusState:
        """The first state read after this call."""
        self.touch()
        deadline = time.monotonic() + timeout_s
        with self._cond:
            seq = self._state_seq
            while self._state_seq == seq:
                remaining = deadline - time.monotonic()
                if self.down_reason is not None:
                    raise BusDownError(f"{self.bus.name}: {self.down_reason}")
                if remaining <= 0 or not self.is_alive():
                    raise StaleStateError(f"{self.bus.name}: no servo state within {timeout_s} s")
                self._cond.wait(min(remaining, 0.05))
            assert self._state is not None
            return self._state

    def latest_state(self) -> BusState | None:
        with self._cond:
            return self._state

    def request_goals(self, goals: Mapping[str, float], timeout_s: float = 1.0) -> dict[str, float]:
        """Have the next cycle write `goals` (the bus checks the limits); what was sent, or its error."""
        self.touch()
        request = _WriteRequest(goals)
        with self._cond:
            if self.down_reason is not None:
                raise BusDownError(f"{self.bus.name}: {self.down_reason}")
            self._requests.append(request)
        if not request.done.wait(timeout_s):
            with self._cond:
                if request in self._requests:
                    self._requests.remove(request)
            raise StaleStateError(f"{self.bus.name}: goals not written within {timeout_s} s")
        if request.error is not None:
            raise request.error
        assert request.sent is not None
        return request.sent

    def goals(self) -> dict[str, float]:
        with self._cond:
            return dict(self._goals)

    def call(self, fn: Callable[[ServoBus], Any], timeout_s: float = 2.0) -> Any:
        """Run `fn(bus)` on the loop thread before its next cycle; its result, or its error."""
        action = _LoopAction(fn)
        with self._cond:
            if not self.is_alive():
                raise ShutdownError(f"{self.name}: the servo loop is not running")
            self._actions.append(action)
        if not action.done.wait(timeout_s):
            raise StaleStateError(f"{self.bus.name}: the servo loop did not get to it within {timeout_s} s")
        if action.error is not None:
            raise action.error
        return action.result

    def set_torque(self, on: bool, timeout_s: float = 2.0) -> None:
        """Torque on (each goal set to the present position first: no jump) or off, all joints.
        The goal slot is emptied either way, so no goal from before is written afterwards."""
        def switch(bus: ServoBus) -> None:
            bus.enable() if on else bus.disable()
            with self._cond:
                self._goals = {}
            self.torque_enabled = on
        self.call(switch, timeout_s)
        log.warning("%s: torque %s on all joints (requested)", self.name, "on" if on else "off")

    def stop(self, timeout_s: float = 2.0) -> None:
        self._stop_event.set()
        join_thread(self, timeout_s)

    # -- the loop ------------------------------------------------------------------------
    def _set_priority(self) -> None:
        """SCHED_FIFO for this thread alone (Linux applies it to the calling thread), when allowed:
        root, CAP_SYS_NICE, or an RLIMIT_RTPRIO as high (the unit's LimitRTPRIO=)."""
        if self.realtime_priority <= 0:
            return
        try:
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(self.realtime_priority))
        except (OSError, AttributeError) as err:
            log.warning("%s: realtime priority %d not granted (%s); running at normal priority "
                        "(LimitRTPRIO= in the unit allows it)", self.name, self.realtime_priority, err)
        else:
            log.info("%s: SCHED_FIFO priority %d", self.name, self.realtime_priority)

    def run(self) -> None:
        self._set_priority()
        next_s = time.monotonic()
        previous_s: float | None = None
        try:
            while not self._stop_event.is_set():
                started = time.monotonic()
                if previous_s is not None:
                    self.periods_s.append(started - previous_s)
                previous_s = started
                self._run_actions()
                self._cycle()
                self.cycles += 1
                self.last_cycle_s = time.monotonic()
                next_s += self.period_s
                delay = next_s - time.monotonic()
                if delay < 0:
                    self.overruns += 1
                    next_s = time.monotonic()  # no burst of catch-up cycles
                # Always yield a little: at realtime priority a loop that never waits would
                # starve every other thread of its CPU.
                self._stop_event.wait(max(delay, 0.1 * self.period_s))
        except Exception as err:  # reported through the status, never lost
            self.error = err
            log.exception("%s: the servo loop failed", self.name)
        finally:
            with self._cond:
                stopped = ShutdownError(f"{self.name}: the servo loop stopped")
                for pending in (*self._requests, *self._actions):
                    pending.error = stopped
                    pending.done.set()
                self._requests.clear()
                self._actions.clear()
                self._cond.notify_all()

    def _run_actions(self) -> None:
        with self._cond:
            actions, self._actions = self._actions, []
        for action in actions:
            try:
                action.result = action.fn(self.bus)
            except Exception as err:  # the caller gets it
                action.error = err
            action.done.set()

    def _cycle(self) -> None:
        try:
            state = self.bus.read_state()
        except BusDownError as err:
            self._went_down(str(err))
            return
        except DriverError as err:  # a failed read: nothing is written on a stale state
            self.read_errors += 1
            self.last_read_error = str(err)
            if self.read_errors % 100 == 1:  # at 100 Hz a persistent fault would drown the log
                log.warning("%s: read failed (%d so far): %s", self.name, self.read_errors, err)
            self._fail_requests(err)
            return
        self.last_read_s = time.monotonic()
        if self.down_reason is not None:
            log.warning("%s: servo bus back; motion resumes", self.name)
            self.down_reason = None
            with self._cond:
                self._goals = {}  # the bus restored torque at the positions read back
            self._fault_changed()
        faults = state.faults
        now = time.monotonic()
        with self._cond:
            for joint in faults:
                if joint not in self.faults:
                    # That joint is held where it is until the error clears; the fault is
                    # reported in the status.
                    log.error("%s: %s reports %s: joint held", self.name, self.bus.describe(joint),
                              ", ".join(faults[joint]))
                    self._goals[joint] = state[joint].position
                    self._fault_since[joint] = now
            for joint in set(self._fault_since) - set(faults):
                log.warning("%s: %s: hardware error cleared; joint free again", self.name, self.bus.describe(joint))
                del self._fault_since[joint]
            changed = set(faults) != set(self.faults)
            self.faults = faults
            self._state = state
            self._state_seq += 1
            requests, self._requests = self._requests, []
            self._cond.notify_all()
        stale = time.monotonic() - self._last_input_s > self.input_timeout_s
        if stale and not self._holding and self._goals:
            log.info("%s: no input for %.2f s: holding the present position", self.name, self.input_timeout_s)
            with self._cond:
                self._goals = {j: state[j].position for j in self._goals}
        self._holding = stale
        self._write(state, requests)
        self._recover_faults(state, now)
        if changed:
            self._fault_changed()

    def _fault_changed(self) -> None:
        if self.on_fault_change is not None:
            try:
                self.on_fault_change()
            except Exception:  # a listener must not stop the servo loop
                log.exception("%s: fault listener failed", self.name)

    def _recover_faults(self, state: BusState, now: float) -> None:
        """With `reboot_on_hardware_error`, reboot a servo whose error persists with its torque on
        (the bus itself reboots those whose error cut the torque), at most once per holdoff."""
        if not self.bus.config.reboot_on_hardware_error:
            return
        for joint, since in list(self._fault_since.items()):
            if not state[joint].torque_on or now - since < self.REBOOT_AFTER_S:
                continue
            if now - self._last_reboot_s.get(joint, -math.inf) < AUTO_REBOOT_HOLDOFF_S:
                continue
            self._last_reboot_s[joint] = now
            try:
                self.bus.reboot(joint)  # one cycle takes longer: counted as an overrun
            except DriverError as err:
                log.error("%s: reboot of %s failed: %s", self.name, self.bus.describe(joint), err)

    def _write(self, state: BusState, requests: list[_WriteRequest]) -> None:
        with self._cond:
            for request in requests:
                held = [j for j in request.goals if j in self.faults]
                if held:  # a faulted joint keeps its hold; the command fails as a whole
                    request.error = ServoHardwareError(
                        f"{self.bus.name}: {', '.join(self.bus.describe(j) for j in held)} held after a hardware "
                        f"error ({'; '.join(', '.join(self.faults[j]) for j in held)}); nothing sent")
                    request.done.set()
                    continue
                self._goals.update(request.goals)
            requests = [r for r in requests if not r.done.is_set()]
            goals = {j: a for j, a in self._goals.items() if state[j].torque_on}
        if not goals:
            for request in requests:
                request.error = ServoHardwareError(f"{self.bus.name}: torque off on {', '.join(request.goals)}")
                request.done.set()
            return
        try:
            sent = self.bus.write_goals(goals)
        except (JointLimitError, ServoHardwareError) as err:
            # Refused as a whole (limit policy 'refuse', a faulted joint): drop the new goals.
            with self._cond:
                for request in requests:
                    for joint in request.goals:
                        self._goals[joint] = state[joint].position
            self._fail_requests(err, requests)
            return
        except BusDownError as err:
            self._went_down(str(err))
            self._fail_requests(err, requests)
            return
        except DriverError as err:
            self.write_errors += 1
            log.warning("%s: write failed: %s", self.name, err)
            self._fail_requests(err, requests)
            return
        with self._cond:
            self._goals.update(sent)
        for request in requests:
            request.sent = {j: sent[j] for j in request.goals if j in sent}
            if len(request.sent) != len(request.goals):
                request.error = ServoHardwareError(
                    f"{self.bus.name}: {', '.join(set(request.goals) - set(sent))} held (torque off)")
            request.done.set()

    def _went_down(self, reason: str) -> None:
        first = self.down_reason is None
        if first:
            self.bus_down_count += 1
            log.error("%s: servo bus down (%s): motion paused until it is back", self.name, reason)
        self.down_reason = reason
        if first:
            self._fault_changed()
        self._fail_requests(BusDownError(reason))

    def _fail_requests(self, err: BaseException, requests: list[_WriteRequest] | None = None) -> None:
        if requests is None:
            with self._cond:
                requests, self._requests = self._requests, []
                self._cond.notify_all()
        for request in requests:
            request.error = err
            request.done.set()

    TIMING_MAX_AGE_S = 0.25

    def timing(self) -> dict[str, Any]:
        """Counters, and the period and |period - nominal| quantiles (p50, p99, max) of the last
        cycles. The quantiles cost a millisecond over 6,000 periods: computed at most every
        `TIMING_MAX_AGE_S`, however many clients ask."""
        now = time.monotonic()
        cached = self._timing_cache
        if cached is None or now - cached[0] > self.TIMING_MAX_AGE_S:
            periods = np.array(self.periods_s, dtype=float)
            quantiles: dict[str, float | None] = {}
            for name, values in (("period", periods), ("jitter", np.abs(periods - self.period_s))):
                qs = np.quantile(values, (0.5, 0.99, 1.0)) if len(values) else (None, None, None)
                for label, q in zip(("p50", "p99", "max"), qs):
                    quantiles[f"{name}_{label}_ms"] = None if q is None else round(float(q) * 1e3, 3)
            self._timing_cache = cached = (now, quantiles)
        return {"rate_hz": round(1.0 / self.period_s, 3), "cycles": self.cycles, "overruns": self.overruns,
                "read_errors": self.read_errors, "write_errors": self.write_errors,
                "bus_down_count": self.bus_down_count, **cached[1]}


class LoopBus:
    """What `DriverHead` sees as its bus: the servo loop's states and goal slot.

    `read_state()` gives the first state read after the call; `write_goals()` returns once the
    loop has written the goals (as the bus clamped them) or raises the bus's error. Both raise
    `ShutdownError` once the daemon stops, which aborts the fixation in progress, and
    `LookCancelledError` once the look in progress is cancelled.
    """

    def __init__(self, loop: ServoLoop, interrupt: Interrupt) -> None:
        self.loop = loop
        self.config = loop.bus.config
        self.name = loop.bus.name
        self.interrupt = interrupt

    def read_state(self) -> BusState:
        self.interrupt.check()
        return self.loop.fresh_state()

    def write_goals(self, goals: Mapping[str, float]) -> dict[str, float]:
        self.interrupt.check()
        return self.loop.request_goals(goals)


class AbortablePairSource(StereoPairSource):
    """`StereoPairSource` that waits in short slices so a stopping daemon is not held up, and
    remembers when the last pair it gave was exposed (frame-to-command latency)."""

    def __init__(self, pair: StereoPair, interrupt: Interrupt, slice_s: float = 0.1) -> None:
        super().__init__(pair)
        self.interrupt = interrupt
        self.slice_s = slice_s
        self.last_pair_time_s: float | None = None

    def wait_pair(self, after_s: float, timeout_s: float) -> tuple[np.ndarray, np.ndarray]:
        deadline = time.monotonic() + timeout_s
        while True:
            self.interrupt.check()
            remaining = deadline - time.monotonic()
            try:
                frames = self.pair.wait_pair(after_s, max(0.0, min(self.slice_s, remaining)))
            except CameraTimeoutError as err:
                if remaining <= self.slice_s:
                    raise PairTimeoutError(f"no stereo pair exposed after t={after_s:.3f} s: {err}") from err
                continue
            except (CameraError, DeviceStateError) as err:  # failed, or being restarted: no pair
                raise PairTimeoutError(f"no stereo pair exposed after t={after_s:.3f} s: {err}") from err
            self.last_pair_time_s = max(frames.left.time_s, frames.right.time_s)
            return frames.left.image, frames.right.image


class ObservedHead(DriverHead):
    """`DriverHead` that says which phase of a fixation it is in, times vergence commands, and
    publishes saccade onset (the goals are on the bus) and saccade done (the head at rest)."""

    def __init__(self, *args: Any, events: EventHub | None = None, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.phase = "idle"
        self.events = events or EventHub()
        self.vergence_latency_s: collections.deque[float] = collections.deque(maxlen=2000)
        self._saccade: tuple[float, np.ndarray] | None = None  # (onset, goal) until at rest

    def pose_now(self, loop: ServoLoop) -> np.ndarray:
        """The pose of the loop's latest state, without waiting for a fresh one (API checks)."""
        state = loop.latest_state()
        if state is None:
            raise UnavailableError("no servo state read yet")
        return self.pose_from(state.positions)

    def move_to(self, pose: np.ndarray) -> np.ndarray:
        self.phase = "saccade"
        before = self.read_pose()
        goal = super().move_to(pose)
        self._saccade = (time.monotonic(), goal)
        self.events.publish("saccade_onset", pose_before=before, goal=goal)
        return goal

    def verge_to(self, vergence: float) -> float:
        self.phase = "fine vergence"
        v = super().verge_to(vergence)
        frame_s = getattr(self.pairs, "last_pair_time_s", None)
        if frame_s is not None:  # from the exposure of the pair it reacts to until the goal was on the bus
            self.vergence_latency_s.append(time.monotonic() - frame_s)
        return v

    def wait_settled(self, timeout_s: float) -> float:
        if self.phase in ("idle", "choosing target"):
            self.phase = "at rest"
        # "At goal" means at the goals the loop really writes: it may have replaced the ones
        # this head sent (a joint held after a hardware error, a hold on stale input, goals
        # dropped while the bus was down), and a goal no servo is driven to is never reached.
        loop = getattr(self.bus, "loop", None)
        if loop is not None:
            goals = loop.goals()
            self._goal = pose_of(goals) if all(j in goals for j in JOINTS) else None
        rest_s = super().wait_settled(timeout_s)
        if self._saccade is not None:
            onset_s, goal = self._saccade
            self._saccade = None
            self.events.publish("saccade_done", pose=self.read_pose(), goal=goal,
                                duration_s=rest_s - onset_s)
        return rest_s

    def wait_pair(self, after_s: float, timeout_s: float) -> tuple[np.ndarray, np.ndarray]:
        phase = self.phase
        self.phase = f"{phase}: waiting for frames" if ":" not in phase else phase
        try:
            return super().wait_pair(after_s, timeout_s)
        finally:
            self.phase = phase


# --- the fixation controller thread -----------------------------------------------------------
class FixationThread(threading.Thread):
    """Clients' looks first, else exploratory fixations (back to back or at `rate_hz`) while
    exploration is on; paused while the bus is down or torque is off."""

    SAME_VIEW_DEG = 0.25  # the head moved less than this on every axis: the same view

    def __init__(self, controller: FixationController, head: ObservedHead, adapter: MapAdapter,
                 loop: ServoLoop, interrupt: Interrupt, explore: bool = True, rate_hz: float = 0.0,
                 looks: LookQueue | None = None, events: EventHub | None = None) -> None:
        super().__init__(name="fixation", daemon=True)
        self.controller = controller
        self.head = head
        self.adapter = adapter
        self.loop = loop
        self.interrupt = interrupt
        self.abort = interrupt.stop
        self.explore = explore
        self.min_interval_s = 1.0 / rate_hz if rate_hz > 0 else 0.0
        self.looks = looks or LookQueue()
        self.events = events or head.events
        self.done = 0
        self.taught = 0
        self.refused: collections.Counter[str] = collections.Counter()
        self.last: FixationRecord | None = None
        self.landing_errors_px: collections.deque[float] = collections.deque(maxlen=200)  # target looks'
        self.error: BaseException | None = None
        self._lock = threading.Lock()

    def stop(self, timeout_s: float = 2.0) -> None:
        self.abort.set()
        join_thread(self, timeout_s)

    def counts(self) -> dict[str, Any]:
        with self._lock:
            return {"done": self.done, "taught": self.taught, "refused": dict(self.refused)}

    def paused_reason(self) -> str | None:
        if self.loop.down_reason is not None:
            return "servo bus down"
        if not self.loop.torque_enabled:
            return "torque off"
        return None

    def run(self) -> None:
        next_explore_s = 0.0
        try:
            while not self.abort.is_set():
                job = self.looks.take()
                if job is not None:
                    self._look(job)
                    continue
                paused = self.paused_reason()
                if paused is not None or not self.explore or time.monotonic() < next_explore_s:
                    self.head.phase = (f"paused ({paused})" if paused else
                                       "idle" if self.explore else "idle (exploration off)")
                    wait_s = 0.05 if paused or self.explore else 0.2
                    if self.explore and not paused:
                        wait_s = min(wait_s, next_explore_s - time.monotonic())
                    self.looks.wait_for_work(max(wait_s, 0.001))  # a look wakes it at once
                    continue
                started = time.monotonic()
                self._fixate(None)
                next_explore_s = started + self.min_interval_s
        except Exception as err:  # reported through the status, never lost
            self.error = err
            log.exception("%s: the fixation controller failed", self.name)
        finally:
            self.head.phase = "stopped"
            self.looks.cancel_all("the fixation controller stopped")

    def _fixate(self, target: np.ndarray | None, reference_pose: np.ndarray | None = None) -> FixationRecord:
        """One fixation, taught or refused; one aborted because the head failed under it is
        refused with that reason."""
        self.head.phase = "choosing target"
        try:
            record = self.controller.fixate(target, reference_pose)
        except (HeadctlError, DriverError) as err:
            if isinstance(err, ShutdownError):
                reason = REFUSED_SHUTDOWN
            elif isinstance(err, LookCancelledError):
                reason = REFUSED_CANCELLED
                log.info("%s", err)
            elif isinstance(err, (BusDownError, StaleStateError)):
                reason = REFUSED_BUS_DOWN
                log.info("fixation aborted: %s", err)
            else:  # a hardware error, a limit refused, torque off
                reason = REFUSED_SERVO_FAULT
                log.warning("fixation aborted: %s", err)
                self.abort.wait(0.2)
            record = FixationRecord(index=self.controller.count - 1, kind="explore" if target is None else "target",
                                    target=target, outcome=reason, detail=str(err))
        finally:
            self.head.phase = "idle"
        if record.taught:
            self.adapter.submit(Sample(record.position, record.executed, record.confidence, tag=record.index))
        self._count(record)
        return record

    def _look(self, job: LookJob) -> None:
        request = job.request
        self.events.publish("look_started", id=job.id, **request.as_dict())
        paused = self.paused_reason()
        try:
            if paused is not None:
                self.looks.finish(job, FAILED, paused, f"cannot look: {paused}")
            else:
                with self.interrupt.during(job):
                    if request.kind == "target":
                        self._look_at_target(job)
                    else:
                        self._look_at_angles(job)
        except BaseException as err:  # a client waiting on it hears of it before the thread reports it
            if not job.done.is_set():
                self.looks.finish(job, FAILED, "internal error", repr(err))
            raise
        finally:
            self.events.publish("look_done", id=job.id, state=job.state, outcome=job.outcome, detail=job.detail)

    def _look_at_target(self, job: LookJob) -> None:
        target = np.asarray(job.request.values, dtype=float)
        reference = job.request.reference_pose
        record = self._fixate(target, None if reference is None else np.asarray(reference))
        result: dict[str, Any] = {"converged": record.converged, "taught": record.taught,
                                  "vergence_steps": record.vergence_steps, "duration_s": record.duration_s,
                                  "pose_before": record.pose_before, "pose_after": record.pose_after,
                                  "planned": record.planned, "position": None, "confidence": None,
                                  "landing_error_px": None}
        moved = (None if reference is None or record.pose_before is None
                 else float(np.max(np.abs(record.pose_before - np.asarray(reference)))))
        result["head_moved_deg"] = moved
        if record.match is not None:
            result.update(position=record.position, confidence=record.confidence)
            # Where the head landed, in the image the target was chosen in: measurable only
            # when the pre-fixation images are that view (the head has not moved since).
            if moved is None or moved <= self.SAME_VIEW_DEG:
                landing = float(np.hypot(*(record.position[:2] - target[:2])))
                result["landing_error_px"] = landing
                self.landing_errors_px.append(landing)
        if record.outcome == REFUSED_CANCELLED:
            self.looks.finish(job, CANCELLED, job.cancel_outcome, job.cancel_detail, plain(result))
        else:
            self.looks.finish(job, DONE if record.converged else FAILED, record.outcome, record.detail,
                              plain(result))

    def _look_at_angles(self, job: LookJob) -> None:
        request = job.request
        self.head.phase = "look at angles"
        try:
            before = self.head.read_pose()
            goal = before + request.values if request.relative else np.asarray(request.values, dtype=float)
            outside = [f"{name} {value:.2f} outside [{lo:g}, {hi:g}]" for name, value, lo, hi in
                       zip(("pan", "tilt", "vergence"), goal, self.head.pose_low, self.head.pose_high)
                       if not lo - 1e-9 <= value <= hi + 1e-9]
            if outside:  # never clamped silently: the client asked for somewhere the head cannot go
                self.looks.finish(job, FAILED, "outside the joint limits", "; ".join(outside))
                return
            self.head.move_to(goal)
            self.head.wait_settled(self.controller.params.settle_timeout_s)
            after = self.head.read_pose()
        except LookCancelledError:
            self.looks.finish(job, CANCELLED, job.cancel_outcome, job.cancel_detail)
            return
        except (HeadctlError, DriverError, HeadTimeoutError) as err:
            self.looks.finish(job, FAILED, type(err).__name__, str(err))
            return
        finally:
            self.head.phase = "idle"
        self.looks.finish(job, DONE, "reached", "", plain({"pose_before": before, "pose_after": after,
                                                             "goal": goal}))

    def _count(self, record: FixationRecord) -> None:
        with self._lock:
            self.done += 1
            if record.taught:
                self.taught += 1
            else:
                self.refused[record.outcome] += 1
            self.last = record
        # One event a fixation: converged (taught, or refused after converging: the outcome
        # says why), or refused before converging.
        if record.converged:
            self.events.publish("fixation_converged", index=record.index, kind=record.kind, taught=record.taught,
                                outcome=record.outcome, detail=record.detail, confidence=record.confidence,
                                position=record.position)
        else:
            self.events.publish("fixation_refused", index=record.index, kind=record.kind, reason=record.outcome,
                                detail=record.detail)


class EventLog(logging.Handler):
    """The last warnings and errors of every module (bus down, hardware errors, reboots, camera
    faults), kept for `headctl status`: what the drivers recover from by themselves is still
    reported."""

    def __init__(self, size: int = 50) -> None:
        super().__init__(level=logging.WARNING)
        self.events: collections.deque[dict[str, Any]] = collections.deque(maxlen=size)
        self.counts: collections.Counter[str] = collections.Counter()

    def emit(self, record: logging.LogRecord) -> None:
        try:
            message = record.getMessage()
        except Exception:  # a bad format string must not break logging
            message = str(record.msg)
        self.counts[record.levelname] += 1
        self.events.append({"time": record.created, "level": record.levelname, "logger": record.name,
                            "message": message})


def _last_fixation(record: FixationRecord) -> dict[str, Any]:
    match = record.match
    return plain({"index": record.index, "kind": record.kind, "outcome": record.outcome, "detail": record.detail,
                  "duration_s": record.duration_s, "converged": record.converged,
                  "confidence": None if match is None else record.confidence,
                  "position": None if match is None else record.position,
                  "left": None if match is None else [match.left.x, match.left.y],
                  "right": None if match is None else [match.right.x, match.right.y]})


# --- persistence ---------------------------------------------------------------------------------
def restore_map(config: HeadConfig) -> tuple[GazeMap, str, list[str]]:
    """The saved map (or its .prev, or a fresh random one); where it came from; problems found.

    A corrupt or incompatible main file is moved aside to `<path>.bad` so the next checkpoint
    does not keep it as `.prev`.
    """
    path = config.map_path
    wanted = config.map_params()
    problems: list[str] = []
    moved_aside = False
    for candidate in (path, Path(f"{path}.prev")):
        if not candidate.exists():
            continue
        try:
            gm = GazeMap.load(candidate)
            if gm.params != wanted:
                raise MapFileError(f"{candidate}: saved for other map parameters (image size {gm.params.image_size}, "
                                   f"grid {gm.params.grid_shape}, profile {gm.params.profile}) than {config.path} sets")
        except MapFileError as err:
            log.error("gaze map: %s", err)
            problems.append(str(err))
            if candidate == path:
                os.replace(path, f"{path}.bad")
                moved_aside = True
            continue
        log.info("gaze map restored from %s (%d adaptations)", candidate, gm.adaptations)
        if moved_aside:
            gm.save(path, keep_previous=False)
        return gm, str(candidate), problems
    log.info("gaze map: none saved in %s; starting from a random map (seed %d)", config.state_dir,
             config.gaze_map.seed)
    return GazeMap(wanted, seed=config.gaze_map.seed), "new", problems


class Checkpointer:
    """Atomic map checkpoints every N adaptations (on the adapter thread) and at shutdown."""

    def __init__(self, adapter: MapAdapter, path: Path, every: int) -> None:
        self.adapter = adapter
        self.path = path
        self.every = every
        self.count = 0
        self.last_adaptations = -1
        self.last_time_s: float | None = None
        self.last_duration_s: float | None = None
        self.error: str | None = None
        self._lock = threading.Lock()

    def maybe(self, adaptations: int) -> None:
        if adaptations > 0 and adaptations % self.every == 0:
            self.save()

    def save(self) -> None:
        with self._lock:
            started = time.monotonic()
            try:
                adaptations = self.adapter.with_map(self._save_map)
            except OSError as err:
                self.error = f"{self.path}: checkpoint failed: {err}"
                log.error("%s", self.error)
                return
            self.error = None
            self.count += 1
            self.last_adaptations = int(adaptations)
            self.last_time_s = time.time()
            self.last_duration_s = time.monotonic() - started
            log.info("gaze map checkpoint %d: %s (%d adaptations, %.0f ms)", self.count, self.path,
                     adaptations, self.last_duration_s * 1e3)

    def _save_map(self, gm: GazeMap) -> int:
        gm.save(self.path)
        return gm.adaptations


def write_atomically(path: Path, text: str) -> None:
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_text(text, encoding="utf-8")
    os.replace(tmp, path)


class StateDirLock:
    """One daemon per state directory: an exclusive flock(2) on `headctl.lock`, released by the
    kernel however the process ends (a kill -9 leaves no stale lock)."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self._fd: int | None = None

    def __enter__(self) -> "StateDirLock":
        fd = os.open(self.path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = os.read(fd, 32).decode(errors="replace").strip() or "?"
            os.close(fd)
            raise HeadctlError(f"{self.path.parent}: another headctl daemon (pid {holder}) is running with "
                               "this state directory") from None
        os.ftruncate(fd, 0)
        os.write(fd, f"{os.getpid()}\n".encode())
        self._fd = fd
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        if self._fd is not None:
            os.close(self._fd)
            self._fd = None


# --- systemd --------------------------------------------------------------------------------
class SystemdNotifier:
    """sd_notify(3) without a dependency: one datagram to `$NOTIFY_SOCKET` per call.

    Written here rather than taken from the `sdnotify` package: the protocol is one `sendto`
    (abstract socket names start with '@'), and the watchdog interval comes from
    `$WATCHDOG_USEC`, which that package does not read.
    """

    def __init__(self, environ: Mapping[str, str] | None = None) -> None:
        env = os.environ if environ is None else environ
        address = env.get("NOTIFY_SOCKET", "")
        self.address = "\0" + address[1:] if address.startswith("@") else address
        usec = env.get("WATCHDOG_USEC", "")
        pid = env.get("WATCHDOG_PID", "")
        self.watchdog_s = int(usec) / 1e6 if usec.isdigit() and (not pid or pid == str(os.getpid())) else None
        self._sock: socket.socket | None = None
        if self.address:
            self._sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM | socket.SOCK_CLOEXEC)

    @property
    def enabled(self) -> bool:
        return self._sock is not None

    def notify(self, **fields: Any) -> None:
        if self._sock is None:
            return
        message = "\n".join(f"{k.upper()}={v}" for k, v in fields.items())
        try:
            self._sock.sendto(message.encode(), self.address)
        except OSError as err:
            log.warning("sd_notify to %s failed: %s", self.address.lstrip("\0"), err)

    def close(self) -> None:
        if self._sock is not None:
            self._sock.close()
            self._sock = None


# --- the daemon -------------------------------------------------------------------------------
class Daemon:
    """The service for one head; `run()` blocks until SIGTERM/SIGINT (or `request_stop()`)."""

    def __init__(self, config: HeadConfig) -> None:
        self.config = config
        self.stop_event = threading.Event()
        self.abort = threading.Event()
        self.started_s = time.monotonic()
        self.phase = "starting"
        self.bus: ServoBus | None = None
        self.cameras: dict[str, Camera] = {}
        self.pair: StereoPair | None = None
        self.loop: ServoLoop | None = None
        self.adapter: MapAdapter | None = None
        self.fixation: FixationThread | None = None
        self.head: ObservedHead | None = None
        self.checkpointer: Checkpointer | None = None
        self.map_source = ""
        self.map_problems: list[str] = []
        self.map_restored: dict[str, Any] = {}  # the restored map's learning figures
        self.adaptations_run = 0
        self.recent_output_errors: collections.deque[np.ndarray] = collections.deque(maxlen=10)
        self.camera_stalled: set[str] = set()  # simulated cameras stalled by fault injection
        self.camera_restarts: collections.Counter[str] = collections.Counter()
        self._camera_restart_s: dict[str, float] = {}
        self.notifier = SystemdNotifier()
        self.api_server: Any = None
        self.api_url: str | None = None
        self.events = EventLog()
        self.hub = EventHub()  # what clients stream: saccades, fixations, looks, faults
        self.looks = LookQueue(config.api.max_queued_looks)
        # The learning curves: one point an adaptation.
        self.learning_points: collections.deque[dict[str, Any]] = collections.deque(maxlen=5000)
        self._points_lock = threading.Lock()
        self._point_seq = 0  # the learning points' index: grows through a map reset or load
        self._faults_seen: set[str] = set()
        self._faults_lock = threading.Lock()

    # -- building ------------------------------------------------------------------------
    def _build_bus(self) -> ServoBus:
        if self.config.simulated:
            from drivers.sim_servo import SimulatedServoBus
            # The simulated head starts with the eyes slightly converged, as the experiments' rig.
            return SimulatedServoBus(self.config.servo_bus, initial_positions={
                "pan": 0.0, "tilt": 0.0, "left_eye": 5.0, "right_eye": -5.0})
        return create_servo_bus(self.config.servo_bus)

    def _camera_resources(self, bus: ServoBus) -> dict[str, dict[str, Any]]:
        cams = self.config.cameras
        if cams.left.backend != "sim":
            return {}
        from headctl.online import SimulatedHeadRig

        head = SimulatedHeadRig.geometry(int(cams.left.width), int(cams.left.height), cams.left.lens)

        def pose_source(side: str) -> Callable[[], dict[str, float]]:
            def pose() -> dict[str, float]:
                if side in self.camera_stalled:
                    raise CameraError(f"camera {side}: stalled (injected fault)")
                return {j: bus.true_position(j) for j in JOINTS}  # type: ignore[attr-defined]
            return pose

        return {side: {"head": head, "pose_source": pose_source(side)} for side in ("left", "right")}

    def _on_adapted(self, sample: Sample, result: AdaptResult) -> None:
        adaptations = self.adapter.progress.adaptations if self.adapter is not None else 0
        if result.accepted:
            self.adaptations_run += 1
            self.recent_output_errors.append(np.asarray(result.output_error, dtype=float))
            with self._points_lock:
                self._point_seq += 1
                self.learning_points.append(plain({
                    "n": self._point_seq, "adaptations": adaptations, "t": time.time(),
                    "retinal_error": result.retinal_error,
                    "output_error_deg": result.output_error, "confidence": sample.confidence}))
        if self.checkpointer is not None:
            self.checkpointer.maybe(adaptations)

    def learning_since(self, since: int = 0, limit: int = 5000) -> dict[str, Any]:
        """The learning-curve points after point `since` (at most `limit`, the newest) and the
        `since` to ask with next time."""
        with self._points_lock:
            points = [p for p in self.learning_points if p["n"] > since]
            newest = self._point_seq
        return {"next": newest, "points": points[-limit:] if limit > 0 else []}

    # -- state for `headctl status` ----------------------------------------------------------
    def faults(self) -> list[str]:
        return list(self.fault_items().values())

    def fault_items(self) -> dict[str, str]:
        """What is wrong now, by a key that stays the same while the fault lasts."""
        out: dict[str, str] = {}
        loop = self.loop
        now = time.monotonic()
        if loop is not None:
            if loop.down_reason is not None:
                out["servo_bus"] = f"servo bus down: {loop.down_reason}"
            for joint, meanings in loop.faults.items():
                out[f"servo:{joint}"] = f"{loop.bus.describe(joint)}: hardware error: {', '.join(meanings)} (joint held)"
            if loop.down_reason is None and now - loop.last_read_s > 0.5:
                out["servo_reads"] = f"servo reads failing for {now - loop.last_read_s:.1f} s: {loop.last_read_error}"
            if loop.error is not None:
                out["servo_loop"] = f"servo loop failed: {loop.error!r}"
            if loop.is_alive() and now - loop.last_cycle_s > 1.0:
                out["servo_loop_stall"] = f"servo loop stalled for {now - loop.last_cycle_s:.1f} s"
        for side, camera in self.cameras.items():
            latest = camera.latest()
            if camera.health.value != "streaming":
                out[f"camera:{side}"] = f"camera {side}: {camera.health.value} ({camera.last_error})"
            elif self.phase == "running" and (latest is None or now - latest.time_s > 1.0):
                age = "no frame yet" if latest is None else f"no frame for {now - latest.time_s:.1f} s"
                out[f"camera:{side}"] = f"camera {side}: stalled, {age} ({camera.last_error})"
        if self.fixation is not None and self.fixation.error is not None:
            out["fixation"] = f"fixation controller failed: {self.fixation.error!r}"
        if self.adapter is not None and self.adapter.error is not None:
            out["adapter"] = f"adapter: {self.adapter.error!r}"
        if self.checkpointer is not None and self.checkpointer.error:
            out["checkpoint"] = self.checkpointer.error
        api = self.api_server
        if api is not None and self.phase == "running" and (api.error is not None or not api.is_alive()):
            out["api"] = f"control API stopped: {api.error!r}"
        return out

    def _watch_faults(self) -> None:
        """A `fault` event when a fault appears, `fault_cleared` when it is gone: polled by the
        main thread, and called by the servo loop the moment its bus or a joint changes (a bus
        down for less than a poll is still reported)."""
        with self._faults_lock:
            items = self.fault_items()
            for key in items.keys() - self._faults_seen:
                self.hub.publish("fault", key=key, message=items[key])
            for key in self._faults_seen - items.keys():
                self.hub.publish("fault_cleared", key=key)
            self._faults_seen = set(items)

    def state(self) -> str:
        if self.phase != "running":
            return self.phase
        return "degraded" if self.faults() else "running"

    def status(self) -> dict[str, Any]:
        loop = self.loop
        joints: dict[str, Any] = {}
        state = loop.latest_state() if loop is not None else None
        goals = loop.goals() if loop is not None else {}
        if state is not None:
            for joint, js in state.joints.items():
                joints[joint] = {"position_deg": round(js.position, 4), "velocity_dps": round(js.velocity, 3),
                                 "moving": js.moving, "torque_on": js.torque_on, "goal_deg": goals.get(joint),
                                 "hardware_errors": list(js.hardware_errors),
                                 "temperature_c": js.temperature_c, "input_voltage_v": js.input_voltage_v}
        fix = self.fixation
        counts = fix.counts() if fix is not None else {"done": 0, "taught": 0, "refused": {}}
        last = fix.last if fix is not None else None
        pose = None
        if state is not None and self.head is not None:
            pose = dict(zip(("pan", "tilt", "vergence"), self.head.pose_from(state.positions).round(4).tolist()))
        learning: dict[str, Any] = {}
        if self.adapter is not None:
            # The published progress, not the map under its lock: a status reader (the API's
            # event loop) must never wait for an adaptation.
            progress = self.adapter.progress
            recent = list(progress.recent_retinal_errors)
            learning = {"adaptations": progress.adaptations,
                        "mean_retinal_error": float(np.mean(recent)) if recent else None,
                        "recent_retinal_errors": recent}
            outs = list(self.recent_output_errors)
            learning["output_error_deg"] = (np.mean(outs, axis=0).round(4).tolist() if outs else None)
            learning["adaptations_this_run"] = self.adaptations_run
            learning["queue_dropped"] = self.adapter.dropped
        cp = self.checkpointer
        cameras = {}
        for side, camera in self.cameras.items():
            latest = camera.latest()
            cameras[side] = {"name": camera.name, "health": camera.health.value, "stats": camera.stats(),
                             "restarts": self.camera_restarts[side],
                             "frame_age_s": None if latest is None else round(time.monotonic() - latest.time_s, 3),
                             "last_error": None if camera.last_error is None else str(camera.last_error)}
        latency = list(self.head.vergence_latency_s) if self.head is not None else []
        l50, l99 = _percentiles(latency, (50, 99))
        return {
            "state": self.state(),
            "pid": os.getpid(),
            "config": str(self.config.path),
            "uptime_s": round(time.monotonic() - self.started_s, 3),
            "faults": self.faults(),
            "api": self.api_url,
            "events_seq": self.hub.seq,
            "image_size": list(self.config.image_size),
            "joints": joints,
            "pose": pose,
            "torque": loop.torque_enabled if loop is not None else None,
            "servo_loop": loop.timing() if loop is not None else None,
            "fixation": {"state": self.head.phase if self.head is not None else self.phase,
                         "explore": fix.explore if fix is not None else self.config.fixation.explore, **counts,
                         "looks_queued": self.looks.pending(),
                         "last": None if last is None else _last_fixation(last),
                         "vergence_latency_ms": {"count": len(latency),
                                                 "p50": None if l50 is None else round(l50 * 1e3, 3),
                                                 "p99": None if l99 is None else round(l99 * 1e3, 3)}},
            "learning": learning,
            "map": {"path": str(self.config.map_path), "restored_from": self.map_source,
                    "restored": self.map_restored, "problems": self.map_problems,
                    "checkpoints": cp.count if cp else 0,
                    "last_checkpoint_adaptations": cp.last_adaptations if cp else None,
                    "last_checkpoint_ms": (None if not cp or cp.last_duration_s is None
                                           else round(cp.last_duration_s * 1e3, 1))},
            "cameras": cameras,
            "events": list(self.events.events),
            "event_counts": dict(self.events.counts),
        }

    # -- fault injection (simulated head only, for tests and demonstrations) ----------------------
    def inject(self, fault: str, joint: str | None = None, camera: str | None = None,
               bits: int = 0) -> str:
        from drivers.sim_servo import SimulatedServoBus

        bus = self.bus
        if not isinstance(bus, SimulatedServoBus):
            raise HeadctlError("fault injection needs the simulated head (servo_bus.backend: sim)")
        if fault == "bus_down":
            bus.inject_bus_down()
        elif fault == "restore_bus":
            bus.restore_bus()
        elif fault == "hardware_error":
            if joint not in JOINTS:
                raise HeadctlError(f"hardware_error needs joint: one of {', '.join(JOINTS)}, got {joint!r}")
            bus.inject_hardware_error(joint, bits or 0b0010_0000)
        elif fault in ("camera_stall", "camera_resume"):
            if camera not in ("left", "right"):
                raise HeadctlError(f"{fault} needs camera: left or right, got {camera!r}")
            (self.camera_stalled.add if fault == "camera_stall" else self.camera_stalled.discard)(camera)
        else:
            raise HeadctlError(f"unknown fault {fault!r}: expected bus_down, restore_bus, hardware_error, "
                               "camera_stall, camera_resume")
        log.warning("injected fault: %s %s", fault, joint or camera or "")
        return fault

    # -- control: what the API asks (thread-safe; ControlError names the field at fault) ----------
    def _running_parts(self) -> tuple[ServoLoop, FixationThread, MapAdapter, ObservedHead]:
        loop, fix, adapter, head = self.loop, self.fixation, self.adapter, self.head
        if self.phase != "running" or loop is None or fix is None or adapter is None or head is None:
            raise UnavailableError(f"the daemon is {self.phase}, not running")
        return loop, fix, adapter, head

    def look(self, request: LookRequest, replace: bool = False) -> LookJob:
        """Queue a look after checking it against the image, the map and the joint limits."""
        loop, _, adapter, head = self._running_parts()
        if request.kind == "target":
            width, height = self.config.image_size
            d_low, d_high = adapter.map.params.disparity_range
            x, y, d = request.values
            checks = [("x", x, 0, width - 1, "the image's columns"), ("y", y, 0, height - 1, "the image's rows")]
            for name, value, low, high, what in checks:
                if not low <= value <= high:
                    raise InvalidRequestError(f"{name} = {value:g} is outside {what}, [{low:g}, {high:g}]", name)
            if d is None:  # sent without a disparity: measured where the client pointed
                d, ncc = self.measure_disparity(x, y)
                request = dataclasses.replace(request, values=(x, y, d), d_ncc=ncc)
            if not d_low <= d <= d_high:
                raise InvalidRequestError(f"d = {d:g} is outside the map's disparity range "
                                          f"(gaze_map.disparity_range), [{d_low:g}, {d_high:g}]", "d")
            # The target is in the view of the pose now; the head may move before the look runs.
            request = dataclasses.replace(request, reference_pose=tuple(head.pose_now(loop).tolist()))
        else:
            pose = head.pose_now(loop) if request.relative else np.zeros(3)
            goal = pose + np.asarray(request.values, dtype=float)
            for i, name in enumerate(("pan", "tilt", "vergence")):
                low, high = head.pose_low[i], head.pose_high[i]
                if not low - 1e-9 <= goal[i] <= high + 1e-9:
                    where = f"{pose[i]:.2f} + {request.values[i]:g} = {goal[i]:.2f}" if request.relative \
                        else f"{goal[i]:g}"
                    raise InvalidRequestError(f"{name}: {where} deg is outside the limits [{low:g}, {high:g}] deg "
                                       "(servo_bus.joints, fixation.vergence_range)", name)
        job = self.looks.submit(request, replace=replace)
        log.info("look %d queued: %s", job.id, request.as_dict())
        return job

    def measure_disparity(self, x: float, y: float) -> tuple[float, float]:
        """The disparity (px, x_right - x_left) at (x, y) of the left image in the latest stereo
        pair, and the NCC of the match: where the patch around it lies in the right image, along
        the same rows, within the map's disparity range (what fine vergence measures at the
        fovea, measured off-centre)."""
        _, fix, adapter, _ = self._running_parts()
        pair = self.pair.latest() if self.pair is not None else None
        age_s = None if pair is None else time.monotonic() - min(pair.left.time_s, pair.right.time_s)
        if age_s is None or age_s > PAIR_MAX_AGE_S:
            raise UnavailableError(f"d: no stereo pair from the last {PAIR_MAX_AGE_S:g} s to measure the "
                                   f"disparity at ({x:g}, {y:g}) in; send d", "d")
        params = fix.controller.params
        d, ncc = horizontal_offset(as_grey_float(pair.left.image), as_grey_float(pair.right.image), (x, y),
                                   params.vergence_patch_size, adapter.map.params.disparity_range)
        if ncc < MIN_DISPARITY_NCC:
            raise InvalidRequestError(
                f"d: the disparity at ({x:g}, {y:g}) could not be measured (the best match in the right image "
                f"scores NCC {ncc:.2f} < {MIN_DISPARITY_NCC}: too near the border, no texture there, or "
                "seen by one eye only); send d", "d")
        return d, ncc

    def set_exploration(self, enabled: bool) -> bool:
        _, fix, _, _ = self._running_parts()
        if fix.explore != enabled:
            fix.explore = enabled
            log.info("exploration %s (requested)", "on" if enabled else "off")
            self.hub.publish("exploration", enabled=enabled)
        return fix.explore

    def set_torque(self, enabled: bool) -> bool:
        loop, _, _, _ = self._running_parts()
        if loop.down_reason is not None:
            raise UnavailableError(f"servo bus down ({loop.down_reason}): torque cannot be switched now")
        try:
            loop.set_torque(enabled)
        except DriverError as err:
            raise ControlError(f"torque {'on' if enabled else 'off'} failed: {err}", "enabled") from err
        self.hub.publish("torque", enabled=enabled)
        return enabled

    def _map_path(self, name: str | None) -> Path:
        if name is None:
            return self.config.map_path
        if not MAP_NAME.fullmatch(name):
            raise InvalidRequestError(f"name {name!r}: expected a file name in the state directory, such as "
                               "'before-lens-swap.npz' (letters, digits, . _ -; ending .npz)", "name")
        return self.config.state_dir / name

    def save_map(self, name: str | None = None) -> dict[str, Any]:
        """Save the map (default: the checkpoint file, atomically, keeping .prev)."""
        _, _, adapter, _ = self._running_parts()
        path = self._map_path(name)
        if name is None and self.checkpointer is not None:
            self.checkpointer.save()
            if self.checkpointer.error:
                raise ControlError(self.checkpointer.error, "name")
            adaptations = self.checkpointer.last_adaptations
        else:
            try:
                adaptations = adapter.with_map(lambda gm: (gm.save(path), gm.adaptations)[1])
            except OSError as err:
                raise ControlError(f"{path}: cannot save: {err}", "name") from err
        self.hub.publish("map", action="saved", path=str(path), adaptations=adaptations)
        return {"path": str(path), "adaptations": adaptations}

    def load_map(self, name: str | None = None) -> dict[str, Any]:
        """Replace the map being learned by a saved one (made for the same map parameters)."""
        _, _, adapter, _ = self._running_parts()
        path = self._map_path(name)
        if not path.exists():
            raise NotFoundError(f"{path}: no such map file", "name")
        try:
            gm = GazeMap.load(path)
        except MapFileError as err:
            raise ControlError(str(err), "name") from err
        if gm.params != self.config.map_params():
            raise ControlError(f"{path}: saved for other map parameters (image size {gm.params.image_size}, "
                               f"grid {gm.params.grid_shape}, profile {gm.params.profile}) than this head's",
                               "name")
        adapter.replace_map(gm)
        log.warning("gaze map replaced by %s (%d adaptations)", path, gm.adaptations)
        self.hub.publish("map", action="loaded", path=str(path), adaptations=gm.adaptations)
        return {"path": str(path), "adaptations": gm.adaptations}

    def reset_map(self, seed: int | None = None) -> dict[str, Any]:
        """Start learning again from a random map; the map before is saved as `before-reset.npz`."""
        _, _, adapter, _ = self._running_parts()
        backup = self.config.state_dir / "before-reset.npz"
        adapter.with_map(lambda gm: gm.save(backup, keep_previous=False))
        seed = self.config.gaze_map.seed if seed is None else seed
        adapter.replace_map(GazeMap(self.config.map_params(), seed=seed))
        log.warning("gaze map reset to a random map (seed %d); the previous one is in %s", seed, backup)
        self.hub.publish("map", action="reset", seed=seed, backup=str(backup), adaptations=0)
        return {"path": str(self.config.map_path), "adaptations": 0, "backup": str(backup)}

    # -- running -----------------------------------------------------------------------------------
    def request_stop(self, signum: int | None = None, frame: Any = None) -> None:
        if signum is not None:
            log.info("signal %s: stopping", signal.Signals(signum).name)
        self.stop_event.set()

    def run(self, install_signals: bool = True) -> int:
        from headctl.api import ApiServer

        cfg = self.config
        # A thread waiting for the GIL gets it after this long (CPython's default is 5 ms): the
        # servo loop's timer would otherwise wait behind Python-level work of the other threads.
        sys.setswitchinterval(cfg.service.switch_interval_ms / 1000.0)
        if install_signals:
            signal.signal(signal.SIGTERM, self.request_stop)
            signal.signal(signal.SIGINT, self.request_stop)
        cfg.state_dir.mkdir(parents=True, exist_ok=True)
        with contextlib.ExitStack() as stack:
            stack.callback(self.notifier.close)
            logging.getLogger().addHandler(self.events)
            stack.callback(logging.getLogger().removeHandler, self.events)
            stack.enter_context(StateDirLock(cfg.lock_path))
            if cfg.api.enabled:
                self.api_server = stack.enter_context(ApiServer(
                    self, cfg.api.host, cfg.api.port, cfg.api.token, cfg.api.stream_fps, cfg.api.jpeg_quality,
                    cfg.api.tls_cert, cfg.api.tls_key))
                if not cfg.api.tls_cert and not is_loopback(cfg.api.host):
                    log.warning("api: %s is served without TLS: the token crosses the network in clear text "
                                "(set api.tls_cert and api.tls_key, or reach it through an SSH tunnel)",
                                cfg.api.host)
                self.api_url = self.api_server.url
                write_atomically(cfg.api_url_path, self.api_url + "\n")
                stack.callback(cfg.api_url_path.unlink, missing_ok=True)
            self.notifier.notify(status="starting: restoring the gaze map")
            gm, self.map_source, self.map_problems = restore_map(cfg)
            self.map_restored = {"adaptations": gm.adaptations, "recent_retinal_errors": list(gm.recent_errors)}
            self.notifier.notify(status="starting: compiling the gaze map's inner loops")
            compile_s = gm.warm_up()
            (log.info if compile_s > 1.0 else log.debug)("gaze map inner loops ready in %.1f s", compile_s)
            bus = self.bus = self._build_bus()
            stack.callback(self._close_bus)
            bus.open()
            bus.enable()
            resources = self._camera_resources(bus)
            for side in ("left", "right"):
                camera = create_camera(getattr(cfg.cameras, side), name=side, key_path=f"cameras.{side}",
                                       **resources.get(side, {}))
                self.cameras[side] = stack.enter_context(camera)
            self.pair = stack.enter_context(StereoPair(self.cameras["left"], self.cameras["right"],
                                                       cfg.cameras.tolerance_s))
            for camera in self.cameras.values():
                camera.enable()
            self.loop = ServoLoop(bus, cfg.service.servo_rate_hz, cfg.service.input_timeout_s,
                                  realtime_priority=cfg.service.realtime_priority, on_fault_change=self._watch_faults)
            self.loop.start()
            stack.callback(self.loop.stop)
            self.adapter = MapAdapter(gm, on_adapted=self._on_adapted)
            self.checkpointer = Checkpointer(self.adapter, cfg.map_path, cfg.service.checkpoint_every)
            self.adapter.start()
            stack.callback(self.adapter.stop)
            interrupt = Interrupt(self.abort)
            self.head = ObservedHead(LoopBus(self.loop, interrupt), AbortablePairSource(self.pair, interrupt),
                                     clock=bus.clock, vergence_range=cfg.fixation.vergence_range, events=self.hub)
            controller = FixationController(self.head, self.adapter, cfg.fixation.params,
                                            seed=None if not cfg.simulated else cfg.gaze_map.seed)
            self.fixation = FixationThread(controller, self.head, self.adapter, self.loop, interrupt,
                                           cfg.fixation.explore, cfg.fixation.rate_hz, looks=self.looks,
                                           events=self.hub)
            self.fixation.start()
            stack.callback(self.fixation.stop)
            self.phase = "running"
            log.info("headctl running: %s, state in %s, API %s", cfg.path, cfg.state_dir,
                     self.api_url or "off (api.enabled: false)")
            self.notifier.notify(ready=1, status=self._status_line())
            self._supervise()
            self._shutdown()
        log.info("headctl stopped")
        return 0

    def _status_line(self) -> str:
        fix = self.fixation.counts() if self.fixation is not None else {"done": 0, "taught": 0}
        faults = self.faults()
        adaptations = self.adapter.progress.adaptations if self.adapter is not None else 0
        line = f"{self.state()}: {fix['done']} fixations, {fix['taught']} taught, {adaptations} adaptations"
        return line + (f"; {faults[0]}" if faults else "")

    def _supervise(self) -> None:
        """The main thread: systemd STATUS and WATCHDOG until asked to stop."""
        watchdog_s = self.notifier.watchdog_s
        interval_s = min(0.25, watchdog_s / 3) if watchdog_s else 0.25  # faults reach clients this fast
        last_line, last_line_s = "", -math.inf
        while not self.stop_event.wait(interval_s):
            line = self._status_line()
            fields: dict[str, Any] = {}
            if line != last_line and time.monotonic() - last_line_s >= 1.0:
                fields["status"] = line
                last_line, last_line_s = line, time.monotonic()
            loop = self.loop
            # Only a live servo loop keeps systemd from restarting the service.
            if watchdog_s and loop is not None and loop.is_alive() and time.monotonic() - loop.last_cycle_s < 1.0:
                fields["watchdog"] = 1
            if fields:
                self.notifier.notify(**fields)
            self._watch_faults()
            self._watch_cameras()

    def _watch_cameras(self) -> None:
        """Restart the stream of a camera that failed or has sent nothing for `camera_stall_s`
        (the backends reopen a lost device themselves; this covers a silent stall and a stream
        that gave up), at most once per `camera_stall_s` per camera."""
        stall_s = self.config.service.camera_stall_s
        now = time.monotonic()
        for side, camera in self.cameras.items():
            latest = camera.latest()
            age = now - (latest.time_s if latest is not None else self.started_s)
            failed = camera.health is StreamHealth.FAILED
            if not (failed or age > stall_s) or now - self._camera_restart_s.get(side, -math.inf) < stall_s:
                continue
            self._camera_restart_s[side] = now
            self.camera_restarts[side] += 1
            log.warning("camera %s: %s; restarting its stream (restart %d)", side,
                        "the stream failed" if failed else f"no frame for {age:.1f} s", self.camera_restarts[side])
            try:
                camera.disable()
                camera.enable()
            except (DriverError, OSError) as err:
                log.error("camera %s: restart failed: %s", side, err)

    def _shutdown(self) -> None:
        started = time.monotonic()
        self.phase = "stopping"
        self.notifier.notify(stopping=1, status="stopping: finishing the fixation, saving the gaze map")
        budget = self.config.service.shutdown_timeout_s
        if self.fixation is not None:
            self.fixation.stop(timeout_s=min(2.0, budget / 2))
        if self.adapter is not None:
            self.adapter.wait_idle(timeout_s=0.5)
            self.adapter.stop(timeout_s=0.5)
        if self.checkpointer is not None:
            self.checkpointer.save()
        self._safe_state()
        log.info("shutdown took %.2f s", time.monotonic() - started)

    def _safe_state(self) -> None:
        loop, bus = self.loop, self.bus
        if loop is not None:
            state = loop.latest_state()
            if state is not None and loop.down_reason is None and loop.is_alive():
                try:
                    loop.request_goals({j: state[j].position for j in JOINTS if state[j].torque_on}, timeout_s=0.5)
                except (DriverError, HeadctlError) as err:
                    log.warning("could not hold the present position at shutdown: %s", err)
            loop.stop()
        if bus is not None and self.config.service.safe_state == "torque_off":
            try:
                bus.disable()
            except DriverError as err:
                log.warning("could not turn torque off at shutdown: %s", err)

    def _close_bus(self) -> None:
        if self.bus is not None:
            self.bus.close()
