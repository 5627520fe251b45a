"""One emulated Protocol 1.0 servo (AX, RX or MX on Protocol 1.0 firmware), for the emulator.

`EmulatedServo1` answers reads and writes the way these servos do: Goal Position outside
the CW/CCW angle limits is refused with the Angle Limit error bit, read-only items with
the Range error bit; its hardware errors (input voltage, overheating, overload) appear in
the error byte of every status packet; an error whose bit is in Alarm Shutdown (18) cuts
torque (Torque Enable and Torque Limit to 0), and writing Torque Limit again (the way such
a servo leaves shutdown) clears the error; a power cycle restores RAM. It moves its shaft
at Moving Speed, and under Goal Acceleration on MX models, on an injectable clock. It knows
nothing of packets: `drivers.dynamixel.emulator.server` serves it.

Injected errors stay until Torque Limit is written or the servo is power cycled: on a real
servo the condition (heat, voltage) would have to pass too.
"""
from __future__ import annotations

import logging
import math

from drivers.clock import SYSTEM_CLOCK, Clock
from drivers.dynamixel.tables.v1 import (
    DEFAULT_SHUTDOWN,
    DPS2_PER_ACCELERATION_UNIT,
    ERRBIT_ANGLE,
    ERRBIT_RANGE,
    HARDWARE_ERROR_BITS,
    P1_BAUD_CODES,
    P1_MODELS,
    US_PER_RETURN_DELAY_UNIT,
    P1Addr,
    P1Model,
)
from drivers.sim.servo_motion import ProfileAxis

log = logging.getLogger(__name__)

_MAX_TORQUE = 1023
# Writable items: address -> size; everything else refuses a write (Range error).
_WRITABLE_COMMON: dict[int, int] = {
    P1Addr.ID: 1, P1Addr.BAUD_RATE: 1, P1Addr.RETURN_DELAY_TIME: 1, P1Addr.CW_ANGLE_LIMIT: 2,
    P1Addr.CCW_ANGLE_LIMIT: 2, P1Addr.TEMPERATURE_LIMIT: 1, P1Addr.MIN_VOLTAGE_LIMIT: 1,
    P1Addr.MAX_VOLTAGE_LIMIT: 1, P1Addr.MAX_TORQUE: 2, P1Addr.STATUS_RETURN_LEVEL: 1, P1Addr.ALARM_LED: 1,
    P1Addr.SHUTDOWN: 1, P1Addr.TORQUE_ENABLE: 1, P1Addr.LED: 1, 26: 1, 27: 1, 28: 1, 29: 1,
    P1Addr.GOAL_POSITION: 2, P1Addr.MOVING_SPEED: 2, P1Addr.TORQUE_LIMIT: 2, P1Addr.LOCK: 1, P1Addr.PUNCH: 2,
}
_WRITABLE_MX: dict[int, int] = {20: 2, 22: 1, P1Addr.GOAL_ACCELERATION: 1}


