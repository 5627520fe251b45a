"""The servo process's own side: it owns the bus and runs the servo loop in its main thread
(`headctl.service.servo_io.process` describes the whole and the service's side).

After every cycle the child publishes the loop's state in the shared block, then sends the
cycle's answers and the bus's new fault records (`messages`). What it sends is written
without blocking; a service slow to read never holds a cycle back.
"""
from __future__ import annotations

import gc
import logging
import multiprocessing.connection
import os
import pickle
import select
import struct
import sys
from typing import Callable, Mapping, Protocol, cast

import numpy as np

from drivers.servo.joints import JOINTS
from drivers.errors import DriverError
from drivers.servo.bus import ServoBus
from drivers.sim.servo_motion import AxisState
from headctl.config.head import HeadConfig
from headctl.service.servo_io.loop import ServoLoop, _WriteRequest
from headctl.service.servo_io.messages import (Done, Episode, Failed, FaultsChanged, InjectFault, LogRecord, Ready,
                                               RemoteError, Report, Request, ServoFault, Stop, Stopped, SwitchTorque,
                                               WriteGoals)
from headctl.service.servo_io.shared import (COUNTERS, HISTORY, SIZE, TRACE_BASE, DoubleArray, SharedState, _H, _J,
                                              _joint_base, write_true_axis)

log = logging.getLogger(__name__)

MAX_BACKLOG_BYTES = 4 << 20  # past this much unread by the service, the child's log records are dropped


class TrueMotion(Protocol):
    """A bus that declares `reports_true_motion`: where its simulated servos really are."""

    def true_axis(self, joint: str) -> AxisState: ...

    def true_trace(self) -> np.ndarray: ...


class FaultInjection(Protocol):
    """A bus whose capabilities include "fault_injection"."""

    def inject_bus_down(self) -> None: ...

    def restore_bus(self) -> None: ...

    def inject_hardware_error(self, joint: str, bits: int) -> None: ...

    def inject_power_loss(self) -> None: ...

    def restore_power(self, bits: int = 0) -> None: ...

    def remove_servo(self, joint: str) -> None: ...

    def add_servo(self, joint: str) -> None: ...


class _PipeLogHandler(logging.Handler):
    def __init__(self, send: Callable[[Report], None]) -> None:
        super().__init__(level=logging.DEBUG)
        self.send = send

    def emit(self, record: logging.LogRecord) -> None:
        try:
            self.send(LogRecord(record.levelno, record.name, record.getMessage()))
        except Exception:  # logging must never stop the loop
            pass


