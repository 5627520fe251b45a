"""The one exception hierarchy of `drivers`.

Every error is a `DriverError`; subclasses also inherit the matching builtin so callers
can catch `TimeoutError`, `OSError` or `ValueError` as they already do. Messages name the
port, servo id, joint or camera involved.
"""
from __future__ import annotations


class DriverError(Exception):
    """Root of every error raised by `drivers`."""


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
    """Root of servo-bus errors."""


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


class ServoConfigError(ServoError, ValueError):
    """A servo-bus configuration is invalid, or names a joint that is not configured."""


# --- cameras -----------------------------------------------------------------------------
class CameraError(DriverError):
    """Root of camera errors."""


class CameraTimeoutError(CameraError, DeviceTimeoutError):
    """No frame (or no synchronised pair) arrived in time."""


class CameraLostError(CameraError, DeviceIOError):
    """The camera disappeared (unplugged, control lost); it is being reopened."""


class CameraConfigError(CameraError, ValueError):
    """A requested setting (pixel format, size, rate) is not supported by the camera."""
