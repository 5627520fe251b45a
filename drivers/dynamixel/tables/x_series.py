"""The X-series control table (Dynamixel Protocol 2.0): addresses, models, baud codes, units,
and what the Hardware Error Status bits mean (`decode_hardware_error`).

The backend (`drivers.dynamixel.bus_v2`) drives real servos by these addresses and units, and the
emulator's servo model (`drivers.dynamixel.emulator.servo_v2`) serves the same table, so both sides of the
emulated bus agree by construction. Also here: the sync-read block the backend maps with
indirect addressing, and the model numbers a scan can name.

Everything here is for X-series servos on Protocol 2.0 (XM430, XL430, XM540), except
`KNOWN_MODEL_NAMES`, which also names the Protocol 1.0 servos of `drivers.dynamixel.tables.v1`.
"""
from __future__ import annotations

import struct

from drivers.dynamixel.tables.v1 import P1_MODEL_NAMES


class XAddr:
    """Control-table addresses of X-series servos (ROBOTIS e-Manual)."""

    MODEL_NUMBER = 0            # 2 bytes
    FIRMWARE_VERSION = 6
    ID = 7
    BAUD_RATE = 8
    RETURN_DELAY_TIME = 9       # 2 us units
    DRIVE_MODE = 10             # bit 0 reverse, bit 2 time-based profile
    OPERATING_MODE = 11         # 3 = position
    MOVING_THRESHOLD = 24       # 4 bytes
    TEMPERATURE_LIMIT = 31
    MAX_VOLTAGE_LIMIT = 32      # 2 bytes
    MIN_VOLTAGE_LIMIT = 34      # 2 bytes
    PWM_LIMIT = 36              # 2 bytes, 0-885 (100 %)
    VELOCITY_LIMIT = 44         # 4 bytes
    MAX_POSITION_LIMIT = 48     # 4 bytes
    MIN_POSITION_LIMIT = 52     # 4 bytes
    SHUTDOWN = 63
    EEPROM_END = 64             # addresses below are writable only with torque off
    TORQUE_ENABLE = 64
    LED = 65
    STATUS_RETURN_LEVEL = 68
    HARDWARE_ERROR_STATUS = 70
    BUS_WATCHDOG = 98           # 20 ms units; 0 off; reads 255 after it fired
    GOAL_PWM = 100              # 2 bytes: caps the motor's PWM in every operating mode, <= PWM Limit
    GOAL_VELOCITY = 104         # 4 bytes
    PROFILE_ACCELERATION = 108  # 4 bytes, 214.577 rev/min^2 units
    PROFILE_VELOCITY = 112      # 4 bytes, 0.229 rev/min units
    GOAL_POSITION = 116         # 4 bytes
    MOVING = 122
    MOVING_STATUS = 123
    PRESENT_CURRENT = 126       # 2 bytes (Present Load on XL430)
    PRESENT_VELOCITY = 128      # 4 bytes, signed, 0.229 rev/min units
    PRESENT_POSITION = 132      # 4 bytes, signed
    PRESENT_INPUT_VOLTAGE = 144  # 2 bytes, 0.1 V units
    PRESENT_TEMPERATURE = 146
    INDIRECT_ADDRESS_1 = 168    # 2 bytes each, 28 of them
    INDIRECT_DATA_1 = 224       # 1 byte each, 28 of them
    INDIRECT_COUNT = 28
    TABLE_SIZE = 256            # what the emulator serves (indirect 1-28 end at 251)


