"""Protocol 1.0 control tables (AX, RX and MX servos on Protocol 1.0 firmware): addresses,
models, baud codes, units, and the block the backend reads each cycle.

The backend (`drivers.dynamixel.bus_v1`) drives servos by these addresses and units, and the
emulator's Protocol 1.0 servo (`drivers.dynamixel.emulator.servo_v1`) serves the same table, so both sides
of an emulated bus agree by construction.

The models differ in resolution (AX and RX: 1024 ticks over 300 degrees; MX: 4096 over
360), in the unit of Moving Speed, in Goal Acceleration (MX only) and in Bulk Read (MX
only). A Protocol 1.0 servo has no Hardware Error Status register: its hardware errors
come in every status packet's error byte, whose input voltage (bit 0), overheating (bit 2)
and overload (bit 5) bits sit where the X-series Hardware Error Status has the same
meanings (`HARDWARE_ERROR_BITS`); the other bits say an instruction was refused.
"""
from __future__ import annotations

import struct
from dataclasses import dataclass


class P1Addr:
    """Control-table addresses shared by AX, RX and MX servos on Protocol 1.0 (ROBOTIS e-Manual)."""

    MODEL_NUMBER = 0            # 2 bytes
    FIRMWARE_VERSION = 2
    ID = 3
    BAUD_RATE = 4               # 2 Mbps / (value + 1)
    RETURN_DELAY_TIME = 5       # 2 us units
    CW_ANGLE_LIMIT = 6          # 2 bytes: the lowest goal accepted
    CCW_ANGLE_LIMIT = 8         # 2 bytes: the highest
    TEMPERATURE_LIMIT = 11
    MIN_VOLTAGE_LIMIT = 12      # 0.1 V
    MAX_VOLTAGE_LIMIT = 13
    MAX_TORQUE = 14             # 2 bytes; Torque Limit's value at power-on
    STATUS_RETURN_LEVEL = 16
    ALARM_LED = 17
    SHUTDOWN = 18               # error bits that cut torque
    EEPROM_END = 24
    TORQUE_ENABLE = 24
    LED = 25
    GOAL_POSITION = 30          # 2 bytes
    MOVING_SPEED = 32           # 2 bytes; 0 = as fast as the servo can
    TORQUE_LIMIT = 34           # 2 bytes; set to 0 by a shutdown, written again to leave it
    PRESENT_POSITION = 36       # 2 bytes
    PRESENT_SPEED = 38          # 2 bytes: magnitude in bits 0-9, bit 10 set for CW (decreasing)
    PRESENT_LOAD = 40           # 2 bytes
    PRESENT_VOLTAGE = 42        # 0.1 V
    PRESENT_TEMPERATURE = 43
    REGISTERED = 44
    MOVING = 46
    LOCK = 47
    PUNCH = 48                  # 2 bytes
    GOAL_ACCELERATION = 73      # MX only; 8.583 deg/s^2 units, 0 = no control


# Status error byte of Protocol 1.0: one bit per condition.
ERRBIT_VOLTAGE, ERRBIT_ANGLE, ERRBIT_OVERHEAT, ERRBIT_RANGE = 0x01, 0x02, 0x04, 0x08
ERRBIT_CHECKSUM, ERRBIT_OVERLOAD, ERRBIT_INSTRUCTION = 0x10, 0x20, 0x40
# The error-byte bits that are hardware errors; they mean what the same bits of the X-series
# Hardware Error Status mean, so the bus reports them through the same fault flow.
HARDWARE_ERROR_BITS = ERRBIT_VOLTAGE | ERRBIT_OVERHEAT | ERRBIT_OVERLOAD
DEFAULT_SHUTDOWN = ERRBIT_OVERHEAT | ERRBIT_OVERLOAD   # factory Alarm Shutdown (36)

DPS2_PER_ACCELERATION_UNIT = 8.583
MAX_GOAL_ACCELERATION = 254
MAX_MOVING_SPEED = 1023
US_PER_RETURN_DELAY_UNIT = 2
VOLTS_PER_VOLTAGE_UNIT = 0.1
SPEED_DIRECTION_BIT = 0x400

# Baud rate register values (2 Mbps / (value + 1), the nearest to each rate).
P1_BAUD_CODES: dict[int, int] = {9600: 207, 57600: 34, 115200: 16, 1_000_000: 1}


