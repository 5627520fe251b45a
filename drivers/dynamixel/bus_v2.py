"""The Dynamixel backend: Protocol 2.0 X-series servos through dynamixel-sdk 4.1.0.

This module owns the `DynamixelBus` backend of `drivers.servo.bus.ServoBus` (the bus scan is
`drivers.dynamixel.scan`).
A `protocol: 1.0` config gets its subclass `drivers.dynamixel.bus_v1.Protocol1Bus`, which shares
the port, retried transactions, blamed group reads and model checks defined here. A cycle
reads every servo in one Fast Sync Read where all have it (firmware >= 45, confirmed by one
such read once configured), else one Sync Read, which also retries a failed Fast Sync Read. The control table it drives by is `drivers.dynamixel.tables.x_series`,
which the emulator's servos (`drivers.dynamixel.emulator.servo_v2`) serve too; the SDK's classes it talks
through, with their pitfalls fixed, are in `drivers.dynamixel.sdk`.

How the known pitfalls of dynamixel-sdk 4.1.0 are handled (here and in `drivers.dynamixel.sdk`):

* `GroupSyncRead` drops each servo's status error byte (the Alert bit). The sync-read
  block is laid out with indirect addressing so Hardware Error Status (70), Torque
  Enable, Bus Watchdog and the servo's own ID (a check that the mapping survived) come
  back in the same transaction as position and velocity; `SyncRead` also keeps the error
  byte.
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
* Return Delay Time, Drive Mode, Operating Mode and position limits live in EEPROM,
  writable only with torque off: they are written only when they differ, and if torque
  is on the servo is first held (goal = present) and torque restored after.
* Torque on always follows goal = present (in `ServoBus`), so a stale goal never jumps.
* The Bus Watchdog (98) is armed while torque is on when configured, and re-armed after
  it fired (it reads 255 then and the servo ignores goals until cleared).
"""
from __future__ import annotations

import logging
import struct
from collections.abc import Callable, Iterable, Mapping
from typing import Any, NoReturn, TypeVar

from dynamixel_sdk import (
    COMM_PORT_BUSY,
    COMM_RX_CORRUPT,
    COMM_RX_TIMEOUT,
    COMM_SUCCESS,
    GroupSyncWrite,
    PacketHandler,
)

from drivers.clock import SYSTEM_CLOCK, Clock
from drivers.dynamixel.tables.x_series import (
    DPS2_PER_ACCELERATION_UNIT,
    DPS_PER_VELOCITY_UNIT,
    FAST_SYNC_READ_MIN_FIRMWARE,
    KNOWN_MODEL_NAMES,
    MS_PER_WATCHDOG_UNIT,
    OPERATING_MODE_POSITION,
    READ_BLOCK_ADDRESSES,
    READ_BLOCK_FORMAT,
    READ_BLOCK_SIZE,
    US_PER_RETURN_DELAY_UNIT,
    VOLTS_PER_VOLTAGE_UNIT,
    WATCHDOG_FIRED,
    X_MODELS,
    XAddr,
    deg_to_ticks,
    ticks_to_deg,
)
from drivers.dynamixel.tables.v1 import P1_MODELS
from drivers.dynamixel.protocol.v2 import ERRBIT_ALERT
from drivers.dynamixel.sdk import (
    PORT_ERRORS,
    BlockingPortHandler,
    FastSyncRead,
    GroupRead,
    SyncRead,
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
    ServoHardwareError,
    ServoModelError,
    ServoTimeoutError,
)
from drivers.servo.bus import JOINTS, JointState, ServoBus, ServoBusConfig, decode_hardware_error

log = logging.getLogger(__name__)

_T = TypeVar("_T")

_COMM_TIMEOUT_RESULTS = {COMM_RX_TIMEOUT}


