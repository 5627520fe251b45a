"""Servos by id, before anyone knows which joint each one turns: what `headctl setup` needs.

A `ServoBus` (`drivers.servo.bus`) works in joints and needs a config that names them; a
head being set up has no such config yet. `ServoProbe` is the small interface below it:
find the servos on a bus (`scan`), read one's state and its own position limits, and move
one under a torque limit, a velocity limit and a timeout (`MotionSafety`). Positions are
in the servo frame: degrees from the servo's centre position (tick 2048 on an X-series
servo), as `JointConfig.zero_offset` counts them.

Backends, chosen by `servo_bus.backend` through the table in `drivers.backends`:
`dynamixel` (`drivers.dynamixel.probe`: dynamixel-sdk, Protocol 1.0 and 2.0, every baud rate) and
`sim` (`drivers.sim.servos.SimulatedServoProbe`: the simulated head's servos by the ids of
its `servo_bus.wiring`, which the probe never reveals).
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Protocol, runtime_checkable

from drivers.clock import SYSTEM_CLOCK, Clock
from drivers.errors import BackendImportError, BackendNotFoundError, ServoConfigError
from drivers.servo.config import ServoBusConfig


@dataclass(frozen=True)
class FoundServo:
    """A servo that answered a scan."""

    servo_id: int
    model_number: int
    model_name: str
    firmware: int
    protocol: float
    baud: int


@dataclass(frozen=True)
class ServoStatus:
    """One servo's state, servo frame (degrees from centre); `min_deg`/`max_deg` are the
    servo's own position limits (what it refuses to go beyond)."""

    position_deg: float
    goal_deg: float
    moving: bool
    torque_on: bool
    hardware_error_bits: int
    temperature_c: float
    input_voltage_v: float
    min_deg: float
    max_deg: float


@dataclass(frozen=True)
class MotionSafety:
    """What every probing move runs under: a torque limit (a fraction of the servo's
    maximum), a velocity and acceleration limit, and `watchdog_s`: a servo that hears
    nothing from the host for that long stops (where the servo offers it; the host's own
    deadline per move applies always)."""

    torque_fraction: float = 0.3
    velocity_dps: float = 30.0
    acceleration_dps2: float = 200.0
    watchdog_s: float = 0.5


@runtime_checkable
class ServoProbe(Protocol):
    """Servos by id on one bus; see the module docstring. A context manager; `close()` is
    idempotent and leaves every servo as it is."""

    name: str

    def scan(self) -> list[FoundServo]:
        """Every servo that answers, at every baud rate and protocol the backend tries; the
        probe then talks to each at the baud and protocol it was found at."""

    def status(self, servo_id: int) -> ServoStatus: ...

    def limit_motion(self, servo_id: int, safety: MotionSafety) -> None:
        """Apply `safety` to the servo (torque, velocity, acceleration, watchdog), remembering
        what it had, for `restore_motion`."""

    def restore_motion(self, servo_id: int) -> None:
        """Put back what `limit_motion` changed (torque as it was stays the caller's job)."""

    def set_torque(self, servo_id: int, on: bool) -> None: ...

    def write_goal(self, servo_id: int, servo_deg: float) -> None:
        """A goal in the servo frame; `JointLimitError` beyond the servo's own limits."""

    def keep_alive(self, servo_id: int) -> None:
        """Disarm the servo's watchdog while it rests (the host may wait for frames)."""

    def close(self) -> None: ...

    def __enter__(self) -> "ServoProbe": ...

    def __exit__(self, *exc: object) -> None: ...


def create_servo_probe(config: ServoBusConfig, *, clock: Clock = SYSTEM_CLOCK, ids: Sequence[int] | None = None,
                       **resources: Any) -> ServoProbe:
    """The probe of backend `config.backend` (from the `servo_probe` table of
    `drivers.backends`); `ids` bounds the ids a scan tries (default all)."""
    from drivers.backends import resolve

    try:
        cls = resolve("servo_probe", config.backend)
    except (BackendNotFoundError, BackendImportError) as err:
        raise ServoConfigError(key_path=f"{config.key_path}.backend", value=config.backend,
                               expected=f"a backend that headctl setup can probe servos with ({err})") from None
    probe: ServoProbe = cls(config, clock=clock, ids=ids, **resources)
    return probe
