"""The daemon's local control socket: `headctl status` asks it for the daemon's state.

A unix stream socket in the state directory (`status.sock`, mode 0660: the service's user
and group). One request a connection: a JSON object on one line, answered by one JSON line.

    {"cmd": "status"}                                  -> {"ok": true, "status": {...}}
    {"cmd": "inject", "fault": "bus_down"}             -> simulated head only (tests, demos):
        bus_down, restore_bus, hardware_error (+ "joint", "bits"), camera_stall / camera_resume (+ "camera")

The network control API (issue 7) will grow from this.
"""
from __future__ import annotations

import json
import logging
import os
import socket
import threading
from pathlib import Path
from typing import Any

from headctl.errors import HeadctlError

log = logging.getLogger(__name__)

MAX_REQUEST = 64 * 1024


class StatusError(HeadctlError, OSError):
    """The daemon's socket is missing, refuses, or answered nonsense."""


def query(path: str | os.PathLike, request: dict[str, Any] | None = None, timeout_s: float = 2.0) -> dict[str, Any]:
    """Send one request to a daemon's socket and return its answer (raises StatusError)."""
    request = request or {"cmd": "status"}
    try:
        with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as sock:
            sock.settimeout(timeout_s)
            sock.connect(str(path))
            sock.sendall(json.dumps(request).encode() + b"\n")
            chunks = []
            while True:
                chunk = sock.recv(65536)
                if not chunk:
                    break
                chunks.append(chunk)
    except FileNotFoundError as err:
        raise StatusError(f"{path}: no status socket (is the daemon running with this state directory?)") from err
    except ConnectionRefusedError as err:
        raise StatusError(f"{path}: nothing listens (a daemon that stopped uncleanly left it)") from err
    except OSError as err:
        raise StatusError(f"{path}: {err}") from err
    try:
        answer = json.loads(b"".join(chunks))
    except ValueError as err:
        raise StatusError(f"{path}: the daemon answered something that is not JSON ({err})") from err
    if not answer.get("ok"):
        raise StatusError(f"{path}: {answer.get('error', 'request failed')}")
    return answer


class StatusServer(threading.Thread):
    """Serves `daemon.status()` (and fault injection on the simulated head); a context manager."""

    def __init__(self, path: str | os.PathLike, daemon: Any) -> None:
        super().__init__(name="status-server", daemon=True)
        self.path = Path(path)
        self.target = daemon
        self._stop_event = threading.Event()
        self._sock: socket.socket | None = None

    def __enter__(self) -> "StatusServer":
        if self.path.exists():
            try:
                query(self.path, timeout_s=0.5)
            except StatusError:
                self.path.unlink()  # left by a daemon that was killed
            else:
                raise HeadctlError(f"{self.path}: another headctl daemon is running with this state directory")
        sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM | socket.SOCK_CLOEXEC)
        try:
            sock.bind(str(self.path))
            os.chmod(self.path, 0o660)
            sock.listen(8)
            sock.settimeout(0.2)
        except OSError as err:
            sock.close()
            raise HeadctlError(f"{self.path}: cannot listen: {err}") from err
        self._sock = sock
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def stop(self, timeout_s: float = 2.0) -> None:
        """Stop serving and remove the socket. Safe to call twice."""
        self._stop_event.set()
        if self.is_alive() and threading.current_thread() is not self:
            self.join(timeout_s)
        if self._sock is not None:
            self._sock.close()
            self._sock = None
            try:
                self.path.unlink()
            except FileNotFoundError:
                pass

    def run(self) -> None:
        assert self._sock is not None
        sock = self._sock
        while not self._stop_event.is_set():
            try:
                conn, _ = sock.accept()
            except TimeoutError:
                continue
            except OSError as err:
                if not self._stop_event.is_set():
                    log.error("%s: accept failed: %s", self.path, err)
                return
            with conn:
                try:
                    self._serve(conn)
                except Exception:  # one bad client must not stop the server
                    log.exception("%s: request failed", self.path)

    def _serve(self, conn: socket.socket) -> None:
        conn.settimeout(1.0)
        data = b""
        while b"\n" not in data and len(data) < MAX_REQUEST:
            chunk = conn.recv(4096)
            if not chunk:
                break
            data += chunk
        try:
            request = json.loads(data.split(b"\n", 1)[0] or b"{}")
            if not isinstance(request, dict):
                raise ValueError("expected a JSON object")
            answer = self.handle(request)
        except (ValueError, HeadctlError) as err:
            answer = {"ok": False, "error": str(err)}
        conn.sendall(json.dumps(answer, default=_plain).encode() + b"\n")

    def handle(self, request: dict[str, Any]) -> dict[str, Any]:
        cmd = request.get("cmd", "status")
        if cmd == "status":
            return {"ok": True, "status": self.target.status()}
        if cmd == "inject":
            args = {k: request[k] for k in ("joint", "camera", "bits") if k in request}
            return {"ok": True, "injected": self.target.inject(str(request.get("fault")), **args)}
        raise ValueError(f"unknown cmd {cmd!r}: expected status or inject")


def _plain(value: Any) -> Any:
    if hasattr(value, "tolist"):
        return value.tolist()
    return str(value)
