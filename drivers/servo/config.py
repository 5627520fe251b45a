"""The servo bus's configuration, typed: the four joints' servos, the wire, the policies.

`JointConfig` and `ServoBusConfig` are read from plain mappings (what YAML gives) by
`drivers.config.reader`: errors are `ServoConfigError`s naming the key path, the value and what was
expected. This is plain data: what a file may say about a bus is checked here, before any
bus exists; whether the backend it names uses those keys and drives those models is
checked by the backend table (`drivers.backends.check_servo_bus_config`), from the
keys a section gave (`set_keys`). A config names all four joints (`drivers.servo.joints`).
"""
from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, ClassVar

from drivers.config.reader import check_settings, config_meta, read_config, setting
from drivers.errors import ServoConfigError
from drivers.servo.joints import JOINTS
from drivers.sim.servo_mechanics import ServoMechanicsConfig

LIMIT_POLICIES: tuple[str, ...] = ("clamp", "refuse")
# What the bus does with torque when its servos lost power and came back (a brown-out):
# `restore` torque where it was on (goal := present first), or leave it `off` for a person.
POWER_LOSS_TORQUE: tuple[str, ...] = ("restore", "off")

# Baud rates an X-series servo offers that dynamixel-sdk 4.1.0 also accepts (its
# whitelist stops at 4 Mbps, so the servo's 4.5 Mbps is out of reach).
SUPPORTED_BAUDS: tuple[int, ...] = (9600, 57600, 115200, 1_000_000, 2_000_000, 3_000_000, 4_000_000)


# Dynamixel protocol versions: 2.0 (X-series), 1.0 (AX, RX, MX on Protocol 1.0 firmware).
PROTOCOLS: tuple[float, ...] = (2.0, 1.0)


@dataclass(frozen=True)
class JointConfig:
    """One joint's servo. Angles in degrees, velocity in deg/s, acceleration in deg/s^2.

    `zero_offset` is the servo angle (degrees from the servo's centre position, tick 2048
    on an X-series servo) at which the joint reads 0; `direction` -1 flips the joint's
    sign. So servo_angle = zero_offset + direction * joint_angle.
    A profile velocity or acceleration of 0 means "as fast as the servo can".
    The YAML key of `servo_id` is `id`.
    """

    servo_id: int = field(metadata=config_meta(key="id", lo=0, hi=252))
    model: str = "XM430-W350"
    direction: int = setting(1, choices=(1, -1))
    zero_offset: float = setting(0.0, lo=-180.0, hi=180.0)
    min_angle: float = setting(-90.0, lo=-360.0, hi=360.0)
    max_angle: float = setting(90.0, lo=-360.0, hi=360.0)
    profile_velocity: float = setting(120.0, lo=0.0, hi=10_000.0)
    profile_acceleration: float = setting(600.0, lo=0.0, hi=1e6)
    # The play between the servo's shaft (what its encoder reads) and the joint, degrees, the
    # whole width: the head sends goals beyond their targets by half of it in the direction of
    # approach (headctl.service.play). 0 for a joint a load keeps on one flank (the tilt).
    backlash_deg: float = setting(0.0, lo=0.0, hi=5.0)
    # The keys a mapping gave (set by the reader): a key given at its default value is still
    # refused by a backend that does not use it.
    given_keys: frozenset[str] = setting(frozenset(), source="given_keys", init=False, compare=False, repr=False)

    CONFIG_ERROR: ClassVar[type[ServoConfigError]] = ServoConfigError

    def __post_init__(self) -> None:
        check_settings(self)
        if self.min_angle >= self.max_angle:
            raise ServoConfigError(key_path="min_angle", value=self.min_angle,
                                   expected=f"less than max_angle ({self.max_angle})")
        for key, angle in (("min_angle", self.min_angle), ("max_angle", self.max_angle)):
            servo_deg = self.servo_angle(angle)
            # Position mode covers one turn around the centre: a limit beyond it can
            # never be reached and would wrap around on the servo.
            if not -180.0 <= servo_deg <= 180.0:
                raise ServoConfigError(
                    key_path=key, value=angle,
                    expected=f"an angle whose servo angle (zero_offset + direction * angle = {servo_deg:g}) "
                             "lies within [-180, 180]",
                )

    @classmethod
    def from_mapping(cls, data: Any, key_path: str) -> "JointConfig":
        return read_config(cls, data, key_path)

    def servo_angle(self, joint_angle: float) -> float:
        return self.zero_offset + self.direction * joint_angle

    def joint_angle(self, servo_angle: float) -> float:
        return self.direction * (servo_angle - self.zero_offset)


