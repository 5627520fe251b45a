"""The servo I/O thread: at a fixed rate (default 100 Hz) one `read_state()` and one
`write_goals()` of the latest goals; the only user of the bus while the service runs.

Goals outside the limits are clamped or refused by the bus itself. When the controller falls
silent for `input_timeout_s` the loop holds the present position; while the bus is down it
writes nothing. `ServoLoop` is also what the head sees as its bus (`headctl.service.head.JointBus`):
`read_state()` gives the first state read after the call, `write_goals()` returns once the
loop has written the goals (as the bus clamped them) or raises the bus's error.
"""
from __future__ import annotations

import collections
import logging
import os
import threading
from typing import Callable, Iterable, Mapping, Protocol, Self, TypeVar, cast

import numpy as np

from drivers.clock import SYSTEM_CLOCK, Clock
from drivers.errors import BusDownError, DriverError, JointLimitError, ServoCommError, ServoHardwareError
from drivers.servo.bus import BusState, ServoBus
from drivers.servo.faults import HardwareErrorEpisode
from headctl.errors import ServoLoopStoppedError, StaleStateError

log = logging.getLogger(__name__)

T = TypeVar("T")

# A period longer than this many nominal periods counts as long (12 ms at 100 Hz): a goal written
# that much late is a servo holding a stale goal while the controller thinks it moved.
LONG_PERIOD = 1.2


class ServoIO(Protocol):
    """What the service reads and asks of its servo loop, in a thread (`ServoLoop`) or in a
    process of its own (`headctl.service.servo_io.process.ServoLoopProcess`)."""

    @property
    def down_reason(self) -> str | None: ...

    @property
    def faults(self) -> dict[str, tuple[str, ...]]: ...

    @property
    def missing(self) -> dict[str, str]:
        """The joints whose servo does not answer, each with its description (`BusState.missing`)."""
        ...

    @property
    def last_read_error(self) -> str: ...

    @property
    def error(self) -> BaseException | None: ...

    @property
    def last_read_s(self) -> float: ...

    @property
    def last_cycle_s(self) -> float: ...

    @property
    def torque_enabled(self) -> bool: ...

    def is_alive(self) -> bool: ...

    def latest_state(self) -> BusState | None: ...

    def fresh_state(self, timeout_s: float = 1.0) -> BusState: ...

    def read_state(self) -> BusState: ...

    def write_goals(self, goals: Mapping[str, float]) -> dict[str, float]: ...

    def request_goals(self, goals: Mapping[str, float], timeout_s: float = 1.0) -> dict[str, float]: ...

    def goals(self) -> dict[str, float]: ...

    def set_torque(self, on: bool, timeout_s: float = 2.0) -> None: ...

    def timing(self) -> dict[str, float | None]: ...

    def describe(self, joint: str) -> str: ...

    def fault_records(self, since: int) -> tuple[HardwareErrorEpisode, ...]:
        """The bus's hardware-error records after `since` (`drivers.servo.faults`)."""


def period_quantiles(periods_s: np.ndarray, nominal_s: float) -> dict[str, float | None]:
    """p50, p99 and max of the periods and of |period - nominal|, in ms (None without periods)."""
    quantiles: dict[str, float | None] = {}
    for name, values in (("period", periods_s), ("jitter", np.abs(periods_s - nominal_s))):
        qs = np.quantile(values, (0.5, 0.99, 1.0)) if len(values) else (None, None, None)
        for label, q in zip(("p50", "p99", "max"), qs):
            quantiles[f"{name}_{label}_ms"] = None if q is None else round(float(q) * 1e3, 3)
    return quantiles


def missing_error(name: str, missing: Mapping[str, str], joints: Iterable[str] | None = None) -> ServoCommError:
    """What a command naming a missing joint (`joints`: the ones it names), or a read of the
    whole head (`joints` None), fails with."""
    named = set(missing) if joints is None else set(joints) & set(missing)
    return ServoCommError(f"{name}: servo missing: {'; '.join(missing[j] for j in missing if j in named)}"
                          + ("" if joints is None else "; nothing sent"))


def complete(state: BusState, name: str) -> BusState:
    """`state` if every joint answered, else the error naming the missing ones: what the head
    and the tracker read (a pose needs all four joints)."""
    if state.missing:
        raise missing_error(name, state.missing)
    return state


def join_thread(thread: threading.Thread, timeout_s: float) -> None:
    """Wait for a thread asked to stop (not from itself); a warning if it does not."""
    if thread.is_alive() and threading.current_thread() is not thread:
        thread.join(timeout_s)
        if thread.is_alive():
            log.warning("%s did not stop within %.1f s", thread.name, timeout_s)


