"""How the emulator answers Protocol 2.0 instructions: Ping (also broadcast), Read, Write,
Sync Read, Fast Sync Read, Sync Write, Bulk Read, Bulk Write, Reboot; others get an
Instruction Error status.

`dispatch2` turns one parsed instruction packet into the status packets the addressed
servos send, in the order they send them; `fast_sync_read` builds the one status packet
all servos of a Fast Sync Read share, taking the faults injected into each servo's reply
from a `ReplyFaults`. `drivers.dynamixel.emulator.server.DxlEmulator` serves both on its pseudo-terminal.
"""
from __future__ import annotations

import struct
from collections.abc import Mapping
from typing import Protocol

from drivers.dynamixel.tables.x_series import FAST_SYNC_READ_MIN_FIRMWARE, XAddr
from drivers.dynamixel.protocol.v2 import (
    BROADCAST_ID,
    ERR_CRC,
    ERR_DATA_LENGTH,
    ERR_INSTRUCTION,
    HEADER,
    INST_BULK_READ,
    INST_BULK_WRITE,
    INST_PING,
    INST_READ,
    INST_REBOOT,
    INST_STATUS,
    INST_SYNC_READ,
    INST_SYNC_WRITE,
    INST_WRITE,
    Packet,
    crc16,
    fast_sync_read_length,
    status_packet,
)
from drivers.dynamixel.emulator.servo_v2 import EmulatedServo


class ReplyFaults(Protocol):
    """The faults injected into servos' replies, each taken when used."""

    def consume_drop(self, servo_id: int) -> bool: ...

    def consume_corrupt(self, servo_id: int) -> bool: ...

    def consume_delay(self, servo_id: int) -> float: ...


def dispatch2(servos: Mapping[int, EmulatedServo], packet: Packet, now: float) -> list[tuple[int, bytes]]:
    inst, params, target = packet.instruction, packet.params, packet.servo_id
    if target == BROADCAST_ID:
        addressed = list(servos.values())
    else:
        addressed = [servos[target]] if target in servos else []
    if not packet.crc_ok:
        return [(s.servo_id, status_packet(s.servo_id, s.error_byte(ERR_CRC)))
                for s in addressed if target != BROADCAST_ID and not s.is_booting(now)]
    if inst == INST_SYNC_READ or inst == INST_SYNC_WRITE:
        return _sync(servos, inst, params, now)
    if inst == INST_BULK_READ or inst == INST_BULK_WRITE:
        return _bulk(servos, inst, params, now)
    replies = []
    for servo in addressed:
        if servo.is_booting(now):
            continue
        servo.contact(now)
        error, data = _single(servo, inst, params)
        if target == BROADCAST_ID and inst != INST_PING:
            continue  # broadcast: only Ping is answered
        level = servo.table[XAddr.STATUS_RETURN_LEVEL]
        if inst == INST_PING or level >= 2 or (level == 1 and inst == INST_READ):
            replies.append((servo.servo_id, status_packet(servo.servo_id, servo.error_byte(error), data)))
        if inst == INST_REBOOT:
            servo.reboot(now)
    return replies


def _single(servo: EmulatedServo, inst: int, params: bytes) -> tuple[int, bytes]:
    if inst == INST_PING:
        return 0, struct.pack("<HB", servo.get(XAddr.MODEL_NUMBER, 2), servo.table[XAddr.FIRMWARE_VERSION])
    if inst == INST_READ:
        if len(params) != 4:
            return ERR_DATA_LENGTH, b""
        addr, length = struct.unpack("<HH", params)
        return servo.read(addr, length)
    if inst == INST_WRITE:
        if len(params) < 3:
            return ERR_DATA_LENGTH, b""
        return servo.write(struct.unpack_from("<H", params)[0], params[2:]), b""
    if inst == INST_REBOOT:
        return 0, b""
    return ERR_INSTRUCTION, b""


def _sync(servos: Mapping[int, EmulatedServo], inst: int, params: bytes, now: float) -> list[tuple[int, bytes]]:
    if len(params) < 4:
        return []
    addr, length = struct.unpack_from("<HH", params)
    replies = []
    if inst == INST_SYNC_READ:
        for servo_id in params[4:]:
            servo = servos.get(servo_id)
            if servo is None or servo.is_booting(now):
                continue  # an absent servo: the client times out on its reply
            servo.contact(now)
            error, data = servo.read(addr, length)
            replies.append((servo_id, status_packet(servo_id, servo.error_byte(error), data)))
        return replies
    stride = 1 + length
    for offset in range(4, len(params) - stride + 1, stride):
        servo = servos.get(params[offset])
        if servo is not None and not servo.is_booting(now):
            servo.contact(now)
            servo.write(addr, params[offset + 1: offset + stride])
    return []


def _bulk(servos: Mapping[int, EmulatedServo], inst: int, params: bytes, now: float) -> list[tuple[int, bytes]]:
    replies = []
    offset = 0
    while offset + 5 <= len(params):
        servo_id, addr, length = struct.unpack_from("<BHH", params, offset)
        offset += 5
        servo = servos.get(servo_id)
        data = b""
        if inst == INST_BULK_WRITE:
            data = params[offset: offset + length]
            offset += length
        if servo is None or servo.is_booting(now):
            continue
        servo.contact(now)
        if inst == INST_BULK_WRITE:
            servo.write(addr, data)
        else:
            error, data = servo.read(addr, length)
            replies.append((servo_id, status_packet(servo_id, servo.error_byte(error), data)))
    return replies


def fast_sync_read(servos: Mapping[int, EmulatedServo], params: bytes, now: float,
                   faults: ReplyFaults) -> list[tuple[float, bytes]]:
    """Fast Sync Read (0x8A): every listed servo appends its block (error, id, data, and
    the CRC of the whole packet so far) to one status packet from the broadcast id, no
    byte stuffing; the first servo writes the header and the length of all blocks.
    Each servo sends when the block before it has ended, after its Return Delay Time
    (and any injected delay), so a servo that does not answer (absent, booting, firmware
    without Fast Sync Read, reply dropped) cuts the packet short there. Returns what goes
    on the wire as (delay before it in seconds, bytes), one piece per servo that answered."""
    if len(params) < 5:
        return []
    addr, length = struct.unpack_from("<HH", params)
    ids = list(params[4:])
    packet = bytearray(HEADER + bytes([BROADCAST_ID]) + struct.pack("<H", fast_sync_read_length(len(ids), length))
                       + bytes([INST_STATUS]))
    pieces: list[tuple[float, bytes]] = []
    sent = 0
    for servo_id in ids:
        servo = servos.get(servo_id)
        if (servo is None or servo.is_booting(now) or servo.firmware < FAST_SYNC_READ_MIN_FIRMWARE
                or faults.consume_drop(servo_id)):
            break
        servo.contact(now)
        error, data = servo.read(addr, length)
        if len(data) != length:
            break  # a range error: nothing the other servos could follow
        packet += bytes([servo.error_byte(error), servo_id]) + data
        crc = crc16(packet)
        if faults.consume_corrupt(servo_id):
            crc ^= 0xFFFF
        packet += struct.pack("<H", crc)
        pieces.append((servo.return_delay_s + faults.consume_delay(servo_id), bytes(packet[sent:])))
        sent = len(packet)
    return pieces
