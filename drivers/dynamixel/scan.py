"""Finding the Dynamixel servos on a port: which ids answer, at which baud rate and protocol.

`ping_servos` is one baud rate and protocol on an open port: Protocol 2.0 with one broadcast
ping (every servo 0-252 answers in turn), Protocol 1.0, which has no broadcast ping reply,
with a ping per id and its firmware read. `scan` opens the port and tries each baud rate
(`headctl scan`); `drivers.dynamixel.probe` scans with it before `headctl setup` moves anything.
"""
from __future__ import annotations

import logging
from collections.abc import Iterable
from dataclasses import dataclass

from dynamixel_sdk import COMM_SUCCESS, PacketHandler, PortHandler

from drivers.dynamixel.tables.x_series import KNOWN_MODEL_NAMES, XAddr
from drivers.dynamixel.tables.v1 import P1Addr
from drivers.dynamixel.sdk import PORT_ERRORS, BlockingPortHandler, port_access_hint
from drivers.errors import ServoCommError, ServoConfigError

log = logging.getLogger(__name__)

REPLY_SLACK_MS = 3.0  # beyond the packet's own time on the wire, before a reply is given up


@dataclass(frozen=True)
class ScanResult:
    servo_id: int
    model_number: int
    firmware: int  # -1: not read
    baud: int
    protocol: float

    @property
    def model_name(self) -> str:
        return KNOWN_MODEL_NAMES.get(self.model_number, "unknown model")


def ping_servos(handler: PortHandler, packet: PacketHandler, protocol: float, ids: Iterable[int],
                baud: int) -> list[ScanResult]:
    """The servos among `ids` that answer on `handler`, already at `baud`, in id order."""
    wanted = sorted(set(ids))
    if protocol == 2.0:
        replies, _result = packet.broadcastPing(handler)
        return [ScanResult(i, model, fw, baud, protocol) for i, (model, fw) in sorted(replies.items())
                if i in wanted]
    found: list[ScanResult] = []
    for servo_id in wanted:
        model, result, _error = packet.ping(handler, servo_id)
        if result != COMM_SUCCESS:
            continue
        firmware, result, _error = packet.read1ByteTxRx(handler, servo_id, P1Addr.FIRMWARE_VERSION
                                                        if protocol == 1.0 else XAddr.FIRMWARE_VERSION)
        found.append(ScanResult(servo_id, model, firmware if result == COMM_SUCCESS else -1, baud, protocol))
    return found


def scan(port: str, bauds: Iterable[int], *, protocol: float = 2.0, ids: Iterable[int] = range(253),
         latency_timer_ms: float = 1.0) -> list[ScanResult]:
    """Find the servos on `port` at each baud rate (`ping_servos`).

    Raises `ServoCommError` naming the fix when the port cannot be opened.
    """
    handler = BlockingPortHandler(port, latency_timer_ms, REPLY_SLACK_MS)
    packet = PacketHandler(protocol)
    wanted = list(ids)
    found: list[ScanResult] = []
    try:
        for baud in bauds:
            try:
                ok = handler.setBaudRate(baud)
            except PORT_ERRORS as err:
                raise ServoCommError(port_access_hint(port, err)) from err
            if not ok:
                raise ServoConfigError(f"baud {baud}: not supported by dynamixel-sdk (max 4000000)")
            log.info("%s: scanning at %d baud, protocol %.1f", port, baud, protocol)
            try:
                found += ping_servos(handler, packet, protocol, wanted, baud)
            except PORT_ERRORS as err:
                raise ServoCommError(f"{port}: the port failed during the scan: {err}") from err
    finally:
        if handler.ser is not None:
            try:
                handler.closePort()
            except PORT_ERRORS:
                log.debug("%s: closing after the scan failed", port)
    return found
