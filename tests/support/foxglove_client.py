"""A minimal client of the Foxglove WebSocket protocol for the tests.

The protocol's subprotocol name was `foxglove.websocket.v1`; the Foxglove SDK's server speaks the
same messages as `foxglove.sdk.v1` and takes only that name, so both are offered
(`SUBPROTOCOLS`) and `subprotocol` is the one the server chose.
Just enough of RFC 6455 for loopback: the opening handshake with the subprotocols, masked text
frames out, unmasked frames in (fragments joined, pings answered), and of Foxglove's protocol
the JSON operations (`serverInfo`, `advertise`, `subscribe`) and the binary Message Data
frame (opcode 1: subscription id u32, log time u64 ns, payload; little-endian). Every read
has a deadline: a socket timeout, never a sleep.
"""
from __future__ import annotations

import base64
import hashlib
import json
import os
import socket
import struct
from dataclasses import dataclass
from typing import Any

SUBPROTOCOLS = ("foxglove.sdk.v1", "foxglove.websocket.v1")
_GUID = b"258EAFA5-E914-47DA-95CA-C5AB0DC85B11"
_TEXT, _BINARY, _CLOSE, _PING, _PONG, _CONTINUATION = 1, 2, 8, 9, 10, 0
MESSAGE_DATA = 1


@dataclass(frozen=True)
class MessageData:
    subscription: int
    log_time_ns: int
    payload: bytes


class FoxgloveClient:
    """One connection to a Foxglove WebSocket server on `host`:`port`."""

    def __init__(self, host: str, port: int, timeout_s: float = 10.0) -> None:
        self.sock = socket.create_connection((host, port), timeout=timeout_s)
        key = base64.b64encode(os.urandom(16)).decode()
        self.sock.sendall((f"GET / HTTP/1.1\r\nHost: {host}:{port}\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n"
                           f"Sec-WebSocket-Key: {key}\r\nSec-WebSocket-Version: 13\r\n"
                           f"Sec-WebSocket-Protocol: {', '.join(SUBPROTOCOLS)}\r\n\r\n").encode())
        head = b""
        while b"\r\n\r\n" not in head:
            chunk = self.sock.recv(4096)
            if not chunk:
                raise ConnectionError(f"the server closed during the handshake: {head!r}")
            head += chunk
        head, self._buffer = head.split(b"\r\n\r\n", 1)
        lines = head.decode("latin-1").split("\r\n")
        headers = {k.strip().lower(): v.strip() for k, _, v in (line.partition(":") for line in lines[1:])}
        if " 101 " not in lines[0] + " ":
            raise ConnectionError(f"no upgrade: {lines[0]}")
        accept = base64.b64encode(hashlib.sha1(key.encode() + _GUID).digest()).decode()
        if headers.get("sec-websocket-accept") != accept:
            raise ConnectionError(f"wrong Sec-WebSocket-Accept: {headers.get('sec-websocket-accept')}")
        self.subprotocol = headers.get("sec-websocket-protocol")

    def close(self) -> None:
        try:
            self._send(_CLOSE, struct.pack(">H", 1000))
        except OSError:
            pass
        self.sock.close()

    def __enter__(self) -> "FoxgloveClient":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- frames ------------------------------------------------------------------------------
    def _read(self, n: int) -> bytes:
        while len(self._buffer) < n:
            chunk = self.sock.recv(65536)
            if not chunk:
                raise ConnectionError("the server closed the connection")
            self._buffer += chunk
        out, self._buffer = self._buffer[:n], self._buffer[n:]
        return out

    def _send(self, opcode: int, payload: bytes) -> None:
        mask = os.urandom(4)
        n = len(payload)
        size = struct.pack("B", 0x80 | n) if n < 126 else (
            struct.pack(">BH", 0x80 | 126, n) if n < 1 << 16 else struct.pack(">BQ", 0x80 | 127, n))
        masked = bytes(b ^ mask[i % 4] for i, b in enumerate(payload))
        self.sock.sendall(struct.pack("B", 0x80 | opcode) + size + mask + masked)

    def receive(self) -> str | bytes:
        """The next text (str) or binary (bytes) message; pings are answered on the way."""
        opcode, parts = None, []
        while True:
            first, second = self._read(2)
            fin, op, n = first & 0x80, first & 0x0F, second & 0x7F
            if n == 126:
                (n,) = struct.unpack(">H", self._read(2))
            elif n == 127:
                (n,) = struct.unpack(">Q", self._read(8))
            mask = self._read(4) if second & 0x80 else None
            data = self._read(n)
            if mask is not None:
                data = bytes(b ^ mask[i % 4] for i, b in enumerate(data))
            if op == _PING:
                self._send(_PONG, data)
                continue
            if op == _PONG:
                continue
            if op == _CLOSE:
                raise ConnectionError(f"the server closed the connection: {data!r}")
            if op != _CONTINUATION:
                opcode = op
            parts.append(data)
            if fin:
                payload = b"".join(parts)
                return payload.decode() if opcode == _TEXT else payload

    # -- the protocol ------------------------------------------------------------------------
    def send_json(self, message: dict[str, Any]) -> None:
        self._send(_TEXT, json.dumps(message).encode())

    def receive_json(self, op: str) -> dict[str, Any]:
        """The next JSON operation `op` (binary messages and other operations before it are dropped)."""
        while True:
            message = self.receive()
            if isinstance(message, str):
                data = json.loads(message)
                if data.get("op") == op:
                    return data

    def subscribe(self, subscriptions: dict[int, int]) -> None:
        """Subscribe: subscription id -> channel id."""
        self.send_json({"op": "subscribe",
                        "subscriptions": [{"id": s, "channelId": c} for s, c in subscriptions.items()]})

    def receive_data(self) -> MessageData:
        """The next Message Data frame (JSON operations before it are dropped)."""
        while True:
            message = self.receive()
            if isinstance(message, bytes) and message and message[0] == MESSAGE_DATA:
                subscription, log_time_ns = struct.unpack_from("<IQ", message, 1)
                return MessageData(subscription, log_time_ns, message[13:])
