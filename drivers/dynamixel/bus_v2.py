"""The Dynamixel backend on Protocol 2.0: X-series servos through dynamixel-sdk 4.1.0.

`DynamixelBus` drives the control table of `drivers.dynamixel.tables.x_series`, which the
emulator's servos (`drivers.dynamixel.emulator.servo_v2`) serve too; the port, retried
transactions, blamed group reads and the model check it shares with the Protocol 1.0 bus
are in `drivers.dynamixel.bus_base`, and `drivers.dynamixel.factory` picks between the two
(the bus scan is `drivers.dynamixel.scan`). A cycle reads every servo in one Fast Sync Read
where all have it (firmware >= 45, confirmed by one such read once configured), else one
Sync Read, which also retries a failed Fast Sync Read.

The pitfalls of dynamixel-sdk 4.1.0 handled here (the others: `drivers.dynamixel.bus_base`):

* `GroupSyncRead` drops each servo's status error byte (the Alert bit). The sync-read
  block is laid out with indirect addressing so Hardware Error Status (70), Torque
  Enable, Bus Watchdog and the servo's own ID (a check that the mapping survived) come
  back in the same transaction as position and velocity; `SyncRead` also keeps the error
  byte.
* Return Delay Time, Drive Mode, Operating Mode and position limits live in EEPROM,
  writable only with torque off: they are written only when they differ, and if torque
  is on the servo is first held (goal = present) and torque restored after.
* Torque on always follows goal = present (in `ServoBus`), so a stale goal never jumps.
* The Bus Watchdog (98) is armed while torque is on when configured, and re-armed after
  it fired (it reads 255 then and the servo ignores goals until cleared).
"""
from __future__ import annotations

import dataclasses
import logging
import struct
from collections.abc import Iterable, Mapping

from dynamixel_sdk import COMM_SUCCESS, GroupSyncWrite

from drivers.clock import SYSTEM_CLOCK, Clock
from drivers.dynamixel.tables.x_series import (
    DPS2_PER_ACCELERATION_UNIT,
    DPS_PER_VELOCITY_UNIT,
    FAST_SYNC_READ_MIN_FIRMWARE,
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
from drivers.dynamixel.bus_base import DynamixelBusBase
from drivers.dynamixel.protocol.v2 import ERRBIT_ALERT
from drivers.dynamixel.sdk import PORT_ERRORS, BlockingPortHandler, FastSyncRead, SyncRead
from drivers.errors import BusDownError, ServoCommError, ServoConfigError, ServoHardwareError, ServoTimeoutError
from drivers.servo.bus import JointState, ServoBusConfig

log = logging.getLogger(__name__)


# --- the backend -----------------------------------------------------------------------
class DynamixelBus(DynamixelBusBase):
    """Four Protocol 2.0 X-series servos on one port; see the module docstring.

    `fast_sync_read=False` keeps to Sync Read even where the servos have Fast Sync Read
    (for comparisons); `read_method` says which one the bus uses once open.
    """

    capabilities = frozenset({"reboot", "hardware_error", "temperature", "input_voltage", "watchdog"})
    PROTOCOL = 2.0
    FIRMWARE_ADDRESS = XAddr.FIRMWARE_VERSION
    STATUS_HARDWARE_BITS = ERRBIT_ALERT

    def __init__(self, config: ServoBusConfig, *, clock: Clock = SYSTEM_CLOCK, name: str | None = None,
                 fast_sync_read: bool = True) -> None:
        super().__init__(config, clock=clock, name=name)
        self._sync_read: SyncRead | None = None
        self._fast_read: FastSyncRead | None = None
        self._want_fast_read = fast_sync_read

    @classmethod
    def _check_protocol_config(cls, config: ServoBusConfig) -> None:
        for joint, jc in config.joints.items():
            if jc.model not in X_MODELS:
                raise ServoConfigError(
                    f"{config.joint_path(joint)}.model: got {jc.model!r}, expected one of "
                    f"{', '.join(sorted(X_MODELS))} (the models the 'dynamixel' backend drives) on Protocol 2.0; "
                    "Protocol 1.0 models need protocol: 1.0"
                )

    # -- hooks ---------------------------------------------------------------------------
    def _setup_group_transactions(self, port: BlockingPortHandler) -> None:
        """The per-cycle state read and goal write. Whether the read can be a Fast Sync
        Read is found out here, the servos being configured (their Return Delay Time is in
        the reply timeout only then)."""
        self._sync_read = SyncRead(port, self._packet, XAddr.INDIRECT_DATA_1, READ_BLOCK_SIZE)
        for servo_id in self._present_ids.values():
            self._sync_read.addParam(servo_id)
        self._fast_read = None
        self.read_method = "sync read"
        self._sync_write = GroupSyncWrite(port, self._packet, XAddr.GOAL_POSITION, 4)
        self._probe_fast_sync_read()

    def _probe_fast_sync_read(self) -> None:
        """Fast Sync Read where every servo's firmware has it and one read of their ids
        through it comes back right; else Sync Read."""
        port = self._require(self._port)
        ids = list(self._present_ids.values())
        old = {j: fw for j, fw in self.firmware.items() if fw < FAST_SYNC_READ_MIN_FIRMWARE and j in self._present_ids}
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
        self._sync_read = self._fast_read = None
        super()._disconnect()

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
            # Its other RAM settings are at their defaults too: `ServoBus` initialises it again.
            states = {j: dataclasses.replace(s, power_cycled=True) if j in remapped and s is not None else s
                      for j, s in states.items()}
        return {joint: state for joint, state in states.items() if state is not None}

    def _write_servo_goals(self, goals_deg: Mapping[str, float]) -> None:
        sync_write = self._require(self._sync_write)
        sync_write.clearParam()
        for joint, servo_deg in goals_deg.items():
            sync_write.addParam(self._ids[joint], list(struct.pack("<i", deg_to_ticks(servo_deg))))
        self._send_sync_write(sync_write)

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
                        + "; ".join(self.decode_hardware_error(bits))
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
    # -- servo setup -----------------------------------------------------------------------
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

    def _sync_read_states(self) -> dict[str, JointState | None]:
        plain = self._require(self._sync_read)
        sync_read = self._group_read(self._fast_read or plain, plain, "sync read")
        states: dict[str, JointState | None] = {}
        watchdog_units = self.config.watchdog_ms // MS_PER_WATCHDOG_UNIT
        for joint, servo_id in self._present_ids.items():
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
