"""systemd integration: sd_notify(3) READY, STATUS, WATCHDOG and STOPPING messages."""
from __future__ import annotations

import logging
import os
import socket
from typing import Mapping

log = logging.getLogger(__name__)


class SystemdNotifier:
    """sd_notify(3) without a dependency: one datagram to `$NOTIFY_SOCKET` per call.

    Written here rather than taken from the `sdnotify` package: the protocol is one `sendto`
    (abstract socket names start with '@'), and the watchdog interval comes from
    `$WATCHDOG_USEC`, which that package does not read.
    """

    def __init__(self, environ: Mapping[str, str] | None = None) -> None:
        env = os.environ if environ is None else environ
        address = env.get("NOTIFY_SOCKET", "")
        self.address = "\0" + address[1:] if address.startswith("@") else address
        usec = env.get("WATCHDOG_USEC", "")
        pid = env.get("WATCHDOG_PID", "")
        self.watchdog_s = int(usec) / 1e6 if usec.isdigit() and (not pid or pid == str(os.getpid())) else None
        self._sock: socket.socket | None = None
        if self.address:
            self._sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM | socket.SOCK_CLOEXEC)

    @property
    def enabled(self) -> bool:
        return self._sock is not None

    def notify(self, **fields: str | int) -> None:
        if self._sock is None:
            return
        message = "\n".join(f"{k.upper()}={v}" for k, v in fields.items())
        try:
            self._sock.sendto(message.encode(), self.address)
        except OSError as err:
            log.warning("sd_notify to %s failed: %s", self.address.lstrip("\0"), err)

    def close(self) -> None:
        if self._sock is not None:
            self._sock.close()
            self._sock = None