@dataclass(frozen=True)
class WiredServo:
    """How one servo of the simulated head is really mounted (`servo_bus.wiring.<id>`): the
    joint it turns (`none`: a servo on the bus that turns nothing the cameras see), and
    `direction` and `zero_offset` as in `JointConfig`; `off_bus`: it answers nothing when the
    simulation starts (a servo missing at start, until the `servo_add` fault). The simulated
    world's truth, which `headctl setup` has to find out from the bus and the cameras."""

    joint: str = field(metadata=config_meta(choices=(*JOINTS, "none")))
    direction: int = setting(1, choices=(1, -1))
    zero_offset: float = setting(0.0, lo=-180.0, hi=180.0)
    off_bus: bool = setting(False)

    CONFIG_ERROR: ClassVar[type[ServoConfigError]] = ServoConfigError

    def __post_init__(self) -> None:
        check_settings(self)

    def joint_angle(self, servo_angle: float) -> float:
        return self.direction * (servo_angle - self.zero_offset)

    def servo_angle(self, joint_angle: float) -> float:
        return self.zero_offset + self.direction * joint_angle


def read_wiring(data: Any) -> dict[int, WiredServo]:
    """`servo_bus.wiring` typed: servo id (0-252) -> `WiredServo`, each joint wired once.
    Key paths in errors are relative to the section (`wiring.7.joint`)."""
    if not isinstance(data, Mapping) or not data:
        raise ServoConfigError(key_path="wiring", value=data,
                               expected="a mapping of servo ids to {joint, direction, zero_offset}")
    wiring: dict[int, WiredServo] = {}
    wired: dict[str, int] = {}
    for key, entry in data.items():
        if isinstance(key, bool) or not isinstance(key, int) or not 0 <= key <= 252:
            raise ServoConfigError(key_path=f"wiring.{key}", value=key, expected="a servo id, an integer in [0, 252]")
        servo = entry if isinstance(entry, WiredServo) else read_config(WiredServo, entry, f"wiring.{key}")
        if servo.joint in wired and servo.joint != "none":
            raise ServoConfigError(key_path=f"wiring.{key}.joint", value=servo.joint,
                                   expected=f"a joint not already wired to id {wired[servo.joint]}")
        wired[servo.joint] = key
        wiring[key] = servo
    missing = [joint for joint in JOINTS if joint not in wired]
    if missing:
        raise ServoConfigError(key_path="wiring", value=sorted(wiring),
                               expected=f"a servo for every joint ({', '.join(missing)} missing)")
    return wiring


