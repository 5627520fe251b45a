"""The one exception hierarchy of `headctl`."""
from __future__ import annotations

# Config errors of every layer are this one type (servo-bus and camera config errors are
# subclasses), raised by the reader in `drivers/config/reader.py` with the key path, the value and
# what was expected; `headctl.config.head` sets the file.
from drivers.errors import ConfigError as ConfigError  # re-exported


class HeadctlError(Exception):
    """Root of every error raised by `headctl`."""


class ControlError(HeadctlError):
    """A client's request that cannot be carried out now (a map for another head, a look no
    longer queued); `field` names what is wrong. The API layer maps each kind to its answer."""

    def __init__(self, message: str, field: str | None = None) -> None:
        super().__init__(message)
        self.field = field


class InvalidRequestError(ControlError):
    """A request whose value is out of range (outside the image, the joint limits...)."""


class QueueFullError(ControlError):
    """The look queue is full."""


class NotFoundError(ControlError):
    """No such look or map file."""


class UnavailableError(ControlError):
    """The service cannot do it now (starting, stopping, not a simulated head, no recent frames...)."""


class StaleStateError(HeadctlError, TimeoutError):
    """The servo loop produced no fresh state in time."""


class ServoLoopStoppedError(HeadctlError):
    """The servo loop is not running (stopped, or failed)."""
