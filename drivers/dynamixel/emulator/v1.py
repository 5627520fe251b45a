"""How the emulator answers Protocol 1.0 instructions: Ping, Read, Write, Sync Write, Bulk
Read (MX models only: an AX or RX servo ignores it), Reboot and others refused.

`dispatch1` turns one parsed instruction packet into the status packets the addressed
servos send, in the order they send them; `drivers.dynamixel.emulator.server.DxlEmulator` serves it
on its pseudo-terminal, with its faults and timing, when started with `protocol=1.0`.
"""
from __future__ import annotations

from collections.abc import Mapping

from drivers.dynamixel.tables.v1 import ERRBIT_CHECKSUM, ERRBIT_INSTRUCTION, ERRBIT_RANGE, P1Addr
from drivers.dynamixel.protocol.v2 import Packet
from drivers.dynamixel.protocol.v1 import (
    BROADCAST_ID,
    INST_BULK_READ,
    INST_PING,
    INST_READ,
    INST_SYNC_WRITE,
    INST_WRITE,
    status_packet,
)
from drivers.dynamixel.emulator.servo_v1 import EmulatedServo1


def dispatch1(servos: Mapping[int, EmulatedServo1], packet: Packet, now: float) -> list[tuple[int, bytes]]:
    """The replies (servo id, status packet) to one Protocol 1.0 instruction packet."""
    inst, params, target = packet.instruction, packet.params, packet.servo_id
    if target == BROADCAST_ID:
        addressed = list(servos.values())
    else:
        addressed = [servos[target]] if target in servos else []
    if not packet.crc_ok:
        return [(s.servo_id, status_packet(s.servo_id, s.error_byte(ERRBIT_CHECKSUM)))
                for s in addressed if target != BROADCAST_ID and not s.is_booting(now)]
    if inst == INST_SYNC_WRITE:
        _sync_write(servos, params, now)
        return []
    if inst == INST_BULK_READ:
        return _bulk_read(servos, params, now)
    replies = []
    for servo in addressed:
        if servo.is_booting(now):
            continue
        servo.contact(now)
        error, data = _single(servo, inst, params)
        if target == BROADCAST_ID:
            continue  # Protocol 1.0 answers nothing sent to broadcast, not even Ping
        level = servo.status_return_level
        if inst == INST_PING or level >= 2 or (level == 1 and inst == INST_READ):
            replies.append((servo.servo_id, status_packet(servo.servo_id, servo.error_byte(error), data)))
    return replies


def _single(servo: EmulatedServo1, inst: int, params: bytes) -> tuple[int, bytes]:
    if inst == INST_PING:
        return 0, b""
    if inst == INST_READ:
        if len(params) != 2:
            return ERRBIT_RANGE, b""
        return servo.read(params[0], params[1])
    if inst == INST_WRITE:
        if len(params) < 2:
            return ERRBIT_RANGE, b""
        return servo.write(params[0], params[1:]), b""
    return ERRBIT_INSTRUCTION, b""


def _sync_write(servos: Mapping[int, EmulatedServo1], params: bytes, now: float) -> None:
    if len(params) < 2:
        return
    addr, length = params[0], params[1]
    stride = 1 + length
    for offset in range(2, len(params) - stride + 1, stride):
        servo = servos.get(params[offset])
        if servo is not None and not servo.is_booting(now):
            servo.contact(now)
            servo.write(addr, params[offset + 1: offset + stride])


def _bulk_read(servos: Mapping[int, EmulatedServo1], params: bytes, now: float) -> list[tuple[int, bytes]]:
    """Parameters: 0x00, then (length, id, address) per servo; each answers in turn with
    its own status packet. A servo without Bulk Read stays silent, and so does every
    servo after it (each waits for the reply of the one before)."""
    replies = []
    for offset in range(1, len(params) - 2, 3):
        length, servo_id, addr = params[offset], params[offset + 1], params[offset + 2]
        servo = servos.get(servo_id)
        if servo is None or servo.is_booting(now) or not servo.spec.bulk_read:
            break
        servo.contact(now)
        error, data = servo.read(addr, length)
        replies.append((servo_id, status_packet(servo_id, servo.error_byte(error), data)))
    return replies


__all__ = ["P1Addr", "dispatch1"]
