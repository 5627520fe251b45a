"""What the Dynamixel buses of both protocols share: the port, retried transactions, blamed
group reads and the model check, through dynamixel-sdk 4.1.0.

`DynamixelBusBase` is the common base of `drivers.dynamixel.bus_v2.DynamixelBus` (Protocol 2.0,
X-series) and `drivers.dynamixel.bus_v1.Protocol1Bus` (Protocol 1.0: AX, RX, MX);
`drivers.dynamixel.factory` picks one of them by `servo_bus.protocol`. A bus drives the
servos of its own protocol only (`check_config`). The SDK's classes it talks through, with
their pitfalls fixed, are in `drivers.dynamixel.sdk`.

The pitfalls of dynamixel-sdk 4.1.0 both buses meet, handled here and in `drivers.dynamixel.sdk`
(the Protocol 2.0 ones: `drivers.dynamixel.bus_v2`):

* `GroupSyncRead` waits for the servos' replies one id after another, throws away any
  other id's reply that comes while it waits, and stops at the first id that fails: the
  servo it names is whichever it was waiting for when time ran out, often one held up
  behind the servo that was really late. `SyncRead` keeps every reply that arrives under
  its own id and says per id what happened; a failed sync read names the servo(s) that did
  not answer or answered corrupt, judged over all its attempts (`blame_sync_read`).
* A vanished adapter makes the SDK raise a raw `OSError` (or `termios.error`, which is
  not one, from its tcflush) and leaves `port.is_using` set for good: both, and a
  COMM_PORT_BUSY result, become `BusDownError`, the `PortHandler` is discarded, and the
  base class reopens a new one with back-off.
* The SDK computes reply timeouts from a hard-coded 16 ms latency timer and reads a
  `timeout=0` pyserial port in a busy loop: `BlockingPortHandler` waits in `select()`
  until bytes arrive or the deadline passes, on the monotonic clock, with a timeout
  computed from the adapter's real latency timer and the Return Delay Time.
"""
from __future__ import annotations

import abc
import logging
from collections.abc import Callable, Iterable
from typing import Any, ClassVar, NoReturn, TypeVar

from dynamixel_sdk import (
    COMM_PORT_BUSY,
    COMM_RX_CORRUPT,
    COMM_RX_TIMEOUT,
    COMM_SUCCESS,
    GroupSyncWrite,
    PacketHandler,
)

from drivers.clock import SYSTEM_CLOCK, Clock
from drivers.dynamixel.tables.v1 import P1_MODELS
from drivers.dynamixel.tables import x_series
from drivers.dynamixel.tables.x_series import KNOWN_MODEL_NAMES, X_MODELS
from drivers.dynamixel.sdk import (
    PORT_ERRORS,
    BlockingPortHandler,
    GroupRead,
    SyncReadAttempt,
    adapter_latency_timer_ms,
    blame_sync_read,
    port_access_hint,
    status_ids,
)
from drivers.errors import (
    BusDownError,
    ServoCommError,
    ServoConfigError,
    ServoError,
    ServoModelError,
    ServoTimeoutError,
    blaming,
)
from drivers.servo.bus import ServoBus, ServoBusConfig
from drivers.servo.joints import JOINTS

log = logging.getLogger(__name__)

_T = TypeVar("_T")

_COMM_TIMEOUT_RESULTS = {COMM_RX_TIMEOUT}


