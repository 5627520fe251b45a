"""The servo loop in a process of its own, so that nothing the rest of the service does can stall it.

In one process every thread shares one interpreter lock: a burst of API requests, a garbage
collection of the learning thread's heap or a long numpy call in the renderer holds it for
tens of milliseconds, and the servo loop's period with it. So the service runs the loop
(`servo_loop.ServoLoop`) in a child process that owns the bus, and talks to it through:

- a shared-memory state block (`SharedState`), written by the child after every cycle under
  a sequence lock and read by the service without waiting: the latest joint states, the goals
  in force, the loop's counters, the simulated servos' true states (each output, what the
  simulated cameras see, and each controller's position: what a restarted child starts its
  servos from) and the trace of their motion (what the simulated cameras render a frame's
  exposure from); and a ring of the last periods, from which the service computes the quantiles;
- a heartbeat block written by the service whenever it reads or commands: the child's loop
  holds the present position when it goes stale for `service.input_timeout_s` (the loop's
  stale-input rule, as for a silent controller in one process);
- two pipes for what must not be lost: goal requests and their answers (what was sent, or
  the error), torque switches, simulated faults, the loop's fault changes, and the child's
  log records (re-emitted in the service's log), each a typed message (`messages`). The
  child writes without blocking, so a service slow to read never blocks the loop.

The child's side is `child`; `ServoLoopProcess`, here, is the service's side: the same
interface as `ServoLoop` (the `Head` uses it as its bus; the status and the control read
it). The child stops when asked, leaving the
servos in the configured safe state, and also when the service's end of the pipe closes (the
service died): the bus's own watchdog and the stale-input hold cover the time between.
"""
from __future__ import annotations

import collections
import dataclasses
import itertools
import logging
import multiprocessing
import multiprocessing.connection
import multiprocessing.context
import multiprocessing.process
import threading
import time
from typing import Callable, Mapping

import numpy as np

from drivers.servo.joints import JOINTS
from drivers.backends import backend_class
from drivers.clock import SYSTEM_CLOCK, Clock
from drivers.errors import BusDownError, DriverError
from drivers.servo.bus import BusState, JointState
from drivers.servo.faults import HardwareErrorEpisode
from drivers.sim.servo_motion import TRACE_SAMPLES, TRACE_WIDTH, AxisState, joints_at
from headctl.config.head import HeadConfig
from headctl.errors import HeadctlError, ServoLoopStoppedError, StaleStateError
from headctl.service.servo_io.child import servo_main
from headctl.service.servo_io.loop import ServoLoop, complete, period_quantiles
from headctl.service.servo_io.messages import (Done, Episode, ErrorKind, Failed, FaultsChanged, InjectFault,
                                               LogRecord, Ready, RemoteError, Request, ServoFault, Stop, Stopped,
                                               SwitchTorque, WriteGoals)
from headctl.json_types import JSONObject
from headctl.service.servo_io.shared import (COUNTERS, HISTORY, TRACE_BASE, SharedState, _H, _J, _joint_base,
                                              read_true_axes)

log = logging.getLogger(__name__)

START_TIMEOUT_S = 60.0  # the child imports numpy and opens the bus
# A restarted child (forked, modules imported) is ready in well under a second; one that is not
# within this is a failed restart, retried after the next back-off, and the supervisor waiting on
# it stays well within systemd's watchdog interval.
RESTART_TIMEOUT_S = 5.0
POLL_S = 0.001  # how often a reader waiting for a fresh state looks at the block


def _servo_context() -> multiprocessing.context.ForkServerContext | multiprocessing.context.SpawnContext:
    """How children are made: forked from a fork server that imported the child's modules once
    (a clean single-threaded process, not this one), so that a restarted child is ready in tens of
    milliseconds rather than the seconds a fresh interpreter takes to import numpy and the drivers."""
    if "forkserver" not in multiprocessing.get_all_start_methods():
        return multiprocessing.get_context("spawn")
    context = multiprocessing.get_context("forkserver")
    context.set_forkserver_preload(["headctl.service.servo_io.child", "headctl.service.build"])
    return context


class ServoProcessError(HeadctlError):
    """The servo process failed to start, or died."""