@dataclass(frozen=True)
class ServoBusConfig:
    """The servo bus: backend, port, wire settings, policies, and the four joints.

    `watchdog_ms` arms the servos' Bus Watchdog while torque is on (0 = off; 20 ms steps):
    a host that falls silent that long stops the head. `latency_timer_ms` is the USB
    adapter's latency timer (the udev rule sets 1 ms); reply timeouts are computed from it,
    and the simulated bus's timing with `mechanics.bus_timing`.
    `power_loss_torque` says whether servos that lost power and came back get their torque
    back (`restore`) or stay limp (`off`); their settings are written again either way.
    `key_path` is where the section was read (`servo_bus`), for messages.
    """

    joints: Mapping[str, JointConfig] = field(metadata=config_meta(
        keys=JOINTS, expected="the four joints' servos (headctl setup finds them: docs/setup.md)"))
    backend: str = "dynamixel"
    port: str = "/dev/head-servos"
    baud: int = setting(1_000_000, choices=SUPPORTED_BAUDS)
    protocol: float = setting(2.0, choices=PROTOCOLS)
    retries: int = setting(2, lo=0, hi=10)
    limit_policy: str = setting("clamp", choices=LIMIT_POLICIES)
    reboot_on_hardware_error: bool = True
    torque_on_close: bool = False
    power_loss_torque: str = setting("restore", choices=POWER_LOSS_TORQUE)
    watchdog_ms: int = setting(0, lo=0, hi=127 * 20, check=lambda ms: ms % 20 == 0,
                               expected="a multiple of 20 in [0, 2540] (the servo counts in 20 ms steps), 0 = off")
    return_delay_us: int = setting(0, lo=0, hi=508, check=lambda us: us % 2 == 0,
                                   expected="an even number in [0, 508] (the servo counts in 2 us steps)")
    latency_timer_ms: float = setting(1.0, lo=0.0, hi=255.0)
    # The simulated head's true wiring (servo id -> WiredServo; read by `read_wiring`); None:
    # each joint's servo wired as `joints` says. Only the `sim` backend uses it.
    wiring: Any = None
    # The simulated servos' mechanics (play, dead band, droop, encoder, bus timing): a preset
    # and overrides (`drivers.sim.servo_mechanics`). Only the `sim` backend uses it.
    mechanics: ServoMechanicsConfig = ServoMechanicsConfig()
    reboot_timeout_s: float = setting(2.0, lo=0.1, hi=60.0)
    key_path: str = setting("servo_bus", source="key_path")
    given_keys: frozenset[str] = setting(frozenset(), source="given_keys", init=False, compare=False, repr=False)

    CONFIG_ERROR: ClassVar[type[ServoConfigError]] = ServoConfigError

    def __post_init__(self) -> None:
        check_settings(self)
        seen: dict[int, str] = {}
        for joint, jc in self.joints.items():
            if jc.servo_id in seen:
                raise ServoConfigError(key_path=f"joints.{joint}.id", value=jc.servo_id,
                                       expected=f"an id not already used by joint {seen[jc.servo_id]}")
            seen[jc.servo_id] = joint
        if self.wiring is not None:
            object.__setattr__(self, "wiring", read_wiring(self.wiring))
            for joint, jc in self.joints.items():
                if jc.servo_id not in self.wiring:
                    raise ServoConfigError(key_path=f"joints.{joint}.id", value=jc.servo_id,
                                           expected=f"one of the ids wired ({', '.join(map(str, sorted(self.wiring)))})")

    @classmethod
    def from_mapping(cls, data: Any, key_path: str = "servo_bus") -> "ServoBusConfig":
        return read_config(cls, data, key_path)

    def joint_path(self, joint: str) -> str:
        return f"{self.key_path}.joints.{joint}"


@dataclass(frozen=True)
class PartialServoBusConfig(ServoBusConfig):
    """The `servo_bus` section of a head not set up yet (`headctl setup --config`): `joints`
    may be left out (all four or none), everything else as in `ServoBusConfig`."""

    joints: Mapping[str, JointConfig] = setting(default_factory=dict, keys=JOINTS)


def set_keys(section: JointConfig | ServoBusConfig) -> set[str]:
    """The YAML keys a section's mapping gave, or whose value differs from the default."""
    keys = set(section.given_keys)
    for f in dataclasses.fields(section):
        if f.init and f.name != "key_path" and getattr(section, f.name) != f.default:
            keys.add("id" if f.name == "servo_id" else f.name)
    return keys