class _Pending:
    """Something waiting for the loop's thread: done once it ran (`error` if it failed), then
    `callback(self)` on that thread."""

    def __init__(self, callback: Callable[[Self], None] | None) -> None:
        self.done = threading.Event()
        self.error: BaseException | None = None
        self.callback: Callable[[Self], None] | None = callback

    def finish(self: Self) -> None:
        self.done.set()
        if self.callback is not None:
            self.callback(self)


class _WriteRequest(_Pending):
    """Goals for the next cycle to write; `sent`: what the bus sent (clamped)."""

    def __init__(self, goals: Mapping[str, float],
                 callback: Callable[["_WriteRequest"], None] | None = None) -> None:
        super().__init__(callback)
        self.goals = dict(goals)
        self.sent: dict[str, float] | None = None


class _LoopAction(_Pending):
    """A call to run on the loop thread between two cycles (the bus has one user)."""

    def __init__(self, fn: Callable[[ServoBus], object], callback: Callable[[_LoopAction], None] | None = None,
                 ) -> None:
        super().__init__(callback)
        self.fn = fn
        self.result: object = None  # fn's, once done without error


class ServoLoop(threading.Thread):
    """One read and one write per cycle at a fixed rate; the bus's only user while it runs.

    The thread calls `step()` once a period; a test on a `ManualClock` may call it itself
    instead of starting the thread. A joint whose servo reports a hardware error is held at
    its present position until the error clears (the bus's recovery policy decides on
    reboots, `drivers.servo.recovery`).
    """

    def __init__(self, bus: ServoBus, rate_hz: float = 100.0, input_timeout_s: float = 0.5,
                 history: int = 6000, realtime_priority: int = 0,
                 on_fault_change: Callable[[], None] | None = None, clock: Clock = SYSTEM_CLOCK) -> None:
        super().__init__(name="servo-io", daemon=True)
        self.bus = bus
        self.clock = clock
        self.on_fault_change = on_fault_change  # the bus went down or came back, a joint faulted or cleared
        self.realtime_priority = realtime_priority
        self.period_s = 1.0 / rate_hz
        self.input_timeout_s = input_timeout_s
        self._stop_event = threading.Event()
        # Called on the loop's thread before and after each cycle (a servo process exchanges
        # requests and the published state there).
        self.before_cycle: Callable[[], None] | None = None
        self.after_cycle: Callable[[], None] | None = None
        self._cond = threading.Condition()
        self._state: BusState | None = None
        self._state_seq = 0
        self._goals: dict[str, float] = {}  # the latest-value slot: what each cycle writes
        self._requests: list[_WriteRequest] = []
        self._last_input_s = self.clock.monotonic()
        self._holding = False
        self.down_reason: str | None = None
        self.faults: dict[str, tuple[str, ...]] = {}
        self.missing: dict[str, str] = {}  # joint -> its description, as the last state named them
        self.error: BaseException | None = None
        self._fault_since: dict[str, float] = {}  # faulted joints held, since when
        self.read_errors = 0
        self.write_errors = 0
        self.bus_down_count = 0
        self.last_read_error = ""
        self._read_failing = False
        self.torque_enabled = True  # as the daemon enabled the bus; `set_torque` changes it
        self._actions: list[_LoopAction] = []
        self.last_read_s = self.clock.monotonic()
        self.cycles = 0
        self.overruns = 0
        self.long_periods = 0  # periods longer than LONG_PERIOD times the nominal one, since the start
        self.periods_s: collections.deque[float] = collections.deque(maxlen=history)
        self._timing_cache: tuple[float, dict[str, float | None]] | None = None
        self.last_cycle_s = self.clock.monotonic()

    # -- what the controller calls (through LoopBus) ----------------------------------------
    @property
    def power_losses(self) -> int:
        """Times the bus found its servos had lost power and initialised them again."""
        return self.bus.power_losses

    def touch(self) -> None:
        self._last_input_s = self.clock.monotonic()

    def touch_at(self, at_s: float) -> None:
        """The controller was last heard of at `at_s` (a servo process's heartbeat)."""
        if at_s > self._last_input_s:
            self._last_input_s = at_s

    @property
    def state_seq(self) -> int:
        """How many states the loop has read."""
        return self._state_seq

    def fresh_state(self, timeout_s: float = 1.0) -> BusState:
        """The first state read after this call."""
        self.touch()
        deadline = self.clock.monotonic() + timeout_s
        with self._cond:
            seq = self._state_seq
            while self._state_seq == seq:
                remaining = deadline - self.clock.monotonic()
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

    def post_goals(self, goals: Mapping[str, float], callback: Callable[[_WriteRequest], None]) -> None:
        """Have the next cycle write `goals` without waiting: `callback(request)` on the loop's
        thread once written (`request.sent`) or refused (`request.error`)."""
        self.touch()
        request = _WriteRequest(goals, callback)
        with self._cond:
            if self.down_reason is None:
                self._requests.append(request)
                return
        request.error = BusDownError(f"{self.bus.name}: {self.down_reason}")
        request.finish()

    def post_call(self, fn: Callable[[ServoBus], object], callback: Callable[[_LoopAction], None]) -> None:
        """Run `fn(bus)` before the next cycle without waiting: `callback(action)` once done."""
        with self._cond:
            self._actions.append(_LoopAction(fn, callback))

    def describe(self, joint: str) -> str:
        return self.bus.describe(joint)

    def fault_records(self, since: int) -> tuple[HardwareErrorEpisode, ...]:
        return self.bus.fault_log.since(since)

    def goals(self) -> dict[str, float]:
        with self._cond:
            return dict(self._goals)

    def call(self, fn: Callable[[ServoBus], T], timeout_s: float = 2.0) -> T:
        """Run `fn(bus)` on the loop thread before its next cycle; its result, or its error."""
        action = _LoopAction(fn)
        with self._cond:
            if not self.is_alive():
                raise ServoLoopStoppedError(f"{self.name}: the servo loop is not running")
            self._actions.append(action)
        if not action.done.wait(timeout_s):
            raise StaleStateError(f"{self.bus.name}: the servo loop did not get to it within {timeout_s} s")
        if action.error is not None:
            raise action.error
        return cast(T, action.result)

    def torque_switch(self, on: bool) -> Callable[[ServoBus], None]:
        """The action that switches torque on (each goal set to the present position first: no
        jump) or off on all joints, emptying the goal slot so no earlier goal is written after."""
        def switch(bus: ServoBus) -> None:
            bus.enable() if on else bus.disable()
            with self._cond:
                self._goals = {}
            self.torque_enabled = on
            log.warning("%s: torque %s on all joints (requested)", self.name, "on" if on else "off")
        return switch

    def set_torque(self, on: bool, timeout_s: float = 2.0) -> None:
        self.call(self.torque_switch(on), timeout_s)

    @property
    def stopping(self) -> bool:
        """Whether it was asked to stop (a thread that ended then did not fail)."""
        return self._stop_event.is_set()

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
        next_s = self.clock.monotonic()
        previous_s: float | None = None
        try:
            while not self._stop_event.is_set():
                started = self.clock.monotonic()
                if previous_s is not None:
                    period_s = started - previous_s
                    self.periods_s.append(period_s)
                    if period_s > LONG_PERIOD * self.period_s:
                        self.long_periods += 1
                previous_s = started
                self.step()
                next_s += self.period_s
                delay = next_s - self.clock.monotonic()
                if delay < 0:
                    self.overruns += 1
                    next_s = self.clock.monotonic()  # no burst of catch-up cycles
                # Always yield a little: at realtime priority a loop that never waits would
                # starve every other thread of its CPU.
                self._stop_event.wait(max(delay, 0.1 * self.period_s))
        except Exception as err:  # reported through the status, never lost
            self.error = err
            log.exception("%s: the servo loop failed", self.name)
        finally:
            with self._cond:
                stopped = ServoLoopStoppedError(f"{self.name}: the servo loop stopped")
                waiting: list[_Pending] = [*self._requests, *self._actions]
                for pending in waiting:
                    pending.error = stopped
                    pending.finish()
                self._requests.clear()
                self._actions.clear()
                self._cond.notify_all()

    def step(self) -> None:
        """One cycle: the calls waiting for the bus, one read, one write."""
        if self.before_cycle is not None:
            self.before_cycle()
        self._run_actions()
        self._cycle()
        self.cycles += 1
        self.last_cycle_s = self.clock.monotonic()
        if self.after_cycle is not None:
            self.after_cycle()

    def _run_actions(self) -> None:
        with self._cond:
            actions, self._actions = self._actions, []
        for action in actions:
            try:
                action.result = action.fn(self.bus)
            except Exception as err:  # the caller gets it
                action.error = err
            action.finish()

    def _cycle(self) -> None:
        try:
            state = self.bus.read_state()
        except BusDownError as err:
            self._went_down(str(err))
            return
        except DriverError as err:  # a failed read: nothing is written on a stale state
            self.read_errors += 1
            self.last_read_error = str(err)
            tell = not self._read_failing or self.read_errors % 100 == 1
            self._read_failing = True
            if self.read_errors % 100 == 1:  # at 100 Hz a persistent fault would drown the log
                log.warning("%s: read failed (%d so far): %s", self.name, self.read_errors, err)
            self._fail_requests(err)
            if tell:  # the reason, for the status (across the process boundary too), not every cycle
                self._fault_changed()
            return
        self._read_failing = False
        self.last_read_s = self.clock.monotonic()
        if self.torque_enabled and not self.bus.is_enabled:  # servo_bus.power_loss_torque: off
            log.warning("%s: torque off after a power loss; goals dropped until torque is switched on", self.name)
            self.torque_enabled = False
            with self._cond:
                self._goals = {}
        if self.down_reason is not None:
            log.warning("%s: servo bus back; motion resumes", self.name)
            self.down_reason = None
            with self._cond:
                self._goals = {}  # the bus restored torque at the positions read back
            self._fault_changed()
        faults, missing = state.faults, dict(state.missing)
        now = self.clock.monotonic()
        with self._cond:
            for joint in set(missing) | set(self.missing):
                self._goals.pop(joint, None)  # missing, or back with goal := present (the bus did it)
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
            changed = set(faults) != set(self.faults) or set(missing) != set(self.missing)
            self.faults, self.missing = faults, missing
            self._state = state
            self._state_seq += 1
            requests, self._requests = self._requests, []
            self._cond.notify_all()
        stale = self.clock.monotonic() - self._last_input_s > self.input_timeout_s
        if stale and not self._holding and self._goals:
            log.info("%s: no input for %.2f s: holding the present position", self.name, self.input_timeout_s)
            with self._cond:
                self._goals = {j: state[j].position for j in self._goals if j in state.joints}
        self._holding = stale
        self._write(state, requests)
        if changed:
            self._fault_changed()

    def _fault_changed(self) -> None:
        if self.on_fault_change is not None:
            try:
                self.on_fault_change()
            except Exception:  # a listener must not stop the servo loop
                log.exception("%s: fault listener failed", self.name)

    def _write(self, state: BusState, requests: list[_WriteRequest]) -> None:
        with self._cond:
            for request in requests:
                if any(j in self.missing for j in request.goals):  # the others hold where they are
                    request.error = missing_error(self.bus.name, self.missing, request.goals)
                    request.finish()
                    continue
                held = [j for j in request.goals if j in self.faults]
                if held:  # a faulted joint keeps its hold; the command fails as a whole
                    request.error = ServoHardwareError(
                        f"{self.bus.name}: {', '.join(self.bus.describe(j) for j in held)} held after a hardware "
                        f"error ({'; '.join(', '.join(self.faults[j]) for j in held)}); nothing sent")
                    request.finish()
                    continue
                self._goals.update(request.goals)
            requests = [r for r in requests if not r.done.is_set()]
            goals = {j: a for j, a in self._goals.items() if j in state.joints and state[j].torque_on}
        if not goals:
            for request in requests:
                request.error = ServoHardwareError(f"{self.bus.name}: torque off on {', '.join(request.goals)}")
                request.finish()
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
            request.finish()

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
            request.finish()

    TIMING_MAX_AGE_S = 0.25

    def timing(self) -> dict[str, float | None]:
        """Counters, and the period and |period - nominal| quantiles (p50, p99, max) of the last
        cycles. The quantiles cost a millisecond over 6,000 periods: computed at most every
        `TIMING_MAX_AGE_S`, however many clients ask."""
        now = self.clock.monotonic()
        cached = self._timing_cache
        if cached is None or now - cached[0] > self.TIMING_MAX_AGE_S:
            quantiles = period_quantiles(np.array(self.periods_s, dtype=float), self.period_s)
            self._timing_cache = cached = (now, quantiles)
        return {"rate_hz": round(1.0 / self.period_s, 3), "cycles": self.cycles, "overruns": self.overruns,
                "long_periods": self.long_periods,
                "read_errors": self.read_errors, "write_errors": self.write_errors,
                "bus_down_count": self.bus_down_count, "power_losses": self.power_losses, **cached[1]}


    # -- what the head sees (headctl.service.head.JointBus) -------------------------------------------
    def read_state(self) -> BusState:
        return complete(self.fresh_state(), self.bus.name)

    def write_goals(self, goals: Mapping[str, float]) -> dict[str, float]:
        return self.request_goals(goals)