@dataclass(frozen=True)
class P1Model:
    """One Protocol 1.0 model: its number (ping reply), resolution, speed unit and features."""

    name: str
    number: int
    ticks: int                 # positions over `range_deg`
    range_deg: float
    rpm_per_speed_unit: float  # Moving Speed and Present Speed
    no_load_rpm: float         # what Moving Speed 0 means
    bulk_read: bool
    goal_acceleration: bool
    table_size: int

    @property
    def deg_per_tick(self) -> float:
        return self.range_deg / self.ticks

    @property
    def center_tick(self) -> int:
        return self.ticks // 2

    @property
    def dps_per_speed_unit(self) -> float:
        return self.rpm_per_speed_unit * 6.0

    @property
    def half_range_deg(self) -> float:
        """The farthest servo angle from the centre a goal can reach (degrees)."""
        return (self.ticks - 1 - self.center_tick) * self.deg_per_tick

    def deg_to_ticks(self, servo_deg: float) -> int:
        """Servo angle (degrees from centre) -> Goal Position ticks, within the range."""
        return min(max(round(servo_deg / self.deg_per_tick) + self.center_tick, 0), self.ticks - 1)

    def ticks_to_deg(self, ticks: int) -> float:
        return (ticks - self.center_tick) * self.deg_per_tick

    def speed_units(self, dps: float) -> int:
        """deg/s -> Moving Speed (0 stays 0: as fast as the servo can)."""
        return 0 if dps <= 0 else min(max(round(dps / self.dps_per_speed_unit), 1), MAX_MOVING_SPEED)

    def speed_dps(self, raw: int) -> float:
        """Present Speed -> signed deg/s (+ toward increasing position)."""
        magnitude = (raw & (SPEED_DIRECTION_BIT - 1)) * self.dps_per_speed_unit
        return -magnitude if raw & SPEED_DIRECTION_BIT else magnitude

    def raw_speed(self, dps: float) -> int:
        """Signed deg/s -> Present Speed (what the emulated servo publishes)."""
        magnitude = min(round(abs(dps) / self.dps_per_speed_unit), SPEED_DIRECTION_BIT - 1)
        return magnitude | (SPEED_DIRECTION_BIT if dps < 0 and magnitude else 0)

    @property
    def max_speed_dps(self) -> float:
        return MAX_MOVING_SPEED * self.dps_per_speed_unit


_AX = dict(ticks=1024, range_deg=300.0, rpm_per_speed_unit=0.111, bulk_read=False, goal_acceleration=False,
           table_size=50)
_MX = dict(ticks=4096, range_deg=360.0, rpm_per_speed_unit=0.114, bulk_read=True, goal_acceleration=True,
           table_size=74)
P1_MODELS: dict[str, P1Model] = {m.name: m for m in (
    P1Model("AX-12A", 12, no_load_rpm=59.0, **_AX),      # type: ignore[arg-type]
    P1Model("AX-18A", 18, no_load_rpm=97.0, **_AX),      # type: ignore[arg-type]
    P1Model("RX-24F", 24, no_load_rpm=126.0, **_AX),     # type: ignore[arg-type]
    P1Model("RX-28", 28, no_load_rpm=67.0, **_AX),       # type: ignore[arg-type]
    P1Model("RX-64", 64, no_load_rpm=64.0, **_AX),       # type: ignore[arg-type]
    P1Model("MX-28", 29, no_load_rpm=55.0, **_MX),       # type: ignore[arg-type]
    P1Model("MX-64", 310, no_load_rpm=63.0, **_MX),      # type: ignore[arg-type]
    P1Model("MX-106", 320, no_load_rpm=45.0, **_MX),     # type: ignore[arg-type]
)}
P1_MODEL_NAMES: dict[int, str] = {m.number: m.name for m in P1_MODELS.values()}

# The block read from every servo each cycle: Torque Enable (24) up to Moving (46).
READ_START = P1Addr.TORQUE_ENABLE
READ_FORMAT = struct.Struct("<BB4sHHHHHHBBBBB")
READ_SIZE = READ_FORMAT.size
assert READ_START + READ_SIZE - 1 == P1Addr.MOVING


@dataclass(frozen=True)
class P1Block:
    """The fields of the read block the bus uses."""

    torque_enable: int
    goal_position: int
    moving_speed: int
    torque_limit: int
    present_position: int
    present_speed: int
    voltage: int
    temperature: int
    moving: int

    @classmethod
    def unpack(cls, data: bytes) -> "P1Block":
        (torque, _led, _gains, goal, moving_speed, limit, position, speed, _load, voltage, temperature, _registered,
         _reserved, moving) = READ_FORMAT.unpack(data)
        return cls(torque, goal, moving_speed, limit, position, speed, voltage, temperature, moving)
