"""dynamixel-sdk 4.1.0's classes with their pitfalls fixed, and helpers for its serial port.

The SDK is untyped, so its classes are subclassed here and nowhere else (the one module with
pyproject.toml's mypy override allowing it); `drivers.dynamixel.bus_v2` drives the servos through
them.

* `BlockingPortHandler`: a `PortHandler` that waits for replies in `select()` on the
  monotonic clock, with a reply timeout from the adapter's real latency timer and the
  servos' Return Delay Time (the SDK assumes a 16 ms latency timer and reads in a busy
  loop), and drains late replies before a retry.
* `SyncRead`: a `GroupSyncRead` that keeps every reply under its own id with its status
  error byte and says per id what happened (`ReplyCollector`); `blame_sync_read` names the
  servo(s) to blame for a group read that failed every attempt.
* What the SDK lacks or gets wrong, written on its `PortHandler` and packet handlers:
  `FastSyncRead` (Protocol 2.0 Fast Sync Read, which 4.1.0 has no group class for) and
  `BulkRead1` (Protocol 1.0 Bulk Read, which its `GroupBulkRead` fails at), both with the
  same per-id results as `SyncRead`.
* The port: `PORT_ERRORS` (what a vanished adapter raises out of the SDK),
  `port_access_hint` (what fixes a port that cannot be opened), `adapter_latency_timer_ms`
  (the USB adapter's latency timer).
"""
from __future__ import annotations

import errno
import logging
import os
import select
import termios
import time
import struct
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Protocol

from dynamixel_sdk import (
    COMM_PORT_BUSY,
    COMM_RX_CORRUPT,
    COMM_RX_TIMEOUT,
    COMM_SUCCESS,
    COMM_TX_FAIL,
    GroupSyncRead,
    PortHandler,
)

from drivers.dynamixel.protocol.v2 import (
    BROADCAST_ID,
    HEADER,
    INST_FAST_SYNC_READ,
    INST_STATUS,
    PacketParser,
    build_packet,
    crc16,
    fast_sync_read_length,
)
from drivers.dynamixel.protocol.v1 import INST_BULK_READ as INST_BULK_READ1
from drivers.dynamixel.protocol.v1 import PacketParser1
from drivers.servo.bus import TRACE

log = logging.getLogger(__name__)


# --- the port --------------------------------------------------------------------------
# Offsets in a Protocol 2.0 status packet: header (3) + reserved, id, length (2),
# instruction, error, data..., CRC (2).
_PKT_ID = 4
_PKT_ERROR = 8
_STATUS_OVERHEAD = 11
# A Protocol 1.0 status packet: FF FF, id, length, error, data..., checksum.
_P1_STATUS_OVERHEAD = 6
# What a vanished adapter raises out of the SDK: pyserial's SerialException is an OSError,
# but tcflush() on a dead tty raises termios.error, which is not.
PORT_ERRORS = (OSError, termios.error)


def port_access_hint(port: str, err: BaseException) -> str:
    """What fixes a port that cannot be opened: the udev rule or the dialout group."""
    code = getattr(err, "errno", None)
    if code is None and err.args and isinstance(err.args[0], int):
        code = err.args[0]
    if code == errno.ENOENT or not os.path.exists(port):
        return (f"port {port} does not exist: is the adapter plugged in and powered? "
                "`ls -l /dev/serial/by-id/` lists adapters; install udev/99-headctl-servos.rules "
                "(sudo cp udev/99-headctl-servos.rules /etc/udev/rules.d/ && sudo udevadm control --reload "
                "&& sudo udevadm trigger) for the stable name /dev/head-servos")
    if code in (errno.EACCES, errno.EPERM) or not os.access(port, os.R_OK | os.W_OK):
        return (f"no permission to open {port}: add your user to the dialout group "
                "(sudo usermod -aG dialout $USER, then log out and in again), or install "
                "udev/99-headctl-servos.rules, which gives the adapter MODE 0660 GROUP dialout")
    if code == errno.EBUSY:
        return f"port {port} is busy: another program (another headctl, DYNAMIXEL Wizard) has it open"
    return f"could not open {port}: {err}"


def adapter_latency_timer_ms(port: str, sysfs: str = "/sys") -> float | None:
    """The FTDI latency timer of the USB adapter behind `port`, if the kernel exposes it
    (`sysfs`: where sysfs is mounted)."""
    name = os.path.basename(os.path.realpath(port))
    path = os.path.join(sysfs, "bus", "usb-serial", "devices", name, "latency_timer")
    try:
        with open(path, encoding="ascii") as f:
            return float(f.read().strip())
    except (OSError, ValueError):
        return None


