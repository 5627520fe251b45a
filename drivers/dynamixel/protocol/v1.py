"""The Dynamixel Protocol 1.0 wire format: framing, checksum, status packets, a streaming parser.

A packet is FF FF, the servo id, a length (instruction or error + parameters + checksum),
the instruction (0x01 Ping, 0x02 Read, 0x03 Write, 0x83 Sync Write, 0x92 Bulk Read) or, in
a status packet, the error byte, the parameters, and a checksum: the inverted low byte of
the sum of everything after the header. Unlike Protocol 2.0 there is no byte stuffing and
no status instruction: whether a packet is an instruction or a status is known from who
sent it. Read and Write take one-byte addresses and lengths.

The emulator (`drivers.dynamixel.emulator.server`) parses and answers with this; the backend leaves
framing to dynamixel-sdk except for Bulk Read (`drivers.dynamixel.sdk.BulkRead1`).
"""
from __future__ import annotations

from drivers.dynamixel.protocol.v2 import Packet, StreamParser

HEADER = b"\xff\xff"
BROADCAST_ID = 0xFE
INST_PING, INST_READ, INST_WRITE, INST_REBOOT = 0x01, 0x02, 0x03, 0x08
INST_SYNC_WRITE, INST_BULK_READ = 0x83, 0x92
MAX_LENGTH = 250  # dynamixel-sdk's limit for a whole packet


def checksum(body: bytes | bytearray) -> int:
    """~(id + length + instruction/error + parameters) & 0xFF."""
    return ~sum(body) & 0xFF


def build_packet(servo_id: int, instruction: int, params: bytes = b"") -> bytes:
    """A complete Protocol 1.0 packet (also a status packet, with the error byte as `instruction`)."""
    body = bytes([servo_id, len(params) + 2, instruction]) + bytes(params)
    return HEADER + body + bytes([checksum(body)])


def status_packet(servo_id: int, error: int, data: bytes = b"") -> bytes:
    return build_packet(servo_id, error, data)


class PacketParser1(StreamParser):
    """Protocol 1.0 packets: FF FF, id, a one-byte length, instruction (or a status packet's
    error byte), parameters, checksum. `crc_ok` says whether the checksum matched."""

    header = HEADER
    keep = 1  # a possible first FF

    def _frame(self, buf: bytearray) -> int | None:
        # FF FF FF ...: the id cannot be FF, so the header starts one byte later.
        if len(buf) >= 3 and buf[2] == 0xFF:
            return None
        if len(buf) < 4:
            return 0
        length = buf[3]
        return 4 + length if 2 <= length <= MAX_LENGTH - 4 else None

    def _packet(self, raw: bytes) -> Packet:
        return Packet(raw[2], raw[4], raw[5:-1], checksum(raw[2:-1]) == raw[-1])
