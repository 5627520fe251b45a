"""The servo loop in a process of its own, so that nothing the rest of the service does can stall it.

In one process every thread shares one interpreter lock: a burst of API requests, a garbage
collection of the learning thread's heap or a long numpy call in the renderer holds it for
tens of milliseconds, and the servo loop's period with it. So the service runs the loop
(`servo_loop.ServoLoop`) in a child process that owns the bus, and talks to it through:

- a shared-memory state block (`SharedState`), written by the child after every cycle under
  a sequence lock and read by the service without waiting: the latest joint states, the goals
  in force, the loop's counters, the simulated servos' true positions and the trace of their
  motion (what the simulated cameras render a frame's exposure from); and a ring of the last
  periods, from which the service computes the quantiles;
- a heartbeat block written by the service whenever it reads or commands: the child's loop
  holds the present position when it goes stale for `service.input_timeout_s` (the loop's
  stale-input rule, as for a silent controller in one process);
- two pipes for what must not be lost: goal requests and their answers (what was sent, or
  the error), torque switches, simulated faults, the loop's fault changes, and the child's
  log records (re-emitted in the service's log). The child sends from a thread of its own, so
  a service slow to read never blocks the loop.

`ServoLoopProcess` is the service's side: the same interface as `ServoLoop` (the `Head` uses
it as its bus; the status and the control read it). The child stops when asked, leaving the
servos in the configured safe state, and also when the service's end of the pipe closes (the
service died): the bus's own watchdog and the stale-input hold cover the time between.
"""
from __future__ import annotations

import collections
import gc
import itertools
import logging
import multiprocessing
import multiprocessing.connection
import os
import pickle
import select
import struct
import sys
import threading
import time
from typing import Any, Callable, Mapping

import numpy as np

from drivers.servo.joints import JOINTS
from drivers.backends import backend_class
from drivers.clock import SYSTEM_CLOCK, Clock
from drivers.errors import (BusDownError, DriverError, JointLimitError, ServoCommError, ServoHardwareError,
                            ServoTimeoutError)
from drivers.servo.bus import BusState, JointState, ServoBus
from drivers.servo.faults import HardwareErrorEpisode
from drivers.sim.servos import TRACE_SAMPLES, TRACE_WIDTH, joints_at
from headctl.config.head import HeadConfig
from headctl.errors import HeadctlError, ServoLoopStoppedError, StaleStateError
from headctl.service.servo_io.loop import ServoLoop, _WriteRequest, period_quantiles
from headctl.service.servo_io.shared import SIZE, TRACE_BASE, SharedState, _H, _J, _joint_base

log = logging.getLogger(__name__)

HISTORY = 6000  # periods kept for the quantiles, as ServoLoop keeps them
COUNTERS = ("cycles", "overruns", "long_periods", "read_errors", "write_errors", "bus_down_count")
# The errors a goal request can end with, by name across the process boundary.
ERRORS: dict[str, type[Exception]] = {cls.__name__: cls for cls in (
    BusDownError, ServoHardwareError, JointLimitError, ServoCommError, ServoTimeoutError, DriverError,
    ServoLoopStoppedError, StaleStateError)}
START_TIMEOUT_S = 60.0  # the child imports numpy and opens the bus
POLL_S = 0.001  # how often a reader waiting for a fresh state looks at the block
MAX_BACKLOG_BYTES = 4 << 20  # past this much unread by the service, the child's log records are dropped


class ServoProcessError(HeadctlError):
    """The servo process failed to start, or died."""


# --- the child ---------------------------------------------------------------------------------
class _PipeLogHandler(logging.Handler):
    def __init__(self, send: Callable[[tuple[Any, ...]], None]) -> None:
        super().__init__(level=logging.DEBUG)
        self.send = send

    def emit(self, record: logging.LogRecord) -> None:
        try:
            self.send(("log", record.levelno, record.name, record.getMessage()))
        except Exception:  # logging must never stop the loop
            pass