# --- the SDK, with its timing fixed ----------------------------------------------------
class BlockingPortHandler(PortHandler):
    """A `PortHandler` that blocks in select() instead of spinning, on the monotonic clock.

    The SDK's reply timeout assumes a 16 ms adapter latency timer (about 34 ms a reply);
    here it is the wire time of the reply plus twice the real latency timer plus the
    servos' Return Delay Time plus a margin for host scheduling.
    """

    def __init__(self, port_name: str, latency_timer_ms: float, reply_slack_ms: float) -> None:
        super().__init__(port_name)
        self.latency_timer_ms = latency_timer_ms
        self.reply_slack_ms = reply_slack_ms

    def setupPort(self, cflag_baud: int) -> bool:
        opened: bool = super().setupPort(cflag_baud)
        try:
            # FTDI adapters (U2D2) hold short replies for their latency timer; ask for 1 ms.
            # A pseudo-terminal or a non-FTDI adapter refuses, which is harmless.
            self.ser.set_low_latency_mode(True)
        except (OSError, ValueError, AttributeError, NotImplementedError):
            log.log(TRACE, "%s: low-latency mode not available", self.port_name)
        return opened

    def getCurrentTime(self) -> float:
        # The SDK uses wall-clock time, which jumps with NTP; control timing is monotonic.
        return time.monotonic() * 1000.0

    def setPacketTimeout(self, packet_length: int) -> None:
        self.packet_start_time = self.getCurrentTime()
        self.packet_timeout = (self.tx_time_per_byte * packet_length + 2.0 * self.latency_timer_ms
                               + self.reply_slack_ms)

    def readPort(self, length: int) -> bytes:
        remaining_s = (self.packet_timeout - self.getTimeSinceStart()) / 1000.0
        if remaining_s > 0.0:
            # Sleep until a byte arrives or the deadline passes (the SDK loops on us).
            select.select([self.ser.fileno()], [], [], remaining_s)
        data: bytes = self.ser.read(length)
        return data

    def drain_late_replies(self) -> int:
        """Discard replies still arriving after a timeout; returns how many bytes."""
        return len(self.drain_late_bytes())

    def drain_late_bytes(self) -> bytes:
        """Discard replies still arriving after a timeout; returns them (whose they were
        says which servo answered late).

        A reply that comes after its timeout would otherwise be taken as the answer to
        the retry (the SDK matches replies by id only), handing back stale or wrong data.
        Waits until the line has been quiet for one reply timeout.
        """
        quiet_s = (2.0 * self.latency_timer_ms + self.reply_slack_ms) / 1000.0
        discarded = bytearray()
        while select.select([self.ser.fileno()], [], [], quiet_s)[0]:
            chunk = self.ser.read(4096)
            if not chunk:
                break
            discarded += chunk
        return bytes(discarded)


class GroupRead(Protocol):
    """What a group read gives after `txRxPacket()` (see `ReplyCollector`)."""

    answered: set[int]
    failures: dict[int, int]
    strays: list[int]
    errors: dict[int, int]
    data_dict: dict[int, Any]

    def txRxPacket(self) -> int: ...


class ReplyCollector:
    """Takes the replies to a group read in the order they come, each under its own id,
    with its status error byte.

    After `txRxPacket()`: `answered` holds the ids that replied, `failures` maps each id
    that did not to COMM_RX_TIMEOUT (no reply in time) or COMM_RX_CORRUPT (a reply with a
    bad CRC or checksum, or cut short), and `strays` lists the ids of replies nobody was
    waiting for (late replies to an earlier request); `errors` maps id -> status error
    byte and `data_dict` id -> data.
    """

    port: PortHandler
    data_dict: dict[int, Any]

    def _reset_replies(self) -> None:
        self.last_result = False
        self.errors: dict[int, int] = {}
        self.answered: set[int] = set()
        self.failures: dict[int, int] = {}
        self.strays: list[int] = []

    def _collect(self, receive: Callable[[], tuple[list[int], int]], lengths: Mapping[int, int], *,
                 header: bytes, id_at: int, error_at: int, overhead: int) -> int:
        """Receive replies until every id in `lengths` (id -> data length, in the order the
        servos answer) answered or failed; `receive` is the SDK's rxPacket for one packet,
        whose id, error byte and length besides the data (`overhead`) are where the
        protocol has them."""
        order = list(lengths)
        awaited = set(order)
        accepted: list[int] = []  # in the order they came
        while awaited - set(self.failures):
            packet, result = receive()
            if result == COMM_SUCCESS:
                servo_id = packet[id_at]
                if servo_id in order and accepted and order.index(servo_id) < order.index(accepted[-1]):
                    # Servos answer in turn: a reply of an earlier servo after a later one's
                    # means those taken so far were late replies to an earlier request.
                    self.strays += accepted
                    awaited |= set(accepted)
                    self.answered -= set(accepted)
                    accepted.clear()
                length = lengths.get(servo_id, -1)
                if servo_id in awaited and len(packet) == overhead + length:
                    self.data_dict[servo_id] = packet[error_at + 1: error_at + 1 + length]
                    self.errors[servo_id] = packet[error_at]
                    self.failures.pop(servo_id, None)
                    self.answered.add(servo_id)
                    awaited.discard(servo_id)
                    accepted.append(servo_id)
                else:
                    self.strays.append(servo_id)
                continue
            if result != COMM_RX_CORRUPT:
                break  # nothing more came before the timeout
            if len(packet) > id_at and bytes(packet[:len(header)]) == header and packet[id_at] in awaited:
                self.failures[packet[id_at]] = COMM_RX_CORRUPT
            if self.port.isPacketTimeout():
                break  # a reply cut short by the deadline: nothing after it came in time
        for servo_id in awaited:
            self.failures.setdefault(servo_id, COMM_RX_TIMEOUT)
        if self.failures:
            return int(COMM_RX_CORRUPT if COMM_RX_CORRUPT in self.failures.values() else COMM_RX_TIMEOUT)
        self.last_result = True
        return int(COMM_SUCCESS)


