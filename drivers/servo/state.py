"""The states a servo bus reads (`drivers.servo.bus.ServoBus.read_state`): one joint's
(`JointState`) and the bus's, all joints in one transaction (`BusState`)."""
from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass


@dataclass(frozen=True)
class JointState:
    """One servo's state. From `ServoBus.read_state()` in joint units (degrees, deg/s), with
    `hardware_errors` the meanings of `hardware_error_bits` as the backend decodes them
    (`ServoBus.decode_hardware_error`); from a backend's `_read_servos()` hook in the servo
    frame, `hardware_errors` left empty."""

    position: float
    velocity: float
    moving: bool
    torque_on: bool
    hardware_error_bits: int
    temperature_c: float
    input_voltage_v: float
    hardware_errors: tuple[str, ...] = ()
    # The backend found the servo's RAM at its power-on defaults (it lost power and came back
    # since the bus configured it); the bus then initialises it again (`ServoBus.power_losses`).
    power_cycled: bool = False


@dataclass(frozen=True)
class BusState:
    """The joints that answer, read in one bus transaction; `time_s` is the monotonic clock
    at the middle of that transaction. `missing` names the joints whose servo does not
    answer (not in `joints`), each with its description (`MissingServo.describe`)."""

    time_s: float
    joints: Mapping[str, JointState]
    missing: Mapping[str, str] = dataclasses.field(default_factory=dict)

    def __getitem__(self, joint: str) -> JointState:
        return self.joints[joint]

    @property
    def positions(self) -> dict[str, float]:
        return {joint: s.position for joint, s in self.joints.items()}

    @property
    def moving(self) -> bool:
        return any(s.moving for s in self.joints.values())

    @property
    def faults(self) -> dict[str, tuple[str, ...]]:
        return {joint: s.hardware_errors for joint, s in self.joints.items() if s.hardware_error_bits}
