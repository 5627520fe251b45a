"""The lifecycle every device shares (servo bus, camera), after ros2_control.

    closed --open()--> open (states readable) --enable()--> enabled (commands accepted)
    enabled --disable()--> open ;  any --close()--> closed   (close() is idempotent)

The public methods are template methods: they check and move the state once, here; a
backend implements only the `_open`, `_enable`, `_disable` and `_close` hooks. The
device-kind interfaces (`drivers.servo.bus.ServoBus`, `drivers.cameras.camera.Camera`) build on it.
"""
from __future__ import annotations

import enum
import logging
import threading
from typing import Any

from drivers.errors import DeviceStateError

log = logging.getLogger(__name__)


class Lifecycle(enum.Enum):
    CLOSED = "closed"
    OPEN = "open"
    ENABLED = "enabled"


class Device:
    """Base of every device: lifecycle, context manager, idempotent close.

    `name` is what error messages and logs call the device (a port, a camera name).
    """

    def __init__(self, name: str) -> None:
        self.name = name
        self._state = Lifecycle.CLOSED
        self._lifecycle_lock = threading.RLock()

    # -- lifecycle ---------------------------------------------------------------------
    @property
    def state(self) -> Lifecycle:
        return self._state

    @property
    def is_open(self) -> bool:
        return self._state is not Lifecycle.CLOSED

    @property
    def is_enabled(self) -> bool:
        return self._state is Lifecycle.ENABLED

    def open(self) -> "Device":
        with self._lifecycle_lock:
            if self._state is not Lifecycle.CLOSED:
                return self
            try:
                self._open()
            except BaseException:
                # Undo a partial setup before re-raising (pyserial's rule).
                try:
                    self._close()
                except Exception:  # the original error matters more
                    log.debug("%s: cleanup after a failed open also failed", self.name, exc_info=True)
                raise
            self._state = Lifecycle.OPEN
            log.debug("%s: open", self.name)
            return self

    def enable(self) -> None:
        with self._lifecycle_lock:
            if self._state is Lifecycle.CLOSED:
                raise DeviceStateError(f"{self.name}: enable() on a closed device; open() it first")
            if self._state is Lifecycle.ENABLED:
                return
            self._enable()
            self._state = Lifecycle.ENABLED
            log.debug("%s: enabled", self.name)

    def disable(self) -> None:
        with self._lifecycle_lock:
            if self._state is not Lifecycle.ENABLED:
                return
            try:
                self._disable()
            finally:
                self._state = Lifecycle.OPEN
            log.debug("%s: disabled", self.name)

    def close(self) -> None:
        """Leave the device in its configured safe state and release it. Safe to call twice."""
        with self._lifecycle_lock:
            if self._state is Lifecycle.CLOSED:
                return
            try:
                self._close()
            finally:
                self._state = Lifecycle.CLOSED
            log.debug("%s: closed", self.name)

    def require_open(self) -> None:
        if self._state is Lifecycle.CLOSED:
            raise DeviceStateError(f"{self.name}: the device is closed; open() it first")

    def require_enabled(self) -> None:
        if self._state is not Lifecycle.ENABLED:
            raise DeviceStateError(
                f"{self.name}: commands need an enabled device (state is {self._state.value}); "
                "call enable() first"
            )

    def __enter__(self) -> Any:
        self.open()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __del__(self) -> None:  # only warns, never cleans up (python-can's rule)
        try:
            if self._state is not Lifecycle.CLOSED:
                log.warning("%s was not closed; call close() or use it as a context manager", self.name)
        except AttributeError:
            pass

    # -- hooks for backends ------------------------------------------------------------
    def _open(self) -> None:
        """Open the connection; states become readable."""

    def _enable(self) -> None:
        """Power on / start streaming; commands become accepted."""

    def _disable(self) -> None:
        """Undo `_enable`."""

    def _close(self) -> None:
        """Put the device in its safe state and release it. Must tolerate a partial open."""