class SyncRead(ReplyCollector, GroupSyncRead):
    """`GroupSyncRead` that takes the replies in the order they come, each under its own id,
    and keeps each servo's status error byte (`ReplyCollector`)."""

    def txRxPacket(self) -> int:
        self._reset_replies()
        result: int = super().txRxPacket()
        return result

    def rxPacket(self) -> int:
        lengths: dict[int, int] = {servo_id: self.data_length for servo_id in self.data_dict}
        return self._collect(lambda: self.ph.rxPacket(self.port, False), lengths,
                             header=HEADER[:3], id_at=_PKT_ID, error_at=_PKT_ERROR, overhead=_STATUS_OVERHEAD)


class BulkRead1(ReplyCollector):
    """Protocol 1.0 Bulk Read (MX servos): one instruction names (id, address, length) per
    servo, and each answers in turn with its own status packet.

    dynamixel-sdk 4.1.0's `GroupBulkRead` cannot do this: it calls the Protocol 1.0 packet
    handler's `bulkReadTx` with an argument that method does not take. Here the packet goes
    out through the handler's `txPacket` (framing, checksum) and the replies come in
    through its `rxPacket`, taken as `ReplyCollector` says.
    """

    def __init__(self, port: PortHandler, ph: Any, entries: Sequence[tuple[int, int, int]]) -> None:
        self.port, self.ph = port, ph
        self.entries = [(int(i), int(a), int(n)) for i, a, n in entries]  # (id, address, length)
        self.data_dict = {servo_id: [] for servo_id, _a, _n in self.entries}
        self._reset_replies()

    def txRxPacket(self) -> int:
        self._reset_replies()
        params = [0x00] + [v for servo_id, addr, length in self.entries for v in (length, servo_id, addr)]
        # FF FF, broadcast id, length (instruction + parameters + checksum), Bulk Read, parameters, checksum.
        txpacket = [0xFF, 0xFF, BROADCAST_ID, len(params) + 2, INST_BULK_READ1] + params + [0]
        result: int = self.ph.txPacket(self.port, txpacket)
        if result != COMM_SUCCESS:
            return result
        self.port.setPacketTimeout(sum(length + _P1_STATUS_OVERHEAD for _i, _a, length in self.entries))
        return self._collect(lambda: self.ph.rxPacket(self.port), {i: n for i, _a, n in self.entries},
                             header=b"\xff\xff", id_at=2, error_at=4, overhead=_P1_STATUS_OVERHEAD)