class _Child:
    """The child's side: runs the loop in its main thread; answers after each cycle."""

    def __init__(self, config: HeadConfig, inbox: multiprocessing.connection.Connection,
                 outbox: multiprocessing.connection.Connection, state_raw: DoubleArray, heartbeat_raw: DoubleArray,
                 periods_raw: DoubleArray, enable: bool = True, initial_axes: Mapping[str, AxisState] | None = None,
                 ) -> None:
        self.config = config
        self.enable = enable  # torque on at start (goal := present first); False: as the service had switched it
        self.initial_axes = initial_axes  # a simulated bus: its servos as the dead child's were
        self.inbox = inbox
        self.outbox = outbox
        self.shared = SharedState(state_raw)
        self.periods = np.frombuffer(memoryview(periods_raw), dtype=np.float64)
        self.heartbeat = np.frombuffer(memoryview(heartbeat_raw), dtype=np.float64)
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
        self._answers: list[Done] = []  # answers of this cycle, sent once it is published
        self._truth: TrueMotion | None = None  # a simulated bus: its servos' true states are published too

    def send(self, message: Report) -> None:
        if isinstance(message, LogRecord) and len(self._out) > MAX_BACKLOG_BYTES:
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
            bus = self.bus = build_servo_bus(self.config, initial_axes=self.initial_axes)
            bus.open()
            if self.enable:
                bus.enable()
        except Exception as err:  # the service raises it again
            self.send(Failed(RemoteError.of(err)))
            self.send(Stopped())
            self.flush(block=True)
            return
        loop = self.loop = ServoLoop(bus, service.servo_rate_hz, service.input_timeout_s,
                                     realtime_priority=service.realtime_priority, on_fault_change=self._faults)
        loop.torque_enabled = self.enable
        loop.before_cycle = self._receive
        loop.after_cycle = self._publish
        self._truth = cast(TrueMotion, bus) if bus.reports_true_motion else None
        gc.freeze()  # what start-up allocated is never collected again: shorter collections
        sys.setswitchinterval(service.switch_interval_ms / 1000.0)
        self.send(Ready(bus.name))
        self.flush(block=True)
        try:
            loop.run()
        finally:
            self._shutdown(bus, loop)

    def _shutdown(self, bus: ServoBus, loop: ServoLoop) -> None:
        state = loop.latest_state()
        try:
            if self.safe_state == "hold" and state is not None and loop.down_reason is None:
                bus.write_goals({j: s.position for j, s in state.joints.items() if s.torque_on})
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
            self.send(Stopped())
            self.flush(block=True)

    def _faults(self) -> None:
        loop = self.loop
        assert loop is not None
        self.send(FaultsChanged(loop.down_reason, dict(loop.faults), loop.last_read_error, dict(loop.missing)))

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

    def _handle(self, message: Request) -> None:
        loop, bus = self.loop, self.bus
        assert loop is not None and bus is not None
        match message:
            case WriteGoals(rid, goals):
                loop.post_goals(goals, lambda request: self._answer_goals(rid, request))
            case SwitchTorque(rid, on):
                loop.post_call(loop.torque_switch(on), lambda action: self._answer(rid, None, action.error))
            case InjectFault(rid, fault, joint, bits):
                loop.post_call(lambda b: _inject(b, fault, joint, bits),
                               lambda action: self._answer(rid, None, action.error))
            case Stop(safe_state):
                self.safe_state = safe_state
                loop.stop()

    def _answer_goals(self, rid: int, request: _WriteRequest) -> None:
        self._answer(rid, request.sent, request.error)

    def _answer(self, rid: int, sent: dict[str, float] | None, error: BaseException | None) -> None:
        # Sent after this cycle's state is published: a service told its goals were written
        # then reads them as the goals in force, never the ones before.
        self._answers.append(Done(rid, sent, None if error is None else RemoteError.of(error)))

    def _publish(self) -> None:
        loop, bus = self.loop, self.bus
        assert loop is not None and bus is not None
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
        truth = self._truth
        for j, joint in enumerate(JOINTS):
            base = _joint_base(j)
            if state is not None:
                js = state.joints.get(joint)
                v[base + _J["missing"]] = float(js is None)
                if js is not None:
                    v[base:base + 7] = (js.position, js.velocity, js.moving, js.torque_on, js.hardware_error_bits,
                                        js.temperature_c, js.input_voltage_v)
            v[base + _J["goal"]] = goals.get(joint, np.nan)
            if truth is not None:
                write_true_axis(v, j, truth.true_axis(joint))
        if truth is not None:
            v[TRACE_BASE:] = truth.true_trace().ravel()
        self.shared.write(v)
        answers, self._answers = self._answers, []
        for answer in answers:
            self.send(answer)
        for record in bus.fault_log.since(self._fault_seq):  # a few records an episode, rarely
            self._fault_seq = record.seq
            self.send(Episode(record))
        self.flush()


def _inject(bus: ServoBus, fault: ServoFault, joint: str | None, bits: int) -> None:
    """A simulated fault, on a bus that offers fault injection (the service checked the arguments)."""
    if "fault_injection" not in bus.capabilities:
        raise DriverError(f"{bus.name}: no fault injection on this bus")
    faulty = cast(FaultInjection, bus)
    match fault:
        case ServoFault.BUS_DOWN:
            faulty.inject_bus_down()
        case ServoFault.RESTORE_BUS:
            faulty.restore_bus()
        case ServoFault.HARDWARE_ERROR:
            assert joint is not None
            faulty.inject_hardware_error(joint, bits)
        case ServoFault.POWER_LOSS:
            faulty.inject_power_loss()
        case ServoFault.POWER_BACK:
            faulty.restore_power(bits)
        case ServoFault.SERVO_REMOVE:
            assert joint is not None
            faulty.remove_servo(joint)
        case ServoFault.SERVO_ADD:
            assert joint is not None
            faulty.add_servo(joint)


def servo_main(config: HeadConfig, inbox: multiprocessing.connection.Connection,
               outbox: multiprocessing.connection.Connection, state_raw: DoubleArray, heartbeat_raw: DoubleArray,
               periods_raw: DoubleArray, enable: bool = True, initial_axes: Mapping[str, AxisState] | None = None,
               ) -> None:
    """The child process's entry point; a restarted one gets `enable` (torque on) and, on a
    simulated bus, the servos' states as the dead child last published them (`initial_axes`)."""
    _Child(config, inbox, outbox, state_raw, heartbeat_raw, periods_raw, enable, initial_axes).run()