class _Child:
    """The child's side: runs the loop in its main thread; answers on a sender thread."""

    def __init__(self, config: HeadConfig, inbox: multiprocessing.connection.Connection,
                 outbox: multiprocessing.connection.Connection, state_raw: Any, heartbeat_raw: Any,
                 periods_raw: Any) -> None:
        self.config = config
        self.inbox = inbox
        self.outbox = outbox
        self.shared = SharedState(state_raw)
        self.periods = np.frombuffer(periods_raw, dtype=np.float64)
        self.heartbeat = np.frombuffer(heartbeat_raw, dtype=np.float64)
        self.values = np.full(SIZE, np.nan)
        # What is on its way to the service: written without blocking (the pipe's framing,
        # a 4-byte length and the pickle), the rest kept for the next cycle. No second thread:
        # one holding this process's interpreter lock while descheduled would stall the loop.
        self._out = bytearray()
        self._out_fd = outbox.fileno()
        os.set_blocking(self._out_fd, False)
        self._dropped_logs = 0
        self.safe_state = "hold"
        self.loop: ServoLoop | None = None
        self.bus: ServoBus | None = None
        self._fault_seq = 0  # the last fault-log record sent to the service
        self._answers: list[tuple[Any, ...]] = []  # answers of this cycle, sent once it is published
        self._sim = False  # a simulated bus: its servos' true positions are published too

    def send(self, message: tuple[Any, ...]) -> None:
        if message[0] == "log" and len(self._out) > MAX_BACKLOG_BYTES:
            self._dropped_logs += 1  # a service that does not read loses log records, never answers
            return
        payload = pickle.dumps(message, protocol=pickle.HIGHEST_PROTOCOL)
        self._out += struct.pack("!i", len(payload)) + payload
        self.flush()

    def flush(self, block: bool = False) -> None:
        """Write what the pipe takes now (all of it, with `block`)."""
        while self._out:
            try:
                written = os.write(self._out_fd, self._out)
            except BlockingIOError:
                if not block:
                    return
                select.select([], [self._out_fd], [], 1.0)
                continue
            except OSError:  # the service is gone
                self._out.clear()
                return
            del self._out[:written]

    def run(self) -> None:
        from headctl.service.build import build_servo_bus

        root = logging.getLogger()
        root.handlers = [_PipeLogHandler(self.send)]
        root.setLevel(logging.INFO)
        service = self.config.service
        try:
            bus = self.bus = build_servo_bus(self.config)
            bus.open()
            bus.enable()
        except Exception as err:  # the service raises it again, by name
            self.send(("failed", type(err).__name__, str(err)))
            self.send(("stopped",))
            self.flush(block=True)
            return
        loop = self.loop = ServoLoop(bus, service.servo_rate_hz, service.input_timeout_s,
                                     realtime_priority=service.realtime_priority, on_fault_change=self._faults)
        loop.before_cycle = self._receive
        loop.after_cycle = self._publish
        self._sim = hasattr(bus, "true_position")
        gc.freeze()  # what start-up allocated is never collected again: shorter collections
        sys.setswitchinterval(service.switch_interval_ms / 1000.0)
        self.send(("ready", bus.name))
        self.flush(block=True)
        try:
            loop.run()
        finally:
            self._shutdown(bus, loop)

    def _shutdown(self, bus: ServoBus, loop: ServoLoop) -> None:
        state = loop.latest_state()
        try:
            if self.safe_state == "hold" and state is not None and loop.down_reason is None:
                bus.write_goals({j: state[j].position for j in JOINTS if state[j].torque_on})
            elif self.safe_state == "torque_off":
                bus.disable()
        except DriverError as err:
            log.warning("servo process: safe state %s not reached: %s", self.safe_state, err)
        finally:
            bus.close()
            self.values[_H["alive"]] = 0.0
            self.shared.write(self.values)
            for answer in self._answers:  # requests the stopping loop refused
                self.send(answer)
            self._answers.clear()
            self.send(("stopped",))
            self.flush(block=True)

    def _faults(self) -> None:
        loop = self.loop
        assert loop is not None
        self.send(("faults", loop.down_reason, {j: list(m) for j, m in loop.faults.items()}, loop.last_read_error))

    def _receive(self) -> None:
        loop = self.loop
        assert loop is not None
        loop.touch_at(float(self.heartbeat[0]))
        try:
            for _ in range(64):  # bounded: a flood of requests cannot hold a cycle back
                if not self.inbox.poll(0):
                    break
                self._handle(self.inbox.recv())
        except (EOFError, OSError):  # the service is gone: stop, safe state
            log.error("servo process: the service's pipe closed; stopping in the safe state")
            loop.stop()

    def _handle(self, message: tuple[Any, ...]) -> None:
        loop, bus = self.loop, self.bus
        assert loop is not None and bus is not None
        kind = message[0]
        if kind == "goals":
            rid = message[1]
            loop.post_goals(message[2], lambda request: self._answer_goals(rid, request))
        elif kind == "torque":
            rid = message[1]
            loop.post_call(loop.torque_switch(message[2]), lambda action: self._answer(rid, action.result, action.error))
        elif kind == "inject":
            rid, fault, joint, bits = message[1:]
            loop.post_call(lambda b: _inject(b, fault, joint, bits),
                           lambda action: self._answer(rid, action.result, action.error))
        elif kind == "stop":
            self.safe_state = message[1]
            loop.stop()

    def _answer_goals(self, rid: int, request: _WriteRequest) -> None:
        self._answer(rid, request.sent, request.error)

    def _answer(self, rid: int, result: Any, error: BaseException | None) -> None:
        # Sent after this cycle's state is published: a service told its goals were written
        # then reads them as the goals in force, never the ones before.
        self._answers.append(("done", rid, result, None if error is None else type(error).__name__,
                              None if error is None else str(error)))

    def _publish(self) -> None:
        loop = self.loop
        assert loop is not None
        v = self.values
        state = loop.latest_state()
        goals = loop.goals()
        v[_H["state_seq"]] = float(loop.state_seq)
        v[_H["has_state"]] = 0.0 if state is None else 1.0
        v[_H["time_s"]] = np.nan if state is None else state.time_s
        v[_H["last_read_s"]] = loop.last_read_s
        v[_H["last_cycle_s"]] = loop.last_cycle_s
        for name in COUNTERS:
            v[_H[name]] = getattr(loop, name)
        v[_H["down"]] = float(loop.down_reason is not None)
        v[_H["torque_enabled"]] = float(loop.torque_enabled)
        v[_H["alive"]] = 1.0
        # The last period into the ring; the service computes the quantiles (a millisecond or
        # more of numpy here, every quarter second, would be a long period now and then).
        if loop.periods_s:
            self.periods[loop.cycles % HISTORY] = loop.periods_s[-1]
        for j, joint in enumerate(JOINTS):
            base = _joint_base(j)
            if state is not None:
                js = state[joint]
                v[base:base + 7] = (js.position, js.velocity, js.moving, js.torque_on, js.hardware_error_bits,
                                    js.temperature_c, js.input_voltage_v)
            v[base + _J["goal"]] = goals.get(joint, np.nan)
            if self._sim:
                v[base + _J["true_position"]] = self.bus.true_position(joint)  # type: ignore[union-attr]
        if self._sim:
            v[TRACE_BASE:] = self.bus.true_trace().ravel()  # type: ignore[union-attr]
        self.shared.write(v)
        answers, self._answers = self._answers, []
        for answer in answers:
            self.send(answer)
        assert self.bus is not None
        for record in self.bus.fault_log.since(self._fault_seq):  # a few records an episode, rarely
            self._fault_seq = record.seq
            self.send(("episode", record))
        self.flush()