class _Waiting:
    """A request waiting for its answer (set on the link's thread)."""

    def __init__(self) -> None:
        self.event = threading.Event()
        self.answer: Done | None = None

    def finish(self, answer: Done) -> None:
        self.answer = answer
        self.event.set()


class ServoLoopProcess:
    """The servo loop in a child process, with `ServoLoop`'s interface; see the module docstring."""

    name = "servo-io"

    def __init__(self, config: HeadConfig, on_fault_change: Callable[[], None] | None = None,
                 clock: Clock = SYSTEM_CLOCK) -> None:
        self.config = config
        self.clock = clock
        self.on_fault_change = on_fault_change
        self.period_s = 1.0 / config.service.servo_rate_hz
        self._context = _servo_context()
        self._shared = SharedState.create()
        self._heartbeat_raw = self._context.RawArray("d", 1)
        self._heartbeat = np.frombuffer(self._heartbeat_raw, dtype=np.float64)
        self._heartbeat[0] = clock.monotonic()
        self._periods_raw = self._context.RawArray("d", HISTORY)  # the last periods, a ring
        self._periods = np.frombuffer(self._periods_raw, dtype=np.float64)
        self._periods[:] = np.nan  # not yet written
        self._timing_cache: tuple[float, dict[str, float | None]] | None = None
        self._send_lock = threading.Lock()
        self._ids = itertools.count(1)
        self._pending: dict[int, _Waiting] = {}
        self._pending_lock = threading.Lock()
        self._torque_wanted = True  # what a restarted child leaves the servos in (the last set_torque)
        self.restarts = 0
        self._spawn(None)
        self._stopping = False
        self.bus_name = config.servo_bus.port
        # The child's bus decodes hardware error bits; the states read here are decoded alike.
        bus_class = backend_class("servo_bus", config.servo_bus.backend, config.servo_bus)
        self._decode_errors: Callable[[int], tuple[str, ...]] = bus_class.decode_hardware_error
        self.down_reason: str | None = None
        self.faults: dict[str, tuple[str, ...]] = {}
        self.missing: dict[str, str] = {}  # joint -> its description, as the child last told
        self.last_read_error = ""
        self.error: BaseException | None = None
        self._records: collections.deque[HardwareErrorEpisode] = collections.deque(maxlen=1024)
        self._records_lock = threading.Lock()
        # Each child numbers its fault log from 1: the records of a restarted child are moved
        # past the dead one's, so that the log stays one sequence (readers keep a cursor in it).
        self._seq_offset = 0
        self._last_seq = 0
        self._death_code: int | None = None  # the dead child's exit code, as the link first read it

    # -- lifecycle ------------------------------------------------------------------------------
    def _spawn(self, initial_axes: Mapping[str, AxisState] | None) -> None:
        """A new child (not started) with its own pipes, and the thread that reads its messages;
        on a simulated head its servos start in the states `initial_axes` (None: at the start pose)."""
        child_inbox, self._to_child = self._context.Pipe(duplex=False)
        self._from_child, child_outbox = self._context.Pipe(duplex=False)
        self._process = self._context.Process(
            target=servo_main, name="headctl-servo-io", daemon=True,
            args=(self.config, child_inbox, child_outbox, self._shared.raw, self._heartbeat_raw, self._periods_raw),
            kwargs={"enable": self._torque_wanted, "initial_axes": initial_axes})
        self._child_ends = (child_inbox, child_outbox)
        self._reader = threading.Thread(target=self._read_forever, args=(self._from_child, self._process),
                                        name="servo-link", daemon=True)

    @property
    def pid(self) -> int | None:
        """The child's process id (None before it started)."""
        return self._process.pid

    @property
    def exitcode(self) -> int | None:
        """The child's exit code once it exited (negative: killed by that signal), else None."""
        return self._process.exitcode

    # -- supervision (`headctl.service.supervision.restarts.Restartable`) -------------------------------------
    counts = True  # its deaths count toward the service giving up

    def failure(self) -> str | None:
        """Why the child is not running (it died, or its restart failed), None while it runs or
        while it is being stopped."""
        if self._stopping:
            return None
        if self.error is not None:
            return str(self.error)
        if self._process.exitcode is not None:
            return f"servo process {self._process.pid} exited (code {self._process.exitcode})"
        return None

    def restart(self, timeout_s: float = RESTART_TIMEOUT_S) -> dict[str, object]:
        """Replace a child that died by a new one: the bus reopened, the servos initialised again,
        the goals set to the present positions (the bus's `enable()`), torque on unless the service
        had switched it off; returns once it is ready (its pid and the old one's exit code), or
        raises its error. The simulated servos start at rest as the dead child last published
        them (`shared.read_true_axes`): each controller's position and output, so where the output
        sits in the play and the tilt's droop are as they were: killing a process moves no shaft."""
        if self._stopping:
            raise ServoLoopStoppedError(f"{self.name}: stopping; not restarted")
        old_pid = self._process.pid
        old_code = self._death_code if self._death_code is not None else self._process.exitcode
        self._death_code = None
        self._kill()
        if self._reader.is_alive():
            self._reader.join(5.0)
        for end in (self._to_child, self._from_child):
            end.close()
        self._mark_dead()
        with self._records_lock:
            self._seq_offset = self._last_seq
        simulated = self._shared.values[_H["has_state"]] == 1.0 and self.config.simulated
        self._spawn(read_true_axes(self._shared.read()) if simulated else None)
        self.down_reason, self.faults, self.missing, self.last_read_error = None, {}, {}, ""
        try:
            self.start(timeout_s)
        except BaseException as err:
            self.error = err
            raise
        self.restarts += 1
        self.error = None  # the fault lasts until the new child cycles
        if self.on_fault_change is not None:
            self.on_fault_change()
        return {"old_pid": old_pid, "exit_code": old_code, "new_pid": self._process.pid}

    def _mark_dead(self) -> None:
        """The block as a dead child left it, readable again: a write its death cut short leaves
        the sequence odd, on which readers would wait for ever."""
        values = self._shared.values
        values[_H["seq"]] += values[_H["seq"]] % 2
        values[_H["alive"]] = 0.0

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
            try:
                message = self._from_child.recv()
            except (EOFError, OSError) as err:
                self._process.join(5.0)
                raise ServoProcessError(f"servo process {self._process.pid} exited before it was ready "
                                        f"(code {self._process.exitcode})") from err
            match message:
                case LogRecord() as record:
                    self._relay_log(record)
                case Failed(error):
                    self._process.join(5.0)
                    raise error.exception(ServoProcessError)
                case Ready(bus_name):
                    self.bus_name = bus_name
                    break
        self._reader.start()
        while not self.is_alive():  # its first cycle published: commands are taken from now on
            if time.monotonic() > deadline or self._process.exitcode is not None:
                self._kill()
                raise ServoProcessError(f"servo process {self._process.pid}: no cycle within {timeout_s:g} s "
                                        f"(exit code {self._process.exitcode})")
            time.sleep(POLL_S)
        return self

    def stop(self, timeout_s: float = 5.0, safe_state: str = "hold") -> None:
        """Stop the child, which leaves the servos in `safe_state` and closes the bus. Idempotent."""
        if self._stopping:
            return
        self._stopping = True
        try:
            self._send(Stop(safe_state))
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
    def _read_forever(self, inbox: multiprocessing.connection.Connection,
                      process: multiprocessing.process.BaseProcess) -> None:
        while True:
            try:
                message = inbox.recv()
            except (EOFError, OSError):
                break
            match message:
                case Done(rid):
                    with self._pending_lock:
                        waiting = self._pending.pop(rid, None)
                    if waiting is not None:
                        waiting.finish(message)
                case FaultsChanged(down_reason, faults, last_read_error, missing):
                    self.down_reason, self.faults, self.last_read_error = down_reason, dict(faults), last_read_error
                    self.missing = dict(missing)
                    if self.on_fault_change is not None:
                        try:
                            self.on_fault_change()
                        except Exception:  # a listener must not stop the link
                            log.exception("servo process: fault listener failed")
                case LogRecord():
                    self._relay_log(message)
                case Episode(record):
                    with self._records_lock:
                        offset = self._seq_offset
                        record = dataclasses.replace(record, seq=record.seq + offset,
                                                     episode=record.episode + offset)
                        self._last_seq = max(self._last_seq, record.seq)
                        self._records.append(record)
                case Stopped():
                    break
        if not self._stopping:
            process.join(1.0)  # reaped, so that its exit code is known
            self._mark_dead()
            # Kept as first read: a fork server's child's status can be read only once for sure.
            self._death_code = process.exitcode
            self.error = ServoProcessError(f"servo process {process.pid} exited (code {self._death_code})")
            log.error("%s", self.error)
        with self._pending_lock:
            pending, self._pending = self._pending, {}
        for rid, waiting in pending.items():
            waiting.finish(Done(rid, error=RemoteError(ErrorKind.LOOP_STOPPED, "the servo process stopped")))

    @staticmethod
    def _relay_log(record: LogRecord) -> None:
        logging.getLogger(record.name).log(record.level, "%s", record.text)

    def _send(self, message: Request) -> None:
        with self._send_lock:
            try:
                self._to_child.send(message)
            except (OSError, ValueError) as err:
                raise ServoLoopStoppedError(f"{self.name}: the servo process is not running ({err})") from err

    def _request(self, request: Callable[[int], Request], timeout_s: float) -> dict[str, float] | None:
        """Send `request(rid)` and wait for its answer: what was sent, or its error raised here."""
        rid = next(self._ids)
        waiting = _Waiting()
        with self._pending_lock:
            self._pending[rid] = waiting
        self._send(request(rid))
        if not waiting.event.wait(timeout_s):
            with self._pending_lock:
                self._pending.pop(rid, None)
            raise StaleStateError(f"{self.bus_name}: the servo process did not answer within {timeout_s} s")
        answer = waiting.answer
        assert answer is not None
        if answer.error is not None:
            raise answer.error.exception(DriverError)
        return answer.sent

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
        joints, missing = {}, {}
        for j, joint in enumerate(JOINTS):
            b = _joint_base(j)
            if v[b + _J["missing"]] == 1.0:  # its description comes with the child's fault message
                missing[joint] = self.missing.get(joint, f"joint {joint} on {self.bus_name}: not answering")
                continue
            joints[joint] = JointState(position=float(v[b]), velocity=float(v[b + 1]), moving=bool(v[b + 2]),
                                       torque_on=bool(v[b + 3]), hardware_error_bits=int(v[b + 4]),
                                       temperature_c=float(v[b + 5]), input_voltage_v=float(v[b + 6]),
                                       hardware_errors=self._decode_errors(int(v[b + 4])))
        return BusState(time_s=float(v[_H["time_s"]]), joints=joints, missing=missing)

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
        if not self.is_alive():  # dead, or a new one not cycling yet: nothing queued for it to send later
            raise ServoLoopStoppedError(f"{self.name}: the servo process is not running")
        sent = self._request(lambda rid: WriteGoals(rid, dict(goals)), timeout_s)
        assert sent is not None
        return sent

    def read_state(self) -> BusState:
        return complete(self.fresh_state(), self.bus_name)

    def write_goals(self, goals: Mapping[str, float]) -> dict[str, float]:
        return self.request_goals(goals)

    def set_torque(self, on: bool, timeout_s: float = 2.0) -> None:
        self._request(lambda rid: SwitchTorque(rid, on), timeout_s)
        self._torque_wanted = on

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

    def timing(self) -> JSONObject:
        """Counters, and the period quantiles over the last `HISTORY` cycles (computed here, at
        most every `ServoLoop.TIMING_MAX_AGE_S`)."""
        v = self._shared.read()
        out: JSONObject = {"rate_hz": round(1.0 / self.period_s, 3), "pid": self._process.pid,
                               "restarts": self.restarts}
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
        self._request(lambda rid: InjectFault(rid, ServoFault(fault), joint, bits), timeout_s)

    def inject_bus_down(self) -> None:
        self.inject("bus_down")

    def restore_bus(self) -> None:
        self.inject("restore_bus")

    def inject_hardware_error(self, joint: str, bits: int) -> None:
        self.inject("hardware_error", joint, bits)

    def inject_power_loss(self) -> None:
        self.inject("power_loss")

    def restore_power(self, bits: int = 0) -> None:
        self.inject("power_back", bits=bits)

    def remove_servo(self, joint: str) -> None:
        self.inject("servo_remove", joint)

    def add_servo(self, joint: str) -> None:
        self.inject("servo_add", joint)