class DynamixelBusBase(ServoBus):
    """Four Dynamixel servos of one protocol on one port; see the module docstring.
    `read_method` says how the bus reads the state once open."""

    CONFIG_KEYS = frozenset({"baud", "protocol", "retries", "watchdog_ms", "return_delay_us", "latency_timer_ms",
                             "reboot_timeout_s"})
    JOINT_CONFIG_KEYS = frozenset({"model", "profile_velocity", "profile_acceleration"})
    # The models of both protocols: a model of the other protocol is refused by
    # `check_config`, with a message saying which protocol drives it.
    MODELS = frozenset(X_MODELS) | frozenset(P1_MODELS)
    PROTOCOL: ClassVar[float]
    FIRMWARE_ADDRESS: ClassVar[int]
    # Status error-byte bits that report a hardware error rather than a refused instruction.
    STATUS_HARDWARE_BITS: ClassVar[int]

    # Host scheduling margin added to every reply timeout: a Python thread on a busy
    # 2-core machine can be late by a couple of milliseconds.
    REPLY_SLACK_MS = 3.0
    REBOOT_POLL_S = 0.05

    @classmethod
    def decode_hardware_error(cls, bits: int) -> tuple[str, ...]:
        """The X-series Hardware Error Status meanings, which Protocol 1.0 servos share."""
        return x_series.decode_hardware_error(bits)

    def __init__(self, config: ServoBusConfig, *, clock: Clock = SYSTEM_CLOCK, name: str | None = None) -> None:
        super().__init__(config, clock=clock, name=name)
        self.check_config(config)
        self._ids = {joint: config.joints[joint].servo_id for joint in JOINTS}
        self._joint_of = {servo_id: joint for joint, servo_id in self._ids.items()}
        self._packet = PacketHandler(self.PROTOCOL)
        self._port: BlockingPortHandler | None = None
        self._sync_write: GroupSyncWrite | None = None
        self.read_method = "sync read"
        self.firmware: dict[str, int] = {}

    @classmethod
    def check_config(cls, config: ServoBusConfig) -> None:
        """Refuse a config of the other protocol, and what this protocol's servos cannot do."""
        if config.protocol != cls.PROTOCOL:
            raise ServoConfigError(
                f"{config.key_path}.protocol: got {config.protocol:g}, expected {cls.PROTOCOL:g}: "
                f"{cls.__module__}.{cls.__qualname__} drives Protocol {cls.PROTOCOL:g} servos (the 'dynamixel' "
                "backend picks the bus by protocol)")
        cls._check_protocol_config(config)

    @classmethod
    @abc.abstractmethod
    def _check_protocol_config(cls, config: ServoBusConfig) -> None:
        """Refuse what the servos of this protocol cannot do, naming the key."""

    # -- hooks ---------------------------------------------------------------------------
    def _connect(self) -> None:
        latency_ms = self.config.latency_timer_ms
        actual_ms = adapter_latency_timer_ms(self.config.port)
        if actual_ms is not None and actual_ms > latency_ms:
            log.warning("%s: the adapter's latency timer is %g ms (config says %g ms): every read waits that "
                        "long; install udev/99-headctl-servos.rules to set it to 1 ms", self.name, actual_ms,
                        latency_ms)
            latency_ms = actual_ms
        slack_ms = self.REPLY_SLACK_MS + len(JOINTS) * self.config.return_delay_us / 1000.0
        port = BlockingPortHandler(self.config.port, latency_ms, slack_ms)
        self._port = port
        try:
            opened = port.setBaudRate(self.config.baud)  # opens the port at that rate
        except PORT_ERRORS as err:
            raise BusDownError(f"{self.name}: {port_access_hint(self.config.port, err)}") from err
        if not opened:
            raise ServoConfigError(f"{self.config.key_path}.baud: dynamixel-sdk refused {self.config.baud} baud")

    def _probe_servo(self, joint: str) -> None:
        self._check_model(joint)

    def _joints_changed(self) -> None:
        self._setup_group_transactions(self._require(self._port))

    @property
    def _present_ids(self) -> dict[str, int]:
        """joint -> id of the joints that answer, in `JOINTS` order."""
        return {joint: self._ids[joint] for joint in self.present_joints}

    @abc.abstractmethod
    def _setup_group_transactions(self, port: BlockingPortHandler) -> None:
        """The per-cycle state read and goal write over the present joints' servos, which
        are configured."""

    def _disconnect(self) -> None:
        port, self._port = self._port, None
        self._sync_write = None
        if port is None or port.ser is None:
            return
        try:
            port.closePort()
        except PORT_ERRORS as err:  # closing a vanished adapter can fail; it is gone either way
            log.debug("%s: closing the port failed: %s", self.name, err)

    def _configure(self, joints: Iterable[str]) -> None:
        for joint in joints:
            self._configure_servo(joint)

    def _send_sync_write(self, sync_write: GroupSyncWrite) -> None:
        try:
            result = sync_write.txPacket()
        except PORT_ERRORS as err:
            raise BusDownError(f"{self.name}: port failed writing goals: {err}") from err
        if result != COMM_SUCCESS:
            raise ServoCommError(f"{self.name}: goal sync write failed: {self._packet.getTxRxResult(result)}")

    # -- servo setup -----------------------------------------------------------------------
    def _check_model(self, joint: str) -> None:
        servo_id = self._ids[joint]
        model_number, _error = self._transact(joint, "ping", lambda: self._packet.ping(self._port, servo_id))
        expected_name = self.config.joints[joint].model
        expected = self._model_number(expected_name)
        if model_number != expected:
            found = KNOWN_MODEL_NAMES.get(model_number, "an unknown model")
            raise ServoModelError(
                f"{self.describe(joint)}: found model number {model_number} ({found}), but "
                f"{self.config.joint_path(joint)}.model is {expected_name} ({expected})"
            )
        self.firmware[joint] = self._read(joint, self.FIRMWARE_ADDRESS, 1)

    @abc.abstractmethod
    def _model_number(self, name: str) -> int:
        """The model number a servo of model `name` answers a ping with."""

    @abc.abstractmethod
    def _configure_servo(self, joint: str) -> None:
        """Apply the joint's settings, writing EEPROM only where it differs."""

    # -- transactions ----------------------------------------------------------------------
    def _group_read(self, first: GroupRead, then: GroupRead, what: str) -> GroupRead:
        """One group read of every servo with bounded retries: `first` on the first attempt,
        `then` on the retries. Returns the group whose attempt succeeded; raises naming the
        servo(s) to blame when every attempt failed."""
        result = COMM_SUCCESS
        attempts: list[SyncReadAttempt] = []
        for attempt in range(self.config.retries + 1):
            group = first if attempt == 0 else then
            try:
                result = group.txRxPacket()
            except PORT_ERRORS as err:
                raise BusDownError(f"{self.name}: port failed during {what}: {err}") from err
            if result == COMM_SUCCESS:
                return group
            if result == COMM_PORT_BUSY:
                raise BusDownError(f"{self.name}: the SDK port is stuck busy after a port failure ({what})")
            late = tuple(group.strays) + status_ids(self._drain(), self.PROTOCOL)
            attempts.append(SyncReadAttempt(frozenset(group.answered), dict(group.failures), late))
            log.debug("%s: %s attempt %d: %s; replies late from %s", self.name, what, attempt + 1,
                      ", ".join(f"id {i}: {self._packet.getTxRxResult(r)}" for i, r in group.failures.items())
                      or self._packet.getTxRxResult(result), list(late) or "none")
        self._raise_sync_read(attempts, result, what)

    def _read(self, joint: str, address: int, size: int) -> int:
        return int.from_bytes(self._read_bytes(joint, address, size), "little")

    def _read_bytes(self, joint: str, address: int, size: int) -> bytes:
        servo_id = self._ids[joint]
        def read() -> tuple[Any, int, int]:
            data, result, error = self._packet.readTxRx(self._port, servo_id, address, size)
            if result == COMM_SUCCESS and len(data) != size:
                result = COMM_RX_CORRUPT  # a stray reply of another request: try again
            return data, result, error

        data, _error = self._transact(joint, f"read of {size} byte(s) at address {address}", read)
        return bytes(data)

    def _write(self, joint: str, address: int, size: int, value: int) -> int:
        """Write one item; returns the status error byte (its Alert bit may be set)."""
        servo_id = self._ids[joint]
        data = list(value.to_bytes(size, "little", signed=value < 0))
        _none, error = self._transact(joint, f"write of {value} to address {address}",
                                      lambda: (None, *self._packet.writeTxRx(self._port, servo_id, address, size, data)))
        return error

    def _transact(self, joint: str, what: str, call: Callable[[], tuple[Any, int, int]]) -> tuple[Any, int]:
        """One request/reply with bounded retries; returns (value, status error byte).

        The Alert bit only says a hardware error is present (read_state reports it); any
        other error number means the servo refused the instruction.
        """
        self._require(self._port)
        result = COMM_SUCCESS
        for attempt in range(self.config.retries + 1):
            try:
                value, result, error = call()
            except PORT_ERRORS as err:
                raise BusDownError(f"{self.name}: port failed during {what} ({self.describe(joint)}): {err}") from err
            if result == COMM_PORT_BUSY:
                raise BusDownError(f"{self.name}: the SDK port is stuck busy after a port failure ({what})")
            if result != COMM_SUCCESS:
                log.debug("%s: %s attempt %d: %s", self.describe(joint), what, attempt + 1,
                          self._packet.getTxRxResult(result))
                self._drain()
                continue
            if error & ~self.STATUS_HARDWARE_BITS:
                refusal = self._packet.getRxPacketError(error & ~self.STATUS_HARDWARE_BITS)
                raise ServoError(f"{self.describe(joint)}: {what} refused: {refusal}")
            return value, error
        self._raise_comm(joint, what, result)

    def _raise_sync_read(self, attempts: list[SyncReadAttempt], result: int, read_name: str = "sync read") -> NoReturn:
        """Raise for a group read that failed every attempt, naming the servo(s) to blame."""
        blamed = blame_sync_read(attempts) if attempts and attempts[-1].failures else {}
        if not blamed:  # the request itself failed to go out: the bus, not a servo
            self._raise_comm(None, read_name, result)
        late = {servo_id for attempt in attempts for servo_id in attempt.late}
        order = list(self._present_ids.values())
        held: list[int] = []
        timeouts = all(r in _COMM_TIMEOUT_RESULTS for r in blamed.values())
        first_late = next((i for i in order if i in blamed and i in late), None)
        if len(blamed) > 1 and timeouts and first_late is not None:
            # Servos answer in turn: those after a late servo are held up behind it and
            # come late too. It is to blame, with any silent one before it.
            held = [i for i in blamed if order.index(i) > order.index(first_late)]
            blamed = {i: r for i, r in blamed.items() if i not in held}

        def what(servo_id: int, servo_result: int) -> str:
            text: str = self._packet.getTxRxResult(servo_result)
            notes = ["its reply came after the timeout"] if servo_id in late else []
            if held and servo_id == first_late:
                notes.append(f"id{'s' if len(held) > 1 else ''} {', '.join(map(str, held))}, after it in turn, "
                             f"held up behind it")
            return text + (f" ({'; '.join(notes)})" if notes else "")

        failed = f"{read_name} failed after {self.config.retries + 1} attempt(s)"
        if len(blamed) == len(order) and not any(attempt.answered for attempt in attempts):
            # No servo ever answered, and none late: the first in turn, which the others
            # wait for, or a bus without power.
            first_joint = next(iter(self._present_ids))
            message = (f"{self.describe(first_joint)}: {failed}: no servo answered: this one, the first in turn "
                       f"(the others wait for its reply), or all of them (power, wiring): "
                       f"{self._packet.getTxRxResult(result)}")
        elif len(blamed) == 1:
            (servo_id, servo_result), = blamed.items()
            joint = self._joint_of.get(servo_id)
            where = self.describe(joint) if joint else f"id {servo_id} on {self.name}"
            message = f"{where}: {failed}: {what(servo_id, servo_result)}"
        else:
            each = "; ".join(
                f"joint {self._joint_of.get(i, '?')} (id {i}): {what(i, r)}" for i, r in blamed.items()
            )
            message = f"{self.name}: {failed}: {each}"
        raise blaming(ServoTimeoutError(message) if timeouts else ServoCommError(message),
                      *(j for j in JOINTS if self._ids[j] in blamed))

    def _raise_comm(self, joint: str | None, what: str, result: int) -> NoReturn:
        where = self.describe(joint) if joint else self.name
        message = (f"{where}: {what} failed after {self.config.retries + 1} attempt(s): "
                   f"{self._packet.getTxRxResult(result)}")
        raise blaming(ServoTimeoutError(message) if result in _COMM_TIMEOUT_RESULTS else ServoCommError(message),
                      *((joint,) if joint else ()))

    def _drain(self) -> bytes:
        """Discard late replies before a retry; returns them."""
        try:
            discarded = self._require(self._port).drain_late_bytes()
        except PORT_ERRORS as err:
            raise BusDownError(f"{self.name}: port failed while draining late replies: {err}") from err
        if discarded:
            log.debug("%s: discarded %d bytes of late replies before retrying", self.name, len(discarded))
        return discarded

    def _require(self, thing: _T | None) -> _T:
        if thing is None:
            raise BusDownError(f"{self.name}: the port is not open")
        return thing