class EmulatedServo1:
    """One Protocol 1.0 servo: its control table and its motion, on `clock`.

    Not thread-safe on its own: `DxlEmulator` serialises access with its lock.
    """

    BOOT_TIME_S = 0.1

    def __init__(self, servo_id: int, model: str = "AX-12A", *, clock: Clock = SYSTEM_CLOCK,
                 baud: int = 1_000_000, firmware: int = 24, position_ticks: int | None = None) -> None:
        self.spec: P1Model = P1_MODELS[model]
        self.model = model
        self.clock = clock
        self.table = bytearray(self.spec.table_size)
        writable = _WRITABLE_COMMON | (_WRITABLE_MX if self.spec.goal_acceleration else {})
        self._writable = frozenset(a + i for a, size in writable.items() for i in range(size))
        self._set(P1Addr.MODEL_NUMBER, 2, self.spec.number)
        self._set(P1Addr.FIRMWARE_VERSION, 1, firmware)
        self._set(P1Addr.ID, 1, servo_id)
        self._set(P1Addr.BAUD_RATE, 1, P1_BAUD_CODES[baud])
        self._set(P1Addr.RETURN_DELAY_TIME, 1, 250)
        self._set(P1Addr.CW_ANGLE_LIMIT, 2, 0)
        self._set(P1Addr.CCW_ANGLE_LIMIT, 2, self.spec.ticks - 1)
        self._set(P1Addr.TEMPERATURE_LIMIT, 1, 70)
        self._set(P1Addr.MIN_VOLTAGE_LIMIT, 1, 60)
        self._set(P1Addr.MAX_VOLTAGE_LIMIT, 1, 140)
        self._set(P1Addr.MAX_TORQUE, 2, _MAX_TORQUE)
        self._set(P1Addr.STATUS_RETURN_LEVEL, 1, 2)
        self._set(P1Addr.ALARM_LED, 1, DEFAULT_SHUTDOWN)
        self._set(P1Addr.SHUTDOWN, 1, DEFAULT_SHUTDOWN)
        now = clock.monotonic()
        self.axis = ProfileAxis(self.spec.center_tick if position_ticks is None else position_ticks, now)
        self.booting_until_s = -math.inf
        self.hardware_error_bits = 0
        self._reset_ram()

    # -- plain table access ----------------------------------------------------------------
    @property
    def servo_id(self) -> int:
        return self.table[P1Addr.ID]

    @property
    def firmware(self) -> int:
        return self.table[P1Addr.FIRMWARE_VERSION]

    def get(self, addr: int, size: int, signed: bool = False) -> int:
        return int.from_bytes(self.table[addr: addr + size], "little", signed=signed)

    def _set(self, addr: int, size: int, value: int) -> None:
        self.table[addr: addr + size] = int(value).to_bytes(size, "little")

    @property
    def torque_on(self) -> bool:
        return self.table[P1Addr.TORQUE_ENABLE] == 1 and self.get(P1Addr.TORQUE_LIMIT, 2) > 0

    @property
    def return_delay_s(self) -> float:
        return self.table[P1Addr.RETURN_DELAY_TIME] * US_PER_RETURN_DELAY_UNIT / 1e6

    @property
    def status_return_level(self) -> int:
        return self.table[P1Addr.STATUS_RETURN_LEVEL]

    def is_booting(self, now_s: float) -> bool:
        return now_s < self.booting_until_s

    def _reset_ram(self) -> None:
        self.table[P1Addr.EEPROM_END:] = bytes(self.spec.table_size - P1Addr.EEPROM_END)
        self._set(P1Addr.TORQUE_LIMIT, 2, self.get(P1Addr.MAX_TORQUE, 2))
        self._set(P1Addr.PRESENT_VOLTAGE, 1, 120)
        self._set(P1Addr.PRESENT_TEMPERATURE, 1, 35)
        self.hardware_error_bits = 0
        self.axis.hold()
        self._set(P1Addr.GOAL_POSITION, 2, round(self.axis.position))
        self._publish()

    # -- behaviour -------------------------------------------------------------------------
    def update(self, now_s: float) -> None:
        """Advance the motion to `now_s` and refresh the present-value registers."""
        spec = self.spec
        speed = self.get(P1Addr.MOVING_SPEED, 2)
        dps = speed * spec.dps_per_speed_unit if speed else spec.no_load_rpm * 6.0
        self.axis.max_velocity = dps / spec.deg_per_tick
        accel = self.table[P1Addr.GOAL_ACCELERATION] if spec.goal_acceleration else 0
        self.axis.max_acceleration = accel * DPS2_PER_ACCELERATION_UNIT / spec.deg_per_tick if accel else math.inf
        self.axis.advance_to(now_s)
        self._publish()

    def _publish(self) -> None:
        self._set(P1Addr.PRESENT_POSITION, 2, round(self.axis.position))
        self._set(P1Addr.PRESENT_SPEED, 2, self.spec.raw_speed(self.axis.velocity * self.spec.deg_per_tick))
        self.table[P1Addr.MOVING] = 1 if self.axis.moving else 0

    def contact(self, now_s: float) -> None:
        """A packet addressed to this servo arrived."""
        self.update(now_s)

    def error_byte(self, error: int = 0) -> int:
        return error | self.hardware_error_bits

    def read(self, addr: int, length: int) -> tuple[int, bytes]:
        if length < 1 or addr + length > self.spec.table_size:
            return ERRBIT_RANGE, b""
        return 0, bytes(self.table[addr: addr + length])

    def write(self, addr: int, data: bytes) -> int:
        """Write `data` at `addr`; returns the status error bits (0 = done)."""
        if not data or addr + len(data) > self.spec.table_size:
            return ERRBIT_RANGE
        span = range(addr, addr + len(data))
        if any(a not in self._writable for a in span):
            return ERRBIT_RANGE
        values = dict(zip(span, data))
        if P1Addr.GOAL_POSITION in values and P1Addr.GOAL_POSITION + 1 in values:
            goal = values[P1Addr.GOAL_POSITION] | values[P1Addr.GOAL_POSITION + 1] << 8
            if not self.get(P1Addr.CW_ANGLE_LIMIT, 2) <= goal <= self.get(P1Addr.CCW_ANGLE_LIMIT, 2):
                return ERRBIT_ANGLE
        torque_before = self.torque_on
        in_shutdown = bool(self.hardware_error_bits & self.table[P1Addr.SHUTDOWN])
        for a, value in values.items():
            self.table[a] = value
        if P1Addr.TORQUE_LIMIT in values and self.get(P1Addr.TORQUE_LIMIT, 2) > 0 and self.hardware_error_bits:
            # Writing Torque Limit again is how these servos leave shutdown.
            log.info("emulated servo %d: error 0x%02x cleared by a Torque Limit write", self.servo_id,
                     self.hardware_error_bits)
            self.hardware_error_bits = 0
        elif in_shutdown and P1Addr.TORQUE_ENABLE in values:
            self.table[P1Addr.TORQUE_ENABLE] = 0  # a servo in shutdown stays limp
        if self.torque_on and not torque_before:
            self.axis.set_goal(self.get(P1Addr.GOAL_POSITION, 2))
        elif not self.torque_on:
            self.axis.hold()
        elif P1Addr.GOAL_POSITION in values:
            self.axis.set_goal(self.get(P1Addr.GOAL_POSITION, 2))
        self._publish()
        return 0

    def reboot(self, now_s: float) -> None:
        """Power cycle: RAM back to defaults (torque off, error cleared); silent while booting."""
        self.update(now_s)
        self._reset_ram()
        self.booting_until_s = now_s + self.BOOT_TIME_S

    def set_hardware_error(self, bits: int) -> None:
        """Raise error-byte bits (input voltage 0x01, overheating 0x04, overload 0x20)."""
        if bits & ~HARDWARE_ERROR_BITS:
            raise ValueError(f"error bits 0x{bits:02x}: a Protocol 1.0 servo reports only input voltage (0x01), "
                             f"overheating (0x04) and overload (0x20)")
        self.update(self.clock.monotonic())
        self.hardware_error_bits |= bits
        if bits & self.table[P1Addr.SHUTDOWN]:
            self.table[P1Addr.TORQUE_ENABLE] = 0
            self._set(P1Addr.TORQUE_LIMIT, 2, 0)
            self.axis.hold()
            self._publish()