class FastSyncRead(ReplyCollector):
    """Protocol 2.0 Fast Sync Read (0x8A), written on the SDK's `PortHandler`: one request,
    and one status packet in which each servo's block (error, id, data, running CRC)
    follows the one before (`drivers.dynamixel.protocol.v2`). Saves a packet header and a bus
    turnaround per servo against Sync Read.

    Every block is checked on its own (its id, and the CRC of the packet up to it), so a
    packet cut short or damaged still gives the blocks before the damage; what is missing
    or damaged is a failure of that servo, as in `ReplyCollector`.
    """

    def __init__(self, port: PortHandler, start_address: int, data_length: int, ids: Sequence[int]) -> None:
        self.port = port
        self.start_address, self.data_length = start_address, data_length
        self.ids = list(ids)
        self.data_dict = {servo_id: b"" for servo_id in self.ids}
        self._reset_replies()

    @property
    def reply_size(self) -> int:
        return 7 + fast_sync_read_length(len(self.ids), self.data_length)

    def txRxPacket(self) -> int:
        self._reset_replies()
        port = self.port
        if port.is_using:
            return int(COMM_PORT_BUSY)
        port.is_using = True
        try:
            port.clearPort()
            request = build_packet(BROADCAST_ID, INST_FAST_SYNC_READ,
                                   struct.pack("<HH", self.start_address, self.data_length) + bytes(self.ids))
            if port.writePort(request) != len(request):
                return int(COMM_TX_FAIL)
            port.setPacketTimeout(self.reply_size)
            received = self._receive()
        finally:
            port.is_using = False
        return self._take(received)

    def _receive(self) -> bytes:
        """Bytes until the whole reply is in or the deadline passes; what came before the
        reply's header (late replies to an earlier request) goes to `strays`."""
        start_marker = HEADER + bytes([BROADCAST_ID])
        raw = bytearray()
        while True:
            start = raw.find(start_marker)
            wanted = self.reply_size - (len(raw) - start if start >= 0 else 0)
            if start >= 0 and wanted <= 0:
                break
            raw += self.port.readPort(max(wanted, 1))
            if self.port.isPacketTimeout():
                break
        start = raw.find(start_marker)
        if start != 0:
            self.strays += list(status_ids(bytes(raw if start < 0 else raw[:start])))
        return bytes(raw[start:]) if start >= 0 else b""

    def _take(self, packet: bytes) -> int:
        n = self.data_length
        if len(packet) >= 8 and (packet[7] != INST_STATUS or
                                 struct.unpack_from("<H", packet, 5)[0] != fast_sync_read_length(len(self.ids), n)):
            packet = b"\x00"  # not the reply asked for: every servo failed
        offset = 8
        for servo_id in self.ids:
            end = offset + n + 4
            if len(packet) < end:
                self.failures[servo_id] = COMM_RX_CORRUPT if len(packet) > offset else COMM_RX_TIMEOUT
            elif packet[offset + 1] != servo_id or crc16(packet[:end - 2]) != struct.unpack_from("<H", packet, end - 2)[0]:
                self.failures[servo_id] = COMM_RX_CORRUPT
            else:
                self.errors[servo_id] = packet[offset]
                self.data_dict[servo_id] = packet[offset + 2: offset + 2 + n]
                self.answered.add(servo_id)
            offset = end
        if self.failures:
            return int(COMM_RX_CORRUPT if COMM_RX_CORRUPT in self.failures.values() else COMM_RX_TIMEOUT)
        self.last_result = True
        return int(COMM_SUCCESS)


@dataclass(frozen=True)
class SyncReadAttempt:
    """What one attempt of a sync read got: the ids that answered, those that failed (id ->
    COMM result), and the ids whose replies came late (unasked during the attempt, or in
    the bytes drained after it)."""

    answered: frozenset[int]
    failures: Mapping[int, int]
    late: tuple[int, ...]


def blame_sync_read(attempts: list[SyncReadAttempt]) -> dict[int, int]:
    """The servos to blame for a sync read that failed every attempt: id -> COMM result.

    Servos reply in turn on one half-duplex line, so a late reply holds up those after it,
    and a retry sent while it is still coming finds the line busy: the next attempt may
    see other servos fail, or none answer at all. So:

    * attempts in which no servo answered say nothing about any one servo; if every attempt
      was like that, every servo is blamed (the bus or its power, not one servo);
    * otherwise the ids that failed in every attempt in which some servo answered; if there
      are none (the failures moved), those of the first such attempt, the one least
      disturbed by the others.
    """
    heard = [a for a in attempts if a.answered]
    if not heard:
        return dict(attempts[-1].failures)
    common = set.intersection(*(set(a.failures) for a in heard))
    blamed = common or set(heard[0].failures)
    result: dict[int, int] = {}
    for attempt in heard:
        for servo_id in blamed & set(attempt.failures):
            result[servo_id] = attempt.failures[servo_id]  # the latest attempt's word
    return dict(sorted(result.items()))


def status_ids(data: bytes, protocol: float = 2.0) -> tuple[int, ...]:
    """The ids of the status packets in a stretch of bytes read off the line."""
    parser = PacketParser1() if protocol == 1.0 else PacketParser()
    return tuple(packet.servo_id for packet in parser.feed(data) if packet.crc_ok)