def _inject(bus: ServoBus, fault: str, joint: str | None, bits: int) -> str:
    """A simulated fault, on the simulated bus (the service checked the arguments)."""
    if fault == "bus_down":
        bus.inject_bus_down()  # type: ignore[attr-defined]
    elif fault == "restore_bus":
        bus.restore_bus()  # type: ignore[attr-defined]
    elif fault == "hardware_error":
        bus.inject_hardware_error(joint, bits)  # type: ignore[attr-defined]
    return fault


def servo_main(config: HeadConfig, inbox: multiprocessing.connection.Connection,
               outbox: multiprocessing.connection.Connection, state_raw: Any, heartbeat_raw: Any,
               periods_raw: Any) -> None:
    """The child process's entry point."""
    _Child(config, inbox, outbox, state_raw, heartbeat_raw, periods_raw).run()


# --- the service's side ------------------------------------------------------------------------
class ServoLoopProcess:
    """The servo loop in a child process, with `ServoLoop`'s interface; see the module docstring."""

    name = "servo-io"

    def __init__(self, config: HeadConfig, on_fault_change: Callable[[], None] | None = None,
                 clock: Clock = SYSTEM_CLOCK) -> None:
        self.config = config
        self.clock = clock
        self.on_fault_change = on_fault_change
        self.period_s = 1.0 / config.service.servo_rate_hz
        self._context = multiprocessing.get_context("spawn")
        self._shared = SharedState.create()
        self._heartbeat_raw = self._context.RawArray("d", 1)
        self._heartbeat = np.frombuffer(self._heartbeat_raw, dtype=np.float64)
        self._heartbeat[0] = clock.monotonic()
        self._periods_raw = self._context.RawArray("d", HISTORY)  # the last periods, a ring
        self._periods = np.frombuffer(self._periods_raw, dtype=np.float64)
        self._periods[:] = np.nan  # not yet written
        self._timing_cache: tuple[float, dict[str, float | None]] | None = None
        child_inbox, self._to_child = self._context.Pipe(duplex=False)
        self._from_child, child_outbox = self._context.Pipe(duplex=False)
        self._process = self._context.Process(target=servo_main, name="headctl-servo-io", daemon=True,
                                              args=(config, child_inbox, child_outbox, self._shared.raw,
                                                    self._heartbeat_raw, self._periods_raw))
        self._child_ends = (child_inbox, child_outbox)
        self._send_lock = threading.Lock()
        self._ids = itertools.count(1)
        self._pending: dict[int, tuple[threading.Event, list[Any]]] = {}
        self._pending_lock = threading.Lock()
        self._reader = threading.Thread(target=self._read_forever, name="servo-link", daemon=True)
        self._stopping = False
        self.bus_name = config.servo_bus.port
        # The child's bus decodes hardware error bits; the states read here are decoded alike.
        bus_class = backend_class("servo_bus", config.servo_bus.backend, config.servo_bus)
        self._decode_errors: Callable[[int], tuple[str, ...]] = bus_class.decode_hardware_error
        self.down_reason: str | None = None
        self.faults: dict[str, tuple[str, ...]] = {}
        self.last_read_error = ""
        self.error: BaseException | None = None
        self._records: collections.deque[HardwareErrorEpisode] = collections.deque(maxlen=1024)
        self._records_lock = threading.Lock()

    # -- lifecycle ------------------------------------------------------------------------------
    def start(self, timeout_s: float = START_TIMEOUT_S) -> "ServoLoopProcess":
        """Start the child; returns once its bus is open and enabled, or raises its error."""
        self._process.start()
        for end in self._child_ends:
            end.close()
        deadline = time.monotonic() + timeout_s
        while True:
            remaining = deadline - time.monotonic()
            if remaining <= 0 or not self._from_child.poll(remaining):
                self._kill()
                raise ServoProcessError(f"servo process: not ready within {timeout_s:g} s")
            message = self._from_child.recv()
            if message[0] == "log":
                self._relay_log(message)
            elif message[0] == "failed":
                self._process.join(5.0)
                raise ERRORS.get(message[1], ServoProcessError)(message[2])
            elif message[0] == "ready":
                self.bus_name = message[1]
                break
        self._reader.start()
        return self

    def stop(self, timeout_s: float = 5.0, safe_state: str = "hold") -> None:
        """Stop the child, which leaves the servos in `safe_state` and closes the bus. Idempotent."""
        if self._stopping:
            return
        self._stopping = True
        try:
            self._send(("stop", safe_state))
        except ServoLoopStoppedError:
            pass
        self._process.join(timeout_s)
        if self._process.is_alive():
            log.warning("servo process did not stop within %.1f s; killed", timeout_s)
            self._kill()
        if self._reader.is_alive():
            self._reader.join(timeout_s)
        self._to_child.close()

    def _kill(self) -> None:
        if self._process.is_alive():
            self._process.kill()
            self._process.join(5.0)

    def is_alive(self) -> bool:
        return self._process.is_alive() and not self._stopping and self._value("alive") == 1.0

    # -- the child's messages -------------------------------------------------------------------
    def _read_forever(self) -> None:
        while True:
            try:
                message = self._from_child.recv()
            except (EOFError, OSError):
                break
            kind = message[0]
            if kind == "done":
                with self._pending_lock:
                    waiting = self._pending.pop(message[1], None)
                if waiting is not None:
                    waiting[1].extend(message[2:])
                    waiting[0].set()
            elif kind == "faults":
                self.down_reason, faults, self.last_read_error = message[1], message[2], message[3]
                self.faults = {j: tuple(m) for j, m in faults.items()}
                if self.on_fault_change is not None:
                    try:
                        self.on_fault_change()
                    except Exception:  # a listener must not stop the link
                        log.exception("servo process: fault listener failed")
            elif kind == "log":
                self._relay_log(message)
            elif kind == "episode":
                with self._records_lock:
                    self._records.append(message[1])
            elif kind == "stopped":
                break
        if not self._stopping:
            self.error = ServoProcessError(f"servo process exited (code {self._process.exitcode})")
            log.error("%s", self.error)
        with self._pending_lock:
            pending, self._pending = self._pending, {}
        for event, result in pending.values():
            result.extend([None, "ServoLoopStoppedError", "the servo process stopped"])
            event.set()

    @staticmethod
    def _relay_log(message: tuple[Any, ...]) -> None:
        _, level, name, text = message
        logging.getLogger(name).log(level, "%s", text)

    def _send(self, message: tuple[Any, ...]) -> None:
        with self._send_lock:
            try:
                self._to_child.send(message)
            except (OSError, ValueError) as err:
                raise ServoLoopStoppedError(f"{self.name}: the servo process is not running ({err})") from err

    def _request(self, message: tuple[Any, ...], timeout_s: float) -> Any:
        rid = next(self._ids)
        event, result = threading.Event(), []  # type: ignore[var-annotated]
        with self._pending_lock:
            self._pending[rid] = (event, result)
        self._send((message[0], rid, *message[1:]))
        if not event.wait(timeout_s):
            with self._pending_lock:
                self._pending.pop(rid, None)
            raise StaleStateError(f"{self.bus_name}: the servo process did not answer within {timeout_s} s")
        value, error_kind, error_text = result
        if error_kind is not None:
            raise ERRORS.get(error_kind, DriverError)(error_text)
        return value

    # -- the state block ------------------------------------------------------------------------
    def _value(self, name: str) -> float:
        return float(self._shared.values[_H[name]])

    def touch(self) -> None:
        self._heartbeat[0] = self.clock.monotonic()

    def latest_state(self) -> BusState | None:
        return self._state(self._shared.read())

    def _state(self, v: np.ndarray) -> BusState | None:
        if v[_H["has_state"]] != 1.0:
            return None
        joints = {}
        for j, joint in enumerate(JOINTS):
            b = _joint_base(j)
            joints[joint] = JointState(position=float(v[b]), velocity=float(v[b + 1]), moving=bool(v[b + 2]),
                                       torque_on=bool(v[b + 3]), hardware_error_bits=int(v[b + 4]),
                                       temperature_c=float(v[b + 5]), input_voltage_v=float(v[b + 6]),
                                       hardware_errors=self._decode_errors(int(v[b + 4])))
        return BusState(time_s=float(v[_H["time_s"]]), joints=joints)

    def fresh_state(self, timeout_s: float = 1.0) -> BusState:
        """The first state read after this call."""
        self.touch()
        seq = self._value("state_seq")
        deadline = self.clock.monotonic() + timeout_s
        while True:
            v = self._shared.read()
            if v[_H["state_seq"]] != seq:
                state = self._state(v)
                if state is not None:
                    return state
            if v[_H["down"]] == 1.0:
                raise BusDownError(f"{self.bus_name}: {self.down_reason or 'bus down'}")
            if self.clock.monotonic() >= deadline or not self._process.is_alive():
                raise StaleStateError(f"{self.bus_name}: no servo state within {timeout_s} s")
            time.sleep(POLL_S)

    def goals(self) -> dict[str, float]:
        v = self._shared.read()
        return {joint: float(v[_joint_base(j) + _J["goal"]]) for j, joint in enumerate(JOINTS)
                if not np.isnan(v[_joint_base(j) + _J["goal"]])}

    def request_goals(self, goals: Mapping[str, float], timeout_s: float = 1.0) -> dict[str, float]:
        """Have the next cycle write `goals` (the bus checks the limits); what was sent, or its error."""
        self.touch()
        if self._value("down") == 1.0:
            raise BusDownError(f"{self.bus_name}: {self.down_reason or 'bus down'}")
        sent: dict[str, float] = self._request(("goals", dict(goals)), timeout_s)
        return sent

    def read_state(self) -> BusState:
        return self.fresh_state()

    def write_goals(self, goals: Mapping[str, float]) -> dict[str, float]:
        return self.request_goals(goals)

    def set_torque(self, on: bool, timeout_s: float = 2.0) -> None:
        self._request(("torque", on), timeout_s)

    def describe(self, joint: str) -> str:
        return f"joint {joint} (id {self.config.servo_bus.joints[joint].servo_id}) on {self.bus_name}"

    def fault_records(self, since: int) -> tuple[HardwareErrorEpisode, ...]:
        with self._records_lock:
            return tuple(r for r in self._records if r.seq > since)

    @property
    def torque_enabled(self) -> bool:
        return self._value("torque_enabled") == 1.0

    @property
    def last_read_s(self) -> float:
        return self._value("last_read_s")

    @property
    def last_cycle_s(self) -> float:
        value = self._value("last_cycle_s")
        return value if np.isfinite(value) else -np.inf

    @property
    def cycles(self) -> int:
        value = self._value("cycles")
        return int(value) if np.isfinite(value) else 0

    def timing(self) -> dict[str, Any]:
        """Counters, and the period quantiles over the last `HISTORY` cycles (computed here, at
        most every `ServoLoop.TIMING_MAX_AGE_S`)."""
        v = self._shared.read()
        out: dict[str, Any] = {"rate_hz": round(1.0 / self.period_s, 3)}
        for name in COUNTERS:
            out[name] = int(v[_H[name]]) if np.isfinite(v[_H[name]]) else 0
        now = self.clock.monotonic()
        cached = self._timing_cache
        if cached is None or now - cached[0] > ServoLoop.TIMING_MAX_AGE_S:
            periods = self._periods.copy()
            self._timing_cache = cached = (now, period_quantiles(periods[~np.isnan(periods)], self.period_s))
        out.update(cached[1])
        return out

    # -- the simulated servos (what SimulatedWorld needs) -----------------------------------------
    def true_position(self, joint: str) -> float:
        return float(self._shared.values[_joint_base(JOINTS.index(joint)) + _J["true_position"]])

    def true_joints_at(self, time_s: float) -> dict[str, float]:
        """Where the simulated joints were at `time_s` (at most now), from the trace of their
        motion the child publishes after each cycle (`drivers.sim.servos.JointTrace`)."""
        rows = self._shared.read()[TRACE_BASE:].reshape(TRACE_SAMPLES, TRACE_WIDTH)
        joints = joints_at(rows, min(time_s, self.clock.monotonic()))
        if joints is None:
            raise StaleStateError(f"{self.bus_name}: the simulated servos' motion is not published yet")
        return joints

    def inject(self, fault: str, joint: str | None = None, bits: int = 0, timeout_s: float = 2.0) -> None:
        self._request(("inject", fault, joint, bits), timeout_s)

    def inject_bus_down(self) -> None:
        self.inject("bus_down")

    def restore_bus(self) -> None:
        self.inject("restore_bus")

    def inject_hardware_error(self, joint: str, bits: int) -> None:
        self.inject("hardware_error", joint, bits)