# --- the backend -----------------------------------------------------------------------
class DynamixelBus(ServoBus):
    """Four Protocol 2.0 X-series servos on one port; see the module docstring.

    Constructed with a `protocol: 1.0` config it is a `drivers.dynamixel.bus_v1.Protocol1Bus`.
    `fast_sync_read=False` keeps to Sync Read even where the servos have Fast Sync Read
    (for comparisons); `read_method` says which one the bus uses once open.
    """

    capabilities = frozenset({"reboot", "hardware_error", "temperature", "input_voltage", "watchdog"})
    CONFIG_KEYS = frozenset({"baud", "protocol", "retries", "watchdog_ms", "return_delay_us", "latency_timer_ms",
                             "reboot_timeout_s"})
    JOINT_CONFIG_KEYS = frozenset({"model", "profile_velocity", "profile_acceleration"})
    MODELS = frozenset(X_MODELS) | frozenset(P1_MODELS)
    PROTOCOL = 2.0
    FIRMWARE_ADDRESS = XAddr.FIRMWARE_VERSION
    # Status error-byte bits that report a hardware error rather than a refused instruction.
    STATUS_HARDWARE_BITS = ERRBIT_ALERT

    # Host scheduling margin added to every reply timeout: a Python thread on a busy
    # 2-core machine can be late by a couple of milliseconds.
    REPLY_SLACK_MS = 3.0
    REBOOT_POLL_S = 0.05

    def __new__(cls, config: ServoBusConfig, **kwargs: Any) -> "DynamixelBus":
        if cls is DynamixelBus and config.protocol == 1.0:
            from drivers.dynamixel.bus_v1 import Protocol1Bus

            bus: DynamixelBus = super().__new__(Protocol1Bus)
            return bus
        return super().__new__(cls)

    def __init__(self, config: ServoBusConfig, *, clock: Clock = SYSTEM_CLOCK, name: str | None = None,
                 fast_sync_read: bool = True) -> None:
        super().__init__(config, clock=clock, name=name)
        self.check_config(config)
        self._ids = {joint: config.joints[joint].servo_id for joint in JOINTS}
        self._joint_of = {servo_id: joint for joint, servo_id in self._ids.items()}
        self._packet = PacketHandler(self.PROTOCOL)
        self._port: BlockingPortHandler | None = None
        self._sync_read: SyncRead | None = None
        self._fast_read: FastSyncRead | None = None
        self._fast_read_probed = False
        self._sync_write: GroupSyncWrite | None = None
        self._want_fast_read = fast_sync_read
        self.read_method = "sync read"
        self.firmware: dict[str, int] = {}

    @classmethod
    def check_config(cls, config: ServoBusConfig) -> None:
        """Refuse what the servos of `config.protocol` cannot do: models of the other
        protocol (Protocol 1.0 settings: `drivers.dynamixel.bus_v1.check_protocol1_config`)."""
        if config.protocol == 1.0:
            from drivers.dynamixel.bus_v1 import check_protocol1_config

            check_protocol1_config(config)
            return
        for joint, jc in config.joints.items():
            if jc.model not in X_MODELS:
                raise ServoConfigError(
                    f"{config.joint_path(joint)}.model: got {jc.model!r}, expected one of "
                    f"{', '.join(sorted(X_MODELS))} (the models the 'dynamixel' backend drives) on Protocol 2.0; "
                    "Protocol 1.0 models need protocol: 1.0"
                )

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
        for joint in JOINTS:
            self._check_model(joint)
        self._setup_group_transactions(port)

    def _setup_group_transactions(self, port: BlockingPortHandler) -> None:
        """The per-cycle state read and goal write. Whether the read can be a Fast Sync
        Read is found out once the servos are configured (their Return Delay Time is in the
        reply timeout only then)."""
        self._sync_read = SyncRead(port, self._packet, XAddr.INDIRECT_DATA_1, READ_BLOCK_SIZE)
        for servo_id in self._ids.values():
            self._sync_read.addParam(servo_id)
        self._fast_read = None
        self._fast_read_probed = False
        self.read_method = "sync read"
        self._sync_write = GroupSyncWrite(port, self._packet, XAddr.GOAL_POSITION, 4)

    def _probe_fast_sync_read(self) -> None:
        """Fast Sync Read where every servo's firmware has it and one read of their ids
        through it comes back right; else Sync Read."""
        self._fast_read_probed = True
        port = self._require(self._port)
        ids = list(self._ids.values())
        old = {j: fw for j, fw in self.firmware.items() if fw < FAST_SYNC_READ_MIN_FIRMWARE}
        if self._want_fast_read and not old:
            # The firmware says it has it; one read of the servos' ids confirms it.
            probe = FastSyncRead(port, XAddr.ID, 1, ids)
            try:
                result = probe.txRxPacket()
            except PORT_ERRORS as err:
                raise BusDownError(f"{self.name}: port failed during the fast sync read probe: {err}") from err
            if result == COMM_SUCCESS and all(probe.data_dict[i] == bytes([i]) for i in ids):
                self._fast_read = FastSyncRead(port, XAddr.INDIRECT_DATA_1, READ_BLOCK_SIZE, ids)
                self.read_method = "fast sync read"
            else:
                self._drain()
                log.warning("%s: the servos' firmware has Fast Sync Read but the probe failed (%s): using Sync "
                            "Read", self.name, self._packet.getTxRxResult(result))
        elif old:
            log.info("%s: Sync Read (Fast Sync Read needs firmware >= %d: %s)", self.name, FAST_SYNC_READ_MIN_FIRMWARE,
                     ", ".join(f"{self.describe(j)} has {fw}" for j, fw in old.items()))
        log.debug("%s: reading state by %s", self.name, self.read_method)

    def _disconnect(self) -> None:
        port, self._port = self._port, None
        self._sync_read = self._sync_write = self._fast_read = None
        if port is None or port.ser is None:
            return
        try:
            port.closePort()
        except PORT_ERRORS as err:  # closing a vanished adapter can fail; it is gone either way
            log.debug("%s: closing the port failed: %s", self.name, err)

    def _configure(self, joints: Iterable[str]) -> None:
        for joint in joints:
            self._configure_servo(joint)
        if not self._fast_read_probed and self.PROTOCOL == 2.0:
            self._probe_fast_sync_read()

    def _read_servos(self) -> dict[str, JointState]:
        states = self._sync_read_states()
        remapped = [j for j, s in states.items() if s is None]
        if remapped:
            # The indirect mapping is gone (the servo lost power and came back with RAM
            # defaults): program it again and read once more.
            for joint in remapped:
                log.warning("%s: indirect mapping lost (servo power cycled?); configuring it again",
                            self.describe(joint))
                self._configure_servo(joint)
            states = self._sync_read_states()
            bad = [j for j, s in states.items() if s is None]
            if bad:
                raise ServoCommError(f"{self.describe(bad[0])}: sync-read block still inconsistent after reconfiguring")
        return {joint: state for joint, state in states.items() if state is not None}

    def _write_servo_goals(self, goals_deg: Mapping[str, float]) -> None:
        sync_write = self._require(self._sync_write)
        sync_write.clearParam()
        for joint, servo_deg in goals_deg.items():
            sync_write.addParam(self._ids[joint], list(struct.pack("<i", deg_to_ticks(servo_deg))))
        self._send_sync_write(sync_write)

    def _send_sync_write(self, sync_write: GroupSyncWrite) -> None:
        try:
            result = sync_write.txPacket()
        except PORT_ERRORS as err:
            raise BusDownError(f"{self.name}: port failed writing goals: {err}") from err
        if result != COMM_SUCCESS:
            raise ServoCommError(f"{self.name}: goal sync write failed: {self._packet.getTxRxResult(result)}")

    def _set_torque(self, joints: Iterable[str], on: bool) -> None:
        watchdog_units = self.config.watchdog_ms // MS_PER_WATCHDOG_UNIT
        for joint in joints:
            if on:
                if self._write(joint, XAddr.TORQUE_ENABLE, 1, 1) & ERRBIT_ALERT \
                        and self._read(joint, XAddr.TORQUE_ENABLE, 1) != 1:
                    # A servo in shutdown accepts the write and stays limp.
                    bits = self._read(joint, XAddr.HARDWARE_ERROR_STATUS, 1)
                    raise ServoHardwareError(
                        f"{self.describe(joint)}: torque refused, hardware error 0x{bits:02x}: "
                        + "; ".join(decode_hardware_error(bits))
                    )
                if watchdog_units:
                    self._write(joint, XAddr.BUS_WATCHDOG, 1, watchdog_units)
            else:
                if watchdog_units:
                    self._write(joint, XAddr.BUS_WATCHDOG, 1, 0)
                self._write(joint, XAddr.TORQUE_ENABLE, 1, 0)

    def _reboot_servo(self, joint: str) -> None:
        servo_id = self._ids[joint]
        self._transact(joint, "reboot", lambda: (None, *self._packet.reboot(self._port, servo_id)))
        deadline_s = self.clock.monotonic() + self.config.reboot_timeout_s
        while True:
            self.clock.sleep(self.REBOOT_POLL_S)  # the servo boots for a few hundred ms
            try:
                _model, result, _error = self._packet.ping(self._require(self._port), servo_id)
            except PORT_ERRORS as err:
                raise BusDownError(f"{self.name}: port failed while {self.describe(joint)} rebooted: {err}") from err
            if result == COMM_SUCCESS:
                return
            if self.clock.monotonic() > deadline_s:
                raise ServoTimeoutError(
                    f"{self.describe(joint)}: no answer {self.config.reboot_timeout_s:g} s after reboot"
                )

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

    def _model_number(self, name: str) -> int:
        return X_MODELS[name]

    def _configure_servo(self, joint: str) -> None:
        """Apply the joint's settings, writing EEPROM only where it differs, torque kept."""
        jc = self.config.joints[joint]
        limit_ticks = sorted(deg_to_ticks(jc.servo_angle(a)) for a in (jc.min_angle, jc.max_angle))
        # (address, size, value) that need torque off: EEPROM and the indirect addresses.
        wanted = [
            (XAddr.RETURN_DELAY_TIME, 1, self.config.return_delay_us // US_PER_RETURN_DELAY_UNIT),
            (XAddr.DRIVE_MODE, 1, 0),  # direction is applied in software; velocity-based profile
            (XAddr.OPERATING_MODE, 1, OPERATING_MODE_POSITION),
            (XAddr.MAX_POSITION_LIMIT, 4, limit_ticks[1]),
            (XAddr.MIN_POSITION_LIMIT, 4, limit_ticks[0]),
        ] + [(XAddr.INDIRECT_ADDRESS_1 + 2 * i, 2, addr) for i, addr in enumerate(READ_BLOCK_ADDRESSES)]
        eeprom = self._read_bytes(joint, 0, XAddr.EEPROM_END)
        indirect = self._read_bytes(joint, XAddr.INDIRECT_ADDRESS_1, 2 * READ_BLOCK_SIZE)

        def current(addr: int, size: int) -> int:
            block, base = (eeprom, 0) if addr < XAddr.EEPROM_END else (indirect, XAddr.INDIRECT_ADDRESS_1)
            return int.from_bytes(block[addr - base: addr - base + size], "little")

        changes = [(addr, size, value) for addr, size, value in wanted if current(addr, size) != value]
        if changes:
            torque_on = self._read(joint, XAddr.TORQUE_ENABLE, 1) == 1
            if torque_on:
                # Hold where it is, so that torque coming back on does not move it.
                log.info("%s: torque briefly off to write %d setting(s)", self.describe(joint), len(changes))
                self._write(joint, XAddr.GOAL_POSITION, 4, self._read(joint, XAddr.PRESENT_POSITION, 4))
                self._write(joint, XAddr.TORQUE_ENABLE, 1, 0)
            for addr, size, value in changes:
                log.debug("%s: address %d := %d", self.describe(joint), addr, value)
                self._write(joint, addr, size, value)
            if torque_on:
                self._write(joint, XAddr.TORQUE_ENABLE, 1, 1)
        # RAM settings, writable any time. The watchdog is cleared (it also clears a fired
        # one) and armed again when torque goes on.
        self._write(joint, XAddr.BUS_WATCHDOG, 1, 0)
        self._write(joint, XAddr.PROFILE_ACCELERATION, 4, round(jc.profile_acceleration / DPS2_PER_ACCELERATION_UNIT))
        self._write(joint, XAddr.PROFILE_VELOCITY, 4, round(jc.profile_velocity / DPS_PER_VELOCITY_UNIT))

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

    def _sync_read_states(self) -> dict[str, JointState | None]:
        plain = self._require(self._sync_read)
        sync_read = self._group_read(self._fast_read or plain, plain, "sync read")
        states: dict[str, JointState | None] = {}
        watchdog_units = self.config.watchdog_ms // MS_PER_WATCHDOG_UNIT
        for joint, servo_id in self._ids.items():
            (mapped_id, hw_error, torque, watchdog, moving, velocity, position, voltage,
             temperature) = READ_BLOCK_FORMAT.unpack(bytes(sync_read.data_dict[servo_id]))
            if mapped_id != servo_id:
                states[joint] = None
                continue
            if sync_read.errors.get(servo_id, 0) & ERRBIT_ALERT and not hw_error:
                hw_error = self._read(joint, XAddr.HARDWARE_ERROR_STATUS, 1)
            if watchdog == WATCHDOG_FIRED:
                log.warning("%s: bus watchdog fired (the host was silent too long): servo stopped; re-arming",
                            self.describe(joint))
                self._write(joint, XAddr.BUS_WATCHDOG, 1, 0)
                if torque and watchdog_units:
                    self._write(joint, XAddr.BUS_WATCHDOG, 1, watchdog_units)
            states[joint] = JointState(
                position=ticks_to_deg(position),
                velocity=velocity * DPS_PER_VELOCITY_UNIT,
                moving=bool(moving),
                torque_on=bool(torque),
                hardware_error_bits=hw_error,
                temperature_c=float(temperature),
                input_voltage_v=voltage * VOLTS_PER_VOLTAGE_UNIT,
            )
        return states

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
        order = list(self._ids.values())
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
            first_joint = next(iter(self._ids))
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
        if timeouts:
            raise ServoTimeoutError(message)
        raise ServoCommError(message)

    def _raise_comm(self, joint: str | None, what: str, result: int) -> NoReturn:
        where = self.describe(joint) if joint else self.name
        message = (f"{where}: {what} failed after {self.config.retries + 1} attempt(s): "
                   f"{self._packet.getTxRxResult(result)}")
        if result in _COMM_TIMEOUT_RESULTS:
            raise ServoTimeoutError(message)
        raise ServoCommError(message)

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
