"""One emulated X-series servo: its control table and its motion, for the emulator.

`EmulatedServo` answers reads and writes the way an X-series servo does (EEPROM writable
only with torque off, read-only items, indirect addressing, position limits, shutdown on
hardware errors, the Bus Watchdog, Reboot back to RAM defaults) and moves its shaft under
its Profile Velocity and Profile Acceleration on an injectable clock. It knows nothing of
packets or ports: `drivers.dynamixel.emulator.server` serves it on a pseudo-terminal and serialises
access to it. Its table is `drivers.dynamixel.tables.x_series`, the one the backend drives by.
"""
from __future__ import annotations

import logging
import math

from drivers.clock import SYSTEM_CLOCK, Clock
from drivers.dynamixel.tables.x_series import (
    DPS2_PER_ACCELERATION_UNIT,
    DEG_PER_TICK,
    DPS_PER_VELOCITY_UNIT,
    MS_PER_WATCHDOG_UNIT,
    OPERATING_MODE_POSITION,
    TICKS_PER_TURN,
    US_PER_RETURN_DELAY_UNIT,
    WATCHDOG_FIRED,
    X_BAUD_CODES,
    X_MODELS,
    XAddr,
)
from drivers.dynamixel.protocol.v2 import ERR_ACCESS, ERR_DATA_LIMIT, ERR_DATA_RANGE, ERRBIT_ALERT
from drivers.sim.servo_motion import ProfileAxis
from drivers.sim.servos import DEFAULT_SHUTDOWN_BITS

log = logging.getLogger(__name__)

# Defaults of the control table: address -> (size, value). EEPROM first, then RAM.
_EEPROM_DEFAULTS: dict[int, tuple[int, int]] = {
    XAddr.RETURN_DELAY_TIME: (1, 250),
    XAddr.DRIVE_MODE: (1, 0),
    XAddr.OPERATING_MODE: (1, OPERATING_MODE_POSITION),
    12: (1, 255),                        # Secondary ID
    13: (1, 2),                          # Protocol Type
    XAddr.MOVING_THRESHOLD: (4, 10),
    XAddr.TEMPERATURE_LIMIT: (1, 80),
    XAddr.MAX_VOLTAGE_LIMIT: (2, 160),
    XAddr.MIN_VOLTAGE_LIMIT: (2, 95),
    XAddr.PWM_LIMIT: (2, 885),
    XAddr.VELOCITY_LIMIT: (4, 200),
    XAddr.MAX_POSITION_LIMIT: (4, TICKS_PER_TURN - 1),
    XAddr.MIN_POSITION_LIMIT: (4, 0),
    XAddr.SHUTDOWN: (1, DEFAULT_SHUTDOWN_BITS),
}
_RAM_DEFAULTS: dict[int, tuple[int, int]] = {
    XAddr.STATUS_RETURN_LEVEL: (1, 2),
    XAddr.PRESENT_INPUT_VOLTAGE: (2, 120),
    XAddr.PRESENT_TEMPERATURE: (1, 35),
    XAddr.GOAL_PWM: (2, 885),
} | {XAddr.INDIRECT_ADDRESS_1 + 2 * i: (2, XAddr.INDIRECT_DATA_1 + i) for i in range(XAddr.INDIRECT_COUNT)}
# Writable items: address -> size. Everything else is read-only (Access Error).
_WRITABLE: dict[int, int] = {
    XAddr.ID: 1, XAddr.BAUD_RATE: 1, XAddr.RETURN_DELAY_TIME: 1, XAddr.DRIVE_MODE: 1, XAddr.OPERATING_MODE: 1,
    12: 1, 13: 1, 20: 4, XAddr.MOVING_THRESHOLD: 4, XAddr.TEMPERATURE_LIMIT: 1, XAddr.MAX_VOLTAGE_LIMIT: 2,
    XAddr.MIN_VOLTAGE_LIMIT: 2, XAddr.PWM_LIMIT: 2, 38: 2, XAddr.VELOCITY_LIMIT: 4, XAddr.MAX_POSITION_LIMIT: 4,
    XAddr.MIN_POSITION_LIMIT: 4, XAddr.SHUTDOWN: 1, XAddr.TORQUE_ENABLE: 1, XAddr.LED: 1,
    XAddr.STATUS_RETURN_LEVEL: 1, XAddr.BUS_WATCHDOG: 1, XAddr.GOAL_PWM: 2, XAddr.GOAL_VELOCITY: 4,
    XAddr.PROFILE_ACCELERATION: 4, XAddr.PROFILE_VELOCITY: 4, XAddr.GOAL_POSITION: 4,
} | {XAddr.INDIRECT_ADDRESS_1 + 2 * i: 2 for i in range(XAddr.INDIRECT_COUNT)} | {
    XAddr.INDIRECT_DATA_1 + i: 1 for i in range(XAddr.INDIRECT_COUNT)}
