"""What the service and its servo process say to each other over their two pipes.

One frozen dataclass a kind of message, dispatched with `match` on either side. Requests
(`WriteGoals`, `SwitchTorque`, `InjectFault`) carry an id that their answer (`Done`) repeats.
An error crosses the boundary as a `RemoteError`: a kind from an explicit table of the
exceptions a request or the start can end with, and the message; the receiver raises the
kind's exception class again (its own fallback class for an exception outside the table).
"""
from __future__ import annotations

import dataclasses
import enum

from drivers.errors import (BusDownError, DriverError, JointLimitError, ServoCommError, ServoHardwareError,
                            ServoTimeoutError)
from drivers.servo.faults import HardwareErrorEpisode
from headctl.errors import ServoLoopStoppedError, StaleStateError


class ErrorKind(enum.Enum):
    """The exceptions that cross the process boundary as themselves; OTHER: any other."""

    BUS_DOWN = "bus_down"
    SERVO_HARDWARE = "servo_hardware"
    JOINT_LIMIT = "joint_limit"
    SERVO_COMM = "servo_comm"
    SERVO_TIMEOUT = "servo_timeout"
    DRIVER = "driver"
    LOOP_STOPPED = "loop_stopped"
    STALE_STATE = "stale_state"
    OTHER = "other"


# Matched on the exact class: a subclass outside the table (whose constructor may need more
# than a message) is OTHER, raised as the receiver's fallback class.
ERROR_CLASSES: dict[ErrorKind, type[Exception]] = {
    ErrorKind.BUS_DOWN: BusDownError,
    ErrorKind.SERVO_HARDWARE: ServoHardwareError,
    ErrorKind.JOINT_LIMIT: JointLimitError,
    ErrorKind.SERVO_COMM: ServoCommError,
    ErrorKind.SERVO_TIMEOUT: ServoTimeoutError,
    ErrorKind.DRIVER: DriverError,
    ErrorKind.LOOP_STOPPED: ServoLoopStoppedError,
    ErrorKind.STALE_STATE: StaleStateError,
}
_KINDS: dict[type[BaseException], ErrorKind] = {cls: kind for kind, cls in ERROR_CLASSES.items()}


@dataclasses.dataclass(frozen=True)
class RemoteError:
    """An exception raised on the other side of the pipes."""

    kind: ErrorKind
    text: str

    @classmethod
    def of(cls, err: BaseException) -> "RemoteError":
        return cls(_KINDS.get(type(err), ErrorKind.OTHER), str(err))

    def exception(self, fallback: type[Exception]) -> Exception:
        """The exception to raise here: the kind's class, `fallback` for OTHER."""
        return ERROR_CLASSES.get(self.kind, fallback)(self.text)


class ServoFault(enum.StrEnum):
    """The faults a simulated bus can be given."""

    BUS_DOWN = "bus_down"
    RESTORE_BUS = "restore_bus"
    HARDWARE_ERROR = "hardware_error"
    POWER_LOSS = "power_loss"
    POWER_BACK = "power_back"
    SERVO_REMOVE = "servo_remove"  # one servo off the bus (`joint`)
    SERVO_ADD = "servo_add"  # back, just powered up


# --- the service to the child ------------------------------------------------------------------
@dataclasses.dataclass(frozen=True)
class WriteGoals:
    """Have the next cycle write these goals (the bus checks the limits)."""

    rid: int
    goals: dict[str, float]


@dataclasses.dataclass(frozen=True)
class SwitchTorque:
    rid: int
    on: bool


@dataclasses.dataclass(frozen=True)
class InjectFault:
    """A simulated fault (the service checked the arguments)."""

    rid: int
    fault: ServoFault
    joint: str | None = None
    bits: int = 0


@dataclasses.dataclass(frozen=True)
class Stop:
    """Stop the loop, leaving the servos in `safe_state` ("hold" or "torque_off")."""

    safe_state: str


Request = WriteGoals | SwitchTorque | InjectFault | Stop


# --- the child to the service ------------------------------------------------------------------
@dataclasses.dataclass(frozen=True)
class Ready:
    """The bus is open and enabled; the loop runs."""

    bus_name: str


@dataclasses.dataclass(frozen=True)
class Failed:
    """The bus could not be opened or enabled; `Stopped` follows."""

    error: RemoteError


@dataclasses.dataclass(frozen=True)
class Done:
    """Request `rid` ran: what was sent (goals), or its error."""

    rid: int
    sent: dict[str, float] | None = None
    error: RemoteError | None = None


@dataclasses.dataclass(frozen=True)
class FaultsChanged:
    """The bus went down or came back, a joint faulted or cleared."""

    down_reason: str | None
    faults: dict[str, tuple[str, ...]]
    last_read_error: str
    missing: dict[str, str] = dataclasses.field(default_factory=dict)  # joint -> its description


@dataclasses.dataclass(frozen=True)
class Episode:
    """A record of the bus's fault log (`drivers.servo.faults`)."""

    record: HardwareErrorEpisode


@dataclasses.dataclass(frozen=True)
class LogRecord:
    """A log record of the child, re-emitted in the service's log."""

    level: int
    name: str
    text: str


@dataclasses.dataclass(frozen=True)
class Stopped:
    """The child has left the servos in the safe state and closed the bus; nothing follows."""


Report = Ready | Failed | Done | FaultsChanged | Episode | LogRecord | Stopped
