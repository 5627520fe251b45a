"""The one exception hierarchy of `drivers`.

Every error is a `DriverError`; subclasses also inherit the matching builtin so callers
can catch `TimeoutError`, `OSError` or `ValueError` as they already do. Messages name the
port, servo id, joint or camera involved.
"""
from __future__ import annotations

import os
from typing import Any, TypeVar


class DriverError(Exception):
    """Root of every error raised by `drivers`."""


class ConfigError(DriverError, ValueError):
    """A configuration is invalid: the one config error type of every layer.

    Raised by the reader in `drivers/config/reader.py` with `key_path` (`servo_bus.joints.pan.
    min_angle`), the `value` found and what was `expected`; `missing` when the key was not
    given. `file` is set by whoever knows the file. The message reads
    `<file>: <key_path>: got <value!r>, expected <expected>`. Backends also raise the
    subclasses with a plain message (a pixel format the camera does not offer); the
    structured fields are None then.
    """

    _FIELDS = frozenset({"message", "key_path", "value", "expected", "missing", "file"})

    def __init__(self, message: str | None = None, *, key_path: str | None = None, value: Any = None,
                 expected: str | None = None, missing: bool = False,
                 file: str | os.PathLike[str] | None = None) -> None:
        super().__init__()
        self.message = message
        self.key_path = key_path
        self.value = value
        self.expected = expected
        self.missing = missing
        self.file = file

    def __setattr__(self, name: str, value: Any) -> None:
        # `args` (what repr and pickling use) follows the fields: a value replaced by a
        # stand-in for a secret, or the file set later, shows there too.
        super().__setattr__(name, value)
        if name in self._FIELDS and all(hasattr(self, f) for f in self._FIELDS):
            self.args = (str(self),)

    def __str__(self) -> str:
        if self.expected is not None:
            got = "missing" if self.missing else f"got {self.value!r}"
            body = f"{self.key_path or '(top level)'}: {got}, expected {self.expected}"
        elif self.key_path is not None:
            body = f"{self.key_path or '(top level)'}: {self.message or 'invalid'}"
        else:
            body = self.message or ""
        return f"{os.fspath(self.file)}: {body}" if self.file is not None else body


class BackendNotFoundError(DriverError, LookupError):
    """No backend of that name, and the name is not an importable `module:Class`."""


class BackendImportError(DriverError, ImportError):
    """The backend exists but its module (or a library it needs) failed to import."""


class DeviceStateError(DriverError, RuntimeError):
    """An operation not allowed in the device's lifecycle state (closed, not enabled)."""


class DeviceTimeoutError(DriverError, TimeoutError):
    """A device did not answer in time."""


class DeviceIOError(DriverError, OSError):
    """Communication with a device failed (port gone, bad checksum, short read)."""


# --- servo buses -------------------------------------------------------------------------
class ServoError(DriverError):
    """Root of servo-bus errors. `joints` names the joints a failed transaction blames, when
    it blames some (set by the bus that raises it; empty otherwise)."""

    joints: tuple[str, ...] = ()


_E = TypeVar("_E", bound=ServoError)


def blaming(err: _E, *joints: str) -> _E:
    """`err` with `joints` as the joints it blames."""
    err.joints = joints
    return err


class ServoCommError(ServoError, DeviceIOError):
    """A packet exchange failed after the allowed retries (timeout, CRC, port down)."""


class ServoTimeoutError(ServoCommError, DeviceTimeoutError):
    """A servo did not reply in time."""


class ServoHardwareError(ServoError):
    """A servo reports a hardware error (overload, overheating, voltage, encoder, shock)."""


class ServoModelError(ServoError, ValueError):
    """The servo at an id is not the model the configuration names."""


class JointLimitError(ServoError, ValueError):
    """A goal outside the configured joint limits was refused."""


class BusDownError(ServoCommError):
    """The bus (adapter) is gone; it is being reopened."""


class ServoConfigError(ServoError, ConfigError):
    """A servo-bus configuration is invalid, or names a joint that is not configured."""


# --- cameras -----------------------------------------------------------------------------
class CameraError(DriverError):
    """Root of camera errors."""


class CameraTimeoutError(CameraError, DeviceTimeoutError):
    """No frame (or no synchronised pair) arrived in time."""


class CameraLostError(CameraError, DeviceIOError):
    """The camera disappeared (unplugged, control lost); it is being reopened."""


class CameraConfigError(CameraError, ConfigError):
    """A camera configuration is invalid, or a requested setting (pixel format, size, rate)
    is not supported by the camera."""
