"""The Dynamixel Protocol 2.0 wire format: framing, byte stuffing, CRC-16, status packets.

A packet is the header FF FF FD 00, the servo id, a little-endian length, the instruction
and its parameters with byte stuffing (an FD inserted after every FF FF FD), and a CRC-16
(polynomial 0x8005) over everything before it. A status packet (instruction 0x55) carries
the servo's error byte: an error number in bits 0-6 and the Alert bit (a hardware error
is present) in bit 7.

Fast Sync Read (0x8A) is a Sync Read whose answer is one status packet from the broadcast
id, without byte stuffing, holding one block per servo in turn: error byte, id, data, and
the CRC of the whole packet up to that point (the last block's CRC ends the packet);
`fast_sync_read_length` is its length field.

The emulator (`drivers.dynamixel.emulator.server`) builds and parses packets with this; the backend
(`drivers.dynamixel.bus_v2`) leaves framing to dynamixel-sdk except for Fast Sync Read
(`drivers.dynamixel.sdk.FastSyncRead`), and takes the status error byte's meaning from here.
Protocol 1.0 is `drivers.dynamixel.protocol.v1`.
"""
from __future__ import annotations

import abc
import struct
from collections.abc import Iterator
from dataclasses import dataclass

HEADER = b"\xff\xff\xfd\x00"
BROADCAST_ID = 0xFE
INST_PING, INST_READ, INST_WRITE, INST_REBOOT = 0x01, 0x02, 0x03, 0x08
INST_STATUS = 0x55
INST_SYNC_READ, INST_SYNC_WRITE, INST_BULK_READ, INST_BULK_WRITE = 0x82, 0x83, 0x92, 0x93
INST_FAST_SYNC_READ = 0x8A
# The status error byte: an error number, and the Alert bit (a hardware error is present).
ERR_RESULT_FAIL, ERR_INSTRUCTION, ERR_CRC, ERR_DATA_RANGE, ERR_DATA_LENGTH, ERR_DATA_LIMIT, ERR_ACCESS = range(1, 8)
ERRBIT_ALERT = 0x80
MAX_PACKET_LENGTH = 1024


def _crc_table() -> list[int]:
    table = []
    for byte in range(256):
        crc = byte << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x8005) if crc & 0x8000 else (crc << 1)
        table.append(crc & 0xFFFF)
    return table


_CRC_TABLE = _crc_table()


def crc16(data: bytes | bytearray) -> int:
    """CRC-16 of Protocol 2.0: polynomial 0x8005, initial 0, not reflected."""
    crc = 0
    for byte in data:
        crc = ((crc << 8) ^ _CRC_TABLE[((crc >> 8) ^ byte) & 0xFF]) & 0xFFFF
    return crc


def stuff(body: bytes) -> bytes:
    """Insert an 0xFD after every FF FF FD in instruction + parameters."""
    out = bytearray()
    for byte in body:
        out.append(byte)
        if byte == 0xFD and out[-3:] == b"\xff\xff\xfd":
            out.append(0xFD)
    return bytes(out)


def unstuff(body: bytes) -> bytes:
    """Remove the 0xFD that stuffing inserted after every FF FF FD."""
    out = bytearray()
    i = 0
    while i < len(body):
        out.append(body[i])
        if body[i] == 0xFD and out[-3:] == b"\xff\xff\xfd" and i + 1 < len(body) and body[i + 1] == 0xFD:
            i += 1  # skip the stuffed byte
        i += 1
    return bytes(out)


def build_packet(servo_id: int, instruction: int, params: bytes = b"") -> bytes:
    """A complete Protocol 2.0 packet: header, id, length, stuffed body, CRC."""
    body = stuff(bytes([instruction]) + bytes(params))
    head = HEADER + bytes([servo_id]) + struct.pack("<H", len(body) + 2)
    packet = head + body
    return packet + struct.pack("<H", crc16(packet))


def fast_sync_read_length(n_servos: int, data_length: int) -> int:
    """The length field of a Fast Sync Read's status packet: the instruction, then per
    servo its error byte, id, data and CRC."""
    return 1 + n_servos * (data_length + 4)


def status_packet(servo_id: int, error: int, data: bytes = b"") -> bytes:
    return build_packet(servo_id, INST_STATUS, bytes([error]) + bytes(data))


@dataclass(frozen=True)
class Packet:
    servo_id: int
    instruction: int
    params: bytes
    crc_ok: bool


class StreamParser(abc.ABC):
    """Splits a byte stream into packets, resynchronising on the header after garbage.

    What differs between the protocols is a packet's frame: `_frame(buf)` looks at a buffer
    that starts with the header and says how long the packet there is (0: more bytes are
    needed; None: not a packet, skip a byte), and `_packet(raw)` decodes a complete one.
    """

    header: bytes = HEADER
    keep: int = len(HEADER) - 1  # bytes kept when no header is found: a header may be arriving

    def __init__(self) -> None:
        self._buffer = bytearray()

    def reset(self) -> None:
        self._buffer.clear()

    @abc.abstractmethod
    def _frame(self, buf: bytearray) -> int | None: ...

    @abc.abstractmethod
    def _packet(self, raw: bytes) -> Packet: ...

    def feed(self, data: bytes) -> Iterator[Packet]:
        self._buffer += data
        buf = self._buffer
        while True:
            start = buf.find(self.header)
            if start < 0:
                del buf[: max(0, len(buf) - self.keep)]
                return
            del buf[:start]
            end = self._frame(buf)
            if end is None:
                del buf[:1]
                continue
            if end == 0 or len(buf) < end:
                return
            raw = bytes(buf[:end])
            del buf[:end]
            yield self._packet(raw)


class PacketParser(StreamParser):
    """Protocol 2.0 packets: FF FF FD 00, id, a two-byte length, the stuffed body, CRC-16."""

    def _frame(self, buf: bytearray) -> int | None:
        if len(buf) < 7:
            return 0
        length: int = struct.unpack_from("<H", buf, 5)[0]
        return 7 + length if 3 <= length <= MAX_PACKET_LENGTH else None

    def _packet(self, raw: bytes) -> Packet:
        crc_ok = crc16(raw[:-2]) == struct.unpack_from("<H", raw, len(raw) - 2)[0]
        body = unstuff(raw[7:-2])
        return Packet(raw[4], body[0], body[1:], crc_ok)