_WRITABLE_BYTES = frozenset(addr + i for addr, size in _WRITABLE.items() for i in range(size))
_INDIRECT_ADDRESS_BYTES = range(XAddr.INDIRECT_ADDRESS_1, XAddr.INDIRECT_ADDRESS_1 + 2 * XAddr.INDIRECT_COUNT)
_INDIRECT_DATA_BYTES = range(XAddr.INDIRECT_DATA_1, XAddr.INDIRECT_DATA_1 + XAddr.INDIRECT_COUNT)


class EmulatedServo:
    """One X-series servo: its control table and its motion, on `clock`.

    Not thread-safe on its own: `DxlEmulator` serialises access with its lock.
    """

    BOOT_TIME_S = 0.1

    def __init__(self, servo_id: int, model: str = "XM430-W350", *, clock: Clock = SYSTEM_CLOCK,
                 baud: int = 1_000_000, firmware: int = 48, position_ticks: int = 2048) -> None:
        self.model = model
        self.clock = clock
        self.table = bytearray(XAddr.TABLE_SIZE)
        self._set(XAddr.MODEL_NUMBER, 2, X_MODELS[model])
        self._set(XAddr.FIRMWARE_VERSION, 1, firmware)
        self._set(XAddr.ID, 1, servo_id)
        self._set(XAddr.BAUD_RATE, 1, X_BAUD_CODES[baud])
        for addr, (size, value) in _EEPROM_DEFAULTS.items():
            self._set(addr, size, value)
        now = clock.monotonic()
        self.axis = ProfileAxis(position_ticks, now)
        self.booting_until_s = -math.inf
        self.last_contact_s = now
        self._reset_ram()

    # -- plain table access ----------------------------------------------------------------
    @property
    def servo_id(self) -> int:
        return self.table[XAddr.ID]

    def get(self, addr: int, size: int, signed: bool = False) -> int:
        return int.from_bytes(self.table[addr: addr + size], "little", signed=signed)

    def _set(self, addr: int, size: int, value: int) -> None:
        self.table[addr: addr + size] = int(value).to_bytes(size, "little", signed=value < 0)

    @property
    def firmware(self) -> int:
        return self.table[XAddr.FIRMWARE_VERSION]

    @property
    def hardware_error_bits(self) -> int:
        return self.table[XAddr.HARDWARE_ERROR_STATUS]

    @property
    def torque_on(self) -> bool:
        return self.table[XAddr.TORQUE_ENABLE] == 1

    @property
    def return_delay_s(self) -> float:
        return self.table[XAddr.RETURN_DELAY_TIME] * US_PER_RETURN_DELAY_UNIT / 1e6

    def is_booting(self, now_s: float) -> bool:
        return now_s < self.booting_until_s

    def _reset_ram(self) -> None:
        self.table[XAddr.EEPROM_END:] = bytes(XAddr.TABLE_SIZE - XAddr.EEPROM_END)
        for addr, (size, value) in _RAM_DEFAULTS.items():
            self._set(addr, size, value)
        self.axis.hold()
        self._set(XAddr.GOAL_POSITION, 4, round(self.axis.position))
        self._publish()

    # -- behaviour -------------------------------------------------------------------------
    def update(self, now_s: float) -> None:
        """Advance the motion to `now_s` and refresh the present-value registers."""
        self.axis.max_velocity = (self.get(XAddr.PROFILE_VELOCITY, 4) or self.get(XAddr.VELOCITY_LIMIT, 4)) \
            * DPS_PER_VELOCITY_UNIT / DEG_PER_TICK
        accel_units = self.get(XAddr.PROFILE_ACCELERATION, 4)
        self.axis.max_acceleration = accel_units * DPS2_PER_ACCELERATION_UNIT / DEG_PER_TICK if accel_units else math.inf
        watchdog_s = self.table[XAddr.BUS_WATCHDOG] * MS_PER_WATCHDOG_UNIT / 1000.0
        if (self.torque_on and self.table[XAddr.BUS_WATCHDOG] not in (0, WATCHDOG_FIRED)
                and now_s - self.last_contact_s > watchdog_s):
            # The host fell silent: stop where the servo was when the watchdog expired.
            self.axis.advance_to(self.last_contact_s + watchdog_s)
            self.axis.hold()
            self.table[XAddr.BUS_WATCHDOG] = WATCHDOG_FIRED
            log.info("emulated servo %d: bus watchdog fired", self.servo_id)
        self.axis.advance_to(now_s)
        self._publish()

    def _publish(self) -> None:
        self._set(XAddr.PRESENT_POSITION, 4, round(self.axis.position))
        self._set(XAddr.PRESENT_VELOCITY, 4, round(self.axis.velocity * DEG_PER_TICK / DPS_PER_VELOCITY_UNIT))
        self.table[XAddr.MOVING] = 1 if self.axis.moving else 0
        self.table[XAddr.MOVING_STATUS] = 1 if self.axis.moving else 0

    def contact(self, now_s: float) -> None:
        """A packet addressed to this servo arrived (feeds the Bus Watchdog)."""
        self.update(now_s)
        self.last_contact_s = now_s

    def error_byte(self, error: int = 0) -> int:
        return error | (ERRBIT_ALERT if self.table[XAddr.HARDWARE_ERROR_STATUS] else 0)

    def read(self, addr: int, length: int) -> tuple[int, bytes]:
        if length < 1 or addr + length > XAddr.TABLE_SIZE:
            return ERR_DATA_RANGE, b""
        out = bytearray()
        for a in range(addr, addr + length):
            out.append(self._read_byte(a))
        return 0, bytes(out)

    def _read_byte(self, addr: int) -> int:
        if addr in _INDIRECT_DATA_BYTES:
            target = self.get(XAddr.INDIRECT_ADDRESS_1 + 2 * (addr - XAddr.INDIRECT_DATA_1), 2)
            if target < XAddr.TABLE_SIZE and target not in _INDIRECT_DATA_BYTES:
                return self.table[target]
        return self.table[addr]

    def write(self, addr: int, data: bytes) -> int:
        """Write `data` at `addr`; returns the status error number (0 = done)."""
        if not data or addr + len(data) > XAddr.TABLE_SIZE:
            return ERR_DATA_RANGE
        # Resolve indirect data to the addresses it stands for.
        targets = []
        for i, a in enumerate(range(addr, addr + len(data))):
            if a in _INDIRECT_DATA_BYTES:
                a = self.get(XAddr.INDIRECT_ADDRESS_1 + 2 * (a - XAddr.INDIRECT_DATA_1), 2)
            targets.append((a, data[i]))
        for a, _value in targets:
            if a not in _WRITABLE_BYTES:
                return ERR_ACCESS
            if self.torque_on and (a < XAddr.EEPROM_END or a in _INDIRECT_ADDRESS_BYTES):
                return ERR_ACCESS  # EEPROM and the indirect map need torque off
        if any(a == XAddr.GOAL_POSITION for a, _ in targets) and len(targets) >= 4:
            goal = int.from_bytes(bytes(v for a, v in targets if XAddr.GOAL_POSITION <= a < XAddr.GOAL_POSITION + 4),
                                  "little", signed=True)
            if not self.get(XAddr.MIN_POSITION_LIMIT, 4) <= goal <= self.get(XAddr.MAX_POSITION_LIMIT, 4):
                return ERR_DATA_LIMIT
        torque_before = self.torque_on
        for a, value in targets:
            if a == XAddr.TORQUE_ENABLE and value and self.table[XAddr.HARDWARE_ERROR_STATUS] & self.table[XAddr.SHUTDOWN]:
                continue  # a servo in shutdown refuses torque until rebooted
            if a == XAddr.GOAL_POSITION and self.table[XAddr.BUS_WATCHDOG] == WATCHDOG_FIRED:
                return ERR_DATA_RANGE  # a fired watchdog blocks goals until it is cleared
            self.table[a] = value
        if self.torque_on and not torque_before:
            # Torque on drives toward the Goal Position register, stale or not.
            self.axis.set_goal(self.get(XAddr.GOAL_POSITION, 4, signed=True))
        elif not self.torque_on:
            self.axis.hold()
        elif any(XAddr.GOAL_POSITION <= a < XAddr.GOAL_POSITION + 4 for a, _ in targets):
            self.axis.set_goal(self.get(XAddr.GOAL_POSITION, 4, signed=True))
        self._publish()
        return 0

    def reboot(self, now_s: float) -> None:
        """RAM back to defaults (torque off, hardware error cleared); silent while booting."""
        self.update(now_s)
        self._reset_ram()
        self.booting_until_s = now_s + self.BOOT_TIME_S

    def set_hardware_error(self, bits: int) -> None:
        self.update(self.clock.monotonic())
        self.table[XAddr.HARDWARE_ERROR_STATUS] |= bits
        if bits & self.table[XAddr.SHUTDOWN]:
            self.table[XAddr.TORQUE_ENABLE] = 0
            self.axis.hold()
            self._publish()