OPERATING_MODE_POSITION = 3
# X-series firmware from which Fast Sync Read (0x8A) is served.
FAST_SYNC_READ_MIN_FIRMWARE = 45
# Model name -> model number (ping reply), Protocol 2.0 X-series.
X_MODELS: dict[str, int] = {
    "XM430-W350": 1020,
    "XL430-W250": 1060,
    "XM540-W270": 1120,
    "XM540-W150": 1130,
}
# Model numbers a scan can name, of both protocols (Protocol 1.0: `drivers.dynamixel.tables.v1`).
KNOWN_MODEL_NAMES: dict[int, str] = {number: name for name, number in X_MODELS.items()} | P1_MODEL_NAMES
# X-series baud rate register values.
X_BAUD_CODES: dict[int, int] = {9600: 0, 57600: 1, 115200: 2, 1_000_000: 3, 2_000_000: 4,
                                3_000_000: 5, 4_000_000: 6, 4_500_000: 7}

# Units of the X-series control table.
TICKS_PER_TURN = 4096
CENTER_TICK = 2048
DEG_PER_TICK = 360.0 / TICKS_PER_TURN
DPS_PER_VELOCITY_UNIT = 0.229 * 360.0 / 60.0          # 0.229 rev/min
DPS2_PER_ACCELERATION_UNIT = 214.577 * 360.0 / 3600.0  # 214.577 rev/min^2
VOLTS_PER_VOLTAGE_UNIT = 0.1
US_PER_RETURN_DELAY_UNIT = 2
MS_PER_WATCHDOG_UNIT = 20
WATCHDOG_FIRED = 0xFF                                  # -1 as a signed byte


def deg_to_ticks(servo_deg: float) -> int:
    """Servo angle (degrees from centre) -> Goal Position ticks, within one turn."""
    return min(max(round(servo_deg / DEG_PER_TICK) + CENTER_TICK, 0), TICKS_PER_TURN - 1)


def ticks_to_deg(ticks: int) -> float:
    return (ticks - CENTER_TICK) * DEG_PER_TICK


# The sync-read block, gathered with indirect addressing: (address, size) in order.
READ_BLOCK: tuple[tuple[int, int], ...] = (
    (XAddr.ID, 1),                      # checks that the indirect mapping is in place
    (XAddr.HARDWARE_ERROR_STATUS, 1),
    (XAddr.TORQUE_ENABLE, 1),
    (XAddr.BUS_WATCHDOG, 1),
    (XAddr.MOVING, 1),
    (XAddr.PRESENT_VELOCITY, 4),
    (XAddr.PRESENT_POSITION, 4),
    (XAddr.PRESENT_INPUT_VOLTAGE, 2),
    (XAddr.PRESENT_TEMPERATURE, 1),
)
# The block as the sync read returns it, field by field in READ_BLOCK's order.
READ_BLOCK_FORMAT = struct.Struct("<BBBBBiiHB")
READ_BLOCK_SIZE = READ_BLOCK_FORMAT.size
# Indirect Address n points at one byte each: the addresses the block's bytes come from.
READ_BLOCK_ADDRESSES: tuple[int, ...] = tuple(addr + i for addr, size in READ_BLOCK for i in range(size))
assert len(READ_BLOCK_ADDRESSES) == READ_BLOCK_SIZE <= XAddr.INDIRECT_COUNT


# Hardware Error Status (address 70): bit -> meaning. Protocol 1.0 servos report the same
# conditions on the same bits of their status error byte (`drivers.dynamixel.tables.v1`).
HARDWARE_ERROR_BITS: dict[int, str] = {
    0: "input voltage out of range",
    2: "overheating",
    3: "motor encoder error",
    4: "electrical shock (motor circuit)",
    5: "overload",
}


def decode_hardware_error(bits: int) -> tuple[str, ...]:
    """The meanings of the bits of a Hardware Error Status byte."""
    if not bits:
        return ()  # every state read decodes its bits: the usual case stays cheap
    meanings = [meaning for bit, meaning in HARDWARE_ERROR_BITS.items() if bits & (1 << bit)]
    known_mask = sum(1 << bit for bit in HARDWARE_ERROR_BITS)
    if bits & ~known_mask:
        meanings.append(f"unknown bits 0x{bits & ~known_mask:02x}")
    return tuple(meanings)
