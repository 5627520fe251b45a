"""The servo-bus interface of the head: joint names, config, units, limits and recovery.

This module owns everything a servo backend shares:

* the four joint names (`JOINTS`); vergence (left_eye = +v/2, right_eye = -v/2) is
  composed above this layer;
* the typed configuration (`JointConfig`, `ServoBusConfig`) parsed from plain mappings
  (what YAML gives), unknown keys rejected with the key path, value and what was expected;
* the abstract `ServoBus`, whose public methods are template methods working in joint
  units (degrees, degrees/s, never ticks). Joint <-> servo frame conversion (direction,
  zero offset), limits (clamp or refuse), logging, the lifecycle, reboot recovery and
  reopening a bus that went down live here, once. A backend implements the small hooks
  `_connect`, `_disconnect`, `_configure`, `_read_servos`, `_write_servo_goals`,
  `_set_torque` and `_reboot_servo`, all in the servo frame: degrees from the servo's
  centre position, before direction and zero offset are applied.

All methods are safe to call from several threads: one lock serialises bus traffic.
"""
from __future__ import annotations

import abc
import dataclasses
import logging
import math
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from typing import Any, ClassVar, TypeVar

from drivers.base import Device
from drivers.clock import SYSTEM_CLOCK, Clock
from drivers.errors import (
    BusDownError,
    DriverError,
    JointLimitError,
    ServoConfigError,
    ServoHardwareError,
)

log = logging.getLogger(__name__)

# Per-packet traffic is logged below DEBUG (STYLE.md rule 8).
TRACE = 5

JOINTS: tuple[str, ...] = ("pan", "tilt", "left_eye", "right_eye")
LIMIT_POLICIES: tuple[str, ...] = ("clamp", "refuse")

# Hardware Error Status (X-series address 70): bit -> meaning.
HARDWARE_ERROR_BITS: dict[int, str] = {
    0: "input voltage out of range",
    2: "overheating",
    3: "motor encoder error",
    4: "electrical shock (motor circuit)",
    5: "overload",
}

# Baud rates an X-series servo offers that dynamixel-sdk 4.1.0 also accepts (its
# whitelist stops at 4 Mbps, so the servo's 4.5 Mbps is out of reach).
SUPPORTED_BAUDS: tuple[int, ...] = (9600, 57600, 115200, 1_000_000, 2_000_000, 3_000_000, 4_000_000)

# A hardware error that comes back this soon after an automatic reboot is reported, not
# rebooted again: an overheating servo would otherwise reboot in a loop.
AUTO_REBOOT_HOLDOFF_S = 10.0
# Reopening a bus that went down: first retry after this, doubling up to the maximum.
REOPEN_BACKOFF_FIRST_S = 0.1
REOPEN_BACKOFF_MAX_S = 5.0

T = TypeVar("T")


def decode_hardware_error(bits: int) -> tuple[str, ...]:
    """The meanings of the bits of a Hardware Error Status byte."""
    meanings = [meaning for bit, meaning in HARDWARE_ERROR_BITS.items() if bits & (1 << bit)]
    known_mask = sum(1 << bit for bit in HARDWARE_ERROR_BITS)
    if bits & ~known_mask:
        meanings.append(f"unknown bits 0x{bits & ~known_mask:02x}")
    return tuple(meanings)


# --- configuration ---------------------------------------------------------------------
_REQUIRED = object()


class _MappingReader:
    """Reads typed values out of one mapping of a config, naming key paths in errors."""

    def __init__(self, data: Any, key_path: str, allowed: Iterable[str]) -> None:
        self.allowed = tuple(allowed)
        if not isinstance(data, Mapping):
            raise ServoConfigError(f"{key_path}: expected a mapping with keys {', '.join(self.allowed)}, got {data!r}")
        for key in data:
            if key not in self.allowed:
                raise ServoConfigError(
                    f"{self.path(key_path, key)}: unknown key (value {data[key]!r}); "
                    f"expected one of: {', '.join(self.allowed)}"
                )
        self.data = data
        self.key_path = key_path

    @staticmethod
    def path(key_path: str, key: object) -> str:
        return f"{key_path}.{key}" if key_path else str(key)

    def _raw(self, key: str, default: Any) -> Any:
        if key in self.data:
            return self.data[key]
        if default is _REQUIRED:
            raise ServoConfigError(f"{self.path(self.key_path, key)}: missing (required)")
        return default

    def fail(self, key: str, value: object, expected: str) -> ServoConfigError:
        return ServoConfigError(f"{self.path(self.key_path, key)}: got {value!r}, expected {expected}")

    def number(self, key: str, default: Any = _REQUIRED, *, lo: float = -math.inf, hi: float = math.inf) -> float:
        value = self._raw(key, default)
        # bool is an int in Python; `true` for an angle is a config mistake, not 1.0.
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise self.fail(key, value, f"a number in [{lo}, {hi}]")
        if not lo <= value <= hi:
            raise self.fail(key, value, f"a number in [{lo}, {hi}]")
        return float(value)

    def integer(self, key: str, default: Any = _REQUIRED, *, lo: int, hi: int) -> int:
        value = self._raw(key, default)
        if isinstance(value, bool) or not isinstance(value, int) or not lo <= value <= hi:
            raise self.fail(key, value, f"an integer in [{lo}, {hi}]")
        return value

    def boolean(self, key: str, default: Any = _REQUIRED) -> bool:
        value = self._raw(key, default)
        if not isinstance(value, bool):
            raise self.fail(key, value, "true or false")
        return value

    def text(self, key: str, default: Any = _REQUIRED) -> str:
        value = self._raw(key, default)
        if not isinstance(value, str) or not value:
            raise self.fail(key, value, "a non-empty string")
        return value

    def choice(self, key: str, default: Any, choices: Iterable[Any]) -> Any:
        value = self._raw(key, default)
        choices = tuple(choices)
        if value not in choices:
            raise self.fail(key, value, f"one of {', '.join(map(str, choices))}")
        return value


@dataclass(frozen=True)
class JointConfig:
    """One joint's servo. Angles in degrees, velocity in deg/s, acceleration in deg/s^2.

    `zero_offset` is the servo angle (degrees from the servo's centre position, tick 2048
    on an X-series servo) at which the joint reads 0; `direction` -1 flips the joint's
    sign. So servo_angle = zero_offset + direction * joint_angle.
    A profile velocity or acceleration of 0 means "as fast as the servo can".
    """

    servo_id: int
    model: str = "XM430-W350"
    direction: int = 1
    zero_offset: float = 0.0
    min_angle: float = -90.0
    max_angle: float = 90.0
    profile_velocity: float = 120.0
    profile_acceleration: float = 600.0

    KEYS: ClassVar[tuple[str, ...]] = (
        "id", "model", "direction", "zero_offset", "min_angle", "max_angle",
        "profile_velocity", "profile_acceleration",
    )

    @classmethod
    def from_mapping(cls, data: Any, key_path: str) -> "JointConfig":
        r = _MappingReader(data, key_path, cls.KEYS)
        default = cls(servo_id=0)
        config = cls(
            servo_id=r.integer("id", lo=0, hi=252),
            model=r.text("model", default.model),
            direction=r.choice("direction", default.direction, (1, -1)),
            zero_offset=r.number("zero_offset", default.zero_offset, lo=-180.0, hi=180.0),
            min_angle=r.number("min_angle", default.min_angle, lo=-360.0, hi=360.0),
            max_angle=r.number("max_angle", default.max_angle, lo=-360.0, hi=360.0),
            profile_velocity=r.number("profile_velocity", default.profile_velocity, lo=0.0, hi=10_000.0),
            profile_acceleration=r.number("profile_acceleration", default.profile_acceleration, lo=0.0, hi=1e6),
        )
        if config.min_angle >= config.max_angle:
            raise r.fail("min_angle", config.min_angle, f"less than max_angle ({config.max_angle})")
        for key, angle in (("min_angle", config.min_angle), ("max_angle", config.max_angle)):
            servo_deg = config.servo_angle(angle)
            # Position mode covers one turn around the centre: a limit beyond it can
            # never be reached and would wrap around on the servo.
            if not -180.0 <= servo_deg <= 180.0:
                raise r.fail(
                    key, angle,
                    f"an angle whose servo angle (zero_offset + direction * angle = {servo_deg:g}) "
                    "lies within [-180, 180]",
                )
        return config

    def servo_angle(self, joint_angle: float) -> float:
        return self.zero_offset + self.direction * joint_angle

    def joint_angle(self, servo_angle: float) -> float:
        return self.direction * (servo_angle - self.zero_offset)


@dataclass(frozen=True)
class ServoBusConfig:
    """The servo bus: backend, port, wire settings, policies, and the four joints.

    `watchdog_ms` arms the servos' Bus Watchdog while torque is on (0 = off; 20 ms steps):
    a host that falls silent that long stops the head. `latency_timer_ms` is the USB
    adapter's latency timer (the udev rule sets 1 ms); reply timeouts are computed from it.
    """

    joints: Mapping[str, JointConfig]
    backend: str = "dynamixel"
    port: str = "/dev/head-servos"
    baud: int = 1_000_000
    protocol: float = 2.0
    retries: int = 2
    limit_policy: str = "clamp"
    reboot_on_hardware_error: bool = True
    torque_on_close: bool = False
    watchdog_ms: int = 0
    return_delay_us: int = 0
    latency_timer_ms: float = 1.0
    reboot_timeout_s: float = 2.0
    key_path: str = "servo_bus"

    KEYS: ClassVar[tuple[str, ...]] = (
        "backend", "port", "baud", "protocol", "retries", "limit_policy",
        "reboot_on_hardware_error", "torque_on_close", "watchdog_ms", "return_delay_us",
        "latency_timer_ms", "reboot_timeout_s", "joints",
    )

    @classmethod
    def from_mapping(cls, data: Any, key_path: str = "servo_bus") -> "ServoBusConfig":
        r = _MappingReader(data, key_path, cls.KEYS)
        joints_path = r.path(key_path, "joints")
        joints_data = r._raw("joints", _REQUIRED)
        jr = _MappingReader(joints_data, joints_path, JOINTS)
        missing = [j for j in JOINTS if j not in jr.data]
        if missing:
            raise ServoConfigError(f"{joints_path}: missing joint(s) {', '.join(missing)}; all of {', '.join(JOINTS)} are needed")
        joints = {j: JointConfig.from_mapping(jr.data[j], r.path(joints_path, j)) for j in JOINTS}
        seen: dict[int, str] = {}
        for joint, jc in joints.items():
            if jc.servo_id in seen:
                raise ServoConfigError(
                    f"{r.path(joints_path, joint)}.id: got {jc.servo_id}, expected an id not already used by joint {seen[jc.servo_id]}"
                )
            seen[jc.servo_id] = joint
        protocol = r._raw("protocol", 2.0)
        if protocol in ("2.0", "2"):
            protocol = 2.0
        if protocol in (1, 1.0, "1.0", "1"):
            # Why not 1.0: it has no Sync Read, so the state of four servos cannot be read
            # in one transaction (AX-12A has no Bulk Read either).
            raise r.fail(
                "protocol", protocol,
                "2.0: Protocol 1.0 (AX-12A, MX-28) is not supported because it cannot read all joints "
                "in one transaction; MX-28 can be switched to Protocol 2.0 firmware with DYNAMIXEL Wizard",
            )
        if protocol != 2.0:
            raise r.fail("protocol", protocol, "2.0")
        watchdog_ms = r.integer("watchdog_ms", cls.watchdog_ms, lo=0, hi=127 * 20)
        if watchdog_ms % 20:
            raise r.fail("watchdog_ms", watchdog_ms, "a multiple of 20 (the servo counts in 20 ms steps), 0 = off")
        return_delay_us = r.integer("return_delay_us", cls.return_delay_us, lo=0, hi=508)
        if return_delay_us % 2:
            raise r.fail("return_delay_us", return_delay_us, "an even number (the servo counts in 2 us steps)")
        return cls(
            joints=joints,
            backend=r.text("backend", cls.backend),
            port=r.text("port", cls.port),
            baud=r.choice("baud", cls.baud, SUPPORTED_BAUDS),
            protocol=2.0,
            retries=r.integer("retries", cls.retries, lo=0, hi=10),
            limit_policy=r.choice("limit_policy", cls.limit_policy, LIMIT_POLICIES),
            reboot_on_hardware_error=r.boolean("reboot_on_hardware_error", cls.reboot_on_hardware_error),
            torque_on_close=r.boolean("torque_on_close", cls.torque_on_close),
            watchdog_ms=watchdog_ms,
            return_delay_us=return_delay_us,
            latency_timer_ms=r.number("latency_timer_ms", cls.latency_timer_ms, lo=0.0, hi=255.0),
            reboot_timeout_s=r.number("reboot_timeout_s", cls.reboot_timeout_s, lo=0.1, hi=60.0),
            key_path=key_path,
        )

    def joint_path(self, joint: str) -> str:
        return f"{self.key_path}.joints.{joint}"


# --- state -----------------------------------------------------------------------------
@dataclass(frozen=True)
class JointState:
    """One servo's state. From `ServoBus.read_state()` in joint units (degrees, deg/s);
    from a backend's `_read_servos()` hook in the servo frame."""

    position: float
    velocity: float
    moving: bool
    torque_on: bool
    hardware_error_bits: int
    temperature_c: float
    input_voltage_v: float

    @property
    def hardware_errors(self) -> tuple[str, ...]:
        return decode_hardware_error(self.hardware_error_bits)


@dataclass(frozen=True)
class BusState:
    """All joints, read in one bus transaction; `time_s` is the monotonic clock at the
    middle of that transaction."""

    time_s: float
    joints: Mapping[str, JointState]

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


# --- the interface ---------------------------------------------------------------------
class ServoBus(Device, abc.ABC):
    """The four joints of the head on one bus, in joint units.

    Lifecycle (`drivers.base`): `open()` connects and configures the servos (states become
    readable), `enable()` turns torque on after setting each goal to the present position
    (no jump), `disable()` turns torque off, `close()` leaves torque as configured.

    If the bus goes down (adapter unplugged), calls raise `BusDownError` and the bus
    reopens itself with a growing back-off on later calls; once back, torque is restored
    (if the bus was enabled) only after positions have been read back.
    """

    # What a backend offers, declared rather than discovered by exceptions.
    capabilities: ClassVar[frozenset[str]] = frozenset()

    def __init__(self, config: ServoBusConfig, *, clock: Clock = SYSTEM_CLOCK, name: str | None = None) -> None:
        super().__init__(name or config.port)
        self.config = config
        self.clock = clock
        self._connected = False
        self._down_reason: str | None = None
        self._reopen_backoff_s = REOPEN_BACKOFF_FIRST_S
        self._next_reopen_s = 0.0
        self._reopen_attempts = 0
        self._faults: dict[str, int] = {}        # joint -> hardware error bits, last read
        self._shut_down: set[str] = set()          # faulted joints whose torque is off
        self._last_auto_reboot_s: dict[str, float] = {}
        self._clamping: set[str] = set()
        self._torque_off_pending = False  # disable() failed while the bus was down

    # -- public API ----------------------------------------------------------------------
    @property
    def is_down(self) -> bool:
        """True while the bus is down and being reopened."""
        return self._down_reason is not None

    def describe(self, joint: str) -> str:
        """'joint pan (id 1) on /dev/head-servos': how messages name a joint."""
        return f"joint {joint} (id {self.config.joints[joint].servo_id}) on {self.name}"

    def read_state(self) -> BusState:
        """Position, velocity, moving flag, hardware errors, temperature and input voltage
        of every joint, read in one bus transaction.

        A hardware error is logged with its meaning; with `reboot_on_hardware_error` the
        servo is rebooted and (if enabled) re-torqued before the state is returned.
        """
        with self._lifecycle_lock:
            self.require_open()
            state = self._io(self._read_state_once)
            return self._after_read(state)

    def write_goals(self, goals: Mapping[str, float]) -> dict[str, float]:
        """Send goal positions (degrees) for some or all joints in one transaction.

        Goals outside a joint's limits are clamped (and logged) or the whole command is
        refused with `JointLimitError`, as configured; such a goal is never sent. Returns
        the goals actually sent. Needs an enabled bus.
        """
        with self._lifecycle_lock:
            self.require_enabled()
            checked = self._check_goals(goals)
            servo_goals = {j: self.config.joints[j].servo_angle(a) for j, a in checked.items()}
            log.log(TRACE, "%s: goals %s", self.name, checked)
            self._io(lambda: self._write_servo_goals(servo_goals))
            return checked

    def reboot(self, joint: str) -> None:
        """Reboot one servo (clears its hardware error, restores RAM defaults), configure
        it again, and if the bus is enabled restore its torque after reading it back."""
        with self._lifecycle_lock:
            self.require_open()
            self._check_joint(joint)
            self._io(lambda: self._reboot_and_restore(joint, "requested"))

    # -- lifecycle hooks of Device, as templates over the servo hooks --------------------
    def _open(self) -> None:
        self._down_reason = None
        self._faults.clear()
        self._shut_down.clear()
        self._connect()
        self._connected = True
        self._configure(JOINTS)
        log.info("%s: servo bus open (%s)", self.name, ", ".join(self.describe(j) for j in JOINTS))

    def _enable(self) -> None:
        self._io(self._enable_now)

    def _enable_now(self) -> None:
        state = self._read_state_once()
        if self.config.reboot_on_hardware_error:
            for joint, joint_state in state.joints.items():
                if joint_state.hardware_error_bits:
                    self._reboot_and_restore(joint, "hardware error at enable")
        try:
            # A servo whose error cut its torque refuses it: the backend raises
            # ServoHardwareError naming it.
            self._restore_torque(JOINTS)
        except DriverError:
            # All or nothing: do not leave some joints torqued on a bus that is not enabled.
            try:
                self._set_torque(JOINTS, False)
            except DriverError as err:
                log.warning("%s: could not undo a partial enable: %s", self.name, err)
            raise
        self._torque_off_pending = False
        log.info("%s: torque on", self.name)

    def _disable(self) -> None:
        try:
            self._io(lambda: self._set_torque(JOINTS, False))
        except BusDownError:
            # Torque goes off as soon as the bus is back (see _reopen_if_due).
            self._torque_off_pending = True
            raise
        log.info("%s: torque off", self.name)

    def _close(self) -> None:
        try:
            if self._connected and not self.is_down:
                if not self.config.torque_on_close:
                    self._set_torque(JOINTS, False)
                elif self.is_enabled:
                    log.info("%s: leaving torque on at close (torque_on_close: true)", self.name)
        except (DriverError, OSError) as err:
            log.warning("%s: could not set torque at close: %s", self.name, err)
        finally:
            self._connected = False
            self._disconnect()

    # -- internals -----------------------------------------------------------------------
    def _io(self, action: Callable[[], T]) -> T:
        """Run one bus action (the lock is held), reopening a downed bus first."""
        self._reopen_if_due()
        try:
            return action()
        except BusDownError as err:
            self._mark_down(err)
            raise

    def _mark_down(self, err: BaseException) -> None:
        if self._down_reason is None:
            log.error("%s: bus down (%s); reopening with back-off", self.name, err)
            self._reopen_backoff_s = REOPEN_BACKOFF_FIRST_S
            self._reopen_attempts = 0
            self._next_reopen_s = self.clock.monotonic() + self._reopen_backoff_s
        self._down_reason = str(err)

    def _reopen_if_due(self) -> None:
        if self._down_reason is None:
            return
        now = self.clock.monotonic()
        if now < self._next_reopen_s:
            raise BusDownError(
                f"{self.name}: bus down ({self._down_reason}); next reopen attempt in "
                f"{self._next_reopen_s - now:.2f} s"
            )
        self._reopen_attempts += 1
        try:
            self._connected = False
            self._disconnect()
            self._connect()
            self._connected = True
            self._configure(JOINTS)
            if self.is_enabled:
                self._restore_torque(JOINTS)
            elif self._torque_off_pending:
                self._set_torque(JOINTS, False)
                self._torque_off_pending = False
        except (DriverError, OSError) as err:
            self._reopen_backoff_s = min(self._reopen_backoff_s * 2.0, REOPEN_BACKOFF_MAX_S)
            self._next_reopen_s = now + self._reopen_backoff_s
            raise BusDownError(
                f"{self.name}: bus down; reopen attempt {self._reopen_attempts} failed ({err}); "
                f"next in {self._reopen_backoff_s:.2f} s"
            ) from err
        log.warning("%s: bus back up after %d reopen attempt(s)%s", self.name, self._reopen_attempts,
                    "; torque restored" if self.is_enabled else "")
        self._down_reason = None

    def _read_state_once(self) -> BusState:
        start_s = self.clock.monotonic()
        servo_states = self._read_servos()
        end_s = self.clock.monotonic()
        joints = {}
        for joint in JOINTS:
            jc = self.config.joints[joint]
            raw = servo_states[joint]
            joints[joint] = dataclasses.replace(
                raw, position=jc.joint_angle(raw.position), velocity=jc.direction * raw.velocity
            )
        return BusState(time_s=(start_s + end_s) / 2.0, joints=joints)

    def _after_read(self, state: BusState) -> BusState:
        """Log hardware errors once per change; reboot when configured; restore lost torque.

        Only a hardware error that cut a servo's torque (its Shutdown setting) is rebooted
        away: one that leaves torque on (by default, input voltage) is reported, since a
        reboot would drop the joint for nothing.
        """
        for joint, joint_state in state.joints.items():
            bits = joint_state.hardware_error_bits
            if bits and self._faults.get(joint) != bits:
                log.error("%s", self._hardware_error(joint, bits, "reported"))
            elif not bits and joint in self._faults:
                log.info("%s: hardware error cleared", self.describe(joint))
        self._note_faults(state)
        acted = False
        now = self.clock.monotonic()
        if self.config.reboot_on_hardware_error:
            for joint in [j for j in self._faults if not state[j].torque_on]:
                if now - self._last_auto_reboot_s.get(joint, -math.inf) < AUTO_REBOOT_HOLDOFF_S:
                    continue  # came back right after a reboot: report, do not loop
                self._last_auto_reboot_s[joint] = now
                self._io(lambda joint=joint: self._reboot_and_restore(joint, "hardware error"))
                acted = True
        if self.is_enabled:
            # Torque found off without a hardware error: the servo lost power and came
            # back. Restore it the safe way (positions read back first).
            lost = [j for j, s in state.joints.items() if not s.torque_on and j not in self._faults]
            if lost:
                log.warning("%s: torque found off on %s; restoring it", self.name, ", ".join(lost))
                self._io(lambda: self._restore_torque(lost))
                acted = True
        if acted:
            state = self._io(self._read_state_once)
            self._note_faults(state)
        return state

    def _note_faults(self, state: BusState) -> None:
        self._faults = {j: s.hardware_error_bits for j, s in state.joints.items() if s.hardware_error_bits}
        self._shut_down = {j for j in self._faults if not state[j].torque_on}

    def _reboot_and_restore(self, joint: str, reason: str) -> None:
        log.warning("%s: rebooting (%s)", self.describe(joint), reason)
        self._reboot_servo(joint)
        self._configure([joint])
        if self.is_enabled:
            self._restore_torque([joint])
        self._faults.pop(joint, None)
        self._shut_down.discard(joint)
        log.info("%s: rebooted%s", self.describe(joint), ", torque restored" if self.is_enabled else "")

    def _restore_torque(self, joints: Iterable[str]) -> None:
        """Torque on without a jump: read positions back, goal = present, then torque."""
        joints = list(joints)
        present = self._read_servos()
        self._write_servo_goals({j: present[j].position for j in joints})
        self._set_torque(joints, True)

    def _check_joint(self, joint: str) -> None:
        if joint not in self.config.joints:
            raise ServoConfigError(f"{self.name}: no joint {joint!r}; expected one of {', '.join(JOINTS)}")

    def _hardware_error(self, joint: str, bits: int, what: str) -> ServoHardwareError:
        meanings = "; ".join(decode_hardware_error(bits))
        return ServoHardwareError(f"{self.describe(joint)}: hardware error 0x{bits:02x} {what}: {meanings}")

    def _check_goals(self, goals: Mapping[str, float]) -> dict[str, float]:
        checked: dict[str, float] = {}
        for joint, angle in goals.items():
            self._check_joint(joint)
            jc = self.config.joints[joint]
            if not isinstance(angle, (int, float)) or not math.isfinite(angle):
                raise JointLimitError(f"{self.describe(joint)}: goal {angle!r} is not a finite angle; nothing sent")
            if joint in self._shut_down:
                raise self._hardware_error(
                    joint, self._faults[joint], "cut its torque (it ignores goals until rebooted: call reboot())"
                )
            if jc.min_angle <= angle <= jc.max_angle:
                if joint in self._clamping:
                    self._clamping.discard(joint)
                    log.info("%s: goals back within limits", self.describe(joint))
                checked[joint] = float(angle)
                continue
            if self.config.limit_policy == "refuse":
                raise JointLimitError(
                    f"{self.describe(joint)}: goal {angle:g} deg outside limits "
                    f"[{jc.min_angle:g}, {jc.max_angle:g}]; command refused, nothing sent"
                )
            clamped = min(max(float(angle), jc.min_angle), jc.max_angle)
            # Log the first clamp of an excursion loudly, the rest quietly: at 100 Hz a
            # warning per cycle would drown the log.
            level = logging.DEBUG if joint in self._clamping else logging.WARNING
            self._clamping.add(joint)
            log.log(level, "%s: goal %g deg outside limits [%g, %g]; clamped to %g",
                    self.describe(joint), angle, jc.min_angle, jc.max_angle, clamped)
            checked[joint] = clamped
        return checked

    # -- hooks for backends (servo frame: degrees from the servo's centre) ---------------
    @abc.abstractmethod
    def _connect(self) -> None:
        """Open the transport and check the servos are there and of the configured model."""

    def _disconnect(self) -> None:
        """Release the transport. Must tolerate a partial connect and a dead port."""

    def _configure(self, joints: Iterable[str]) -> None:
        """(Re)apply per-servo settings (profiles, limits, ...), leaving torque as it was."""

    @abc.abstractmethod
    def _read_servos(self) -> dict[str, JointState]:
        """All joints' states in the servo frame, in one transaction."""

    @abc.abstractmethod
    def _write_servo_goals(self, goals_deg: Mapping[str, float]) -> None:
        """Send goal positions (servo frame) in one transaction; no reply expected."""

    @abc.abstractmethod
    def _set_torque(self, joints: Iterable[str], on: bool) -> None:
        """Torque on or off for the given joints."""

    @abc.abstractmethod
    def _reboot_servo(self, joint: str) -> None:
        """Reboot one servo and return once it answers again."""


def create_servo_bus(config: ServoBusConfig, *, clock: Clock = SYSTEM_CLOCK) -> ServoBus:
    """Construct (not open) the backend `config.backend` names."""
    from drivers.backends import resolve

    cls = resolve("servo_bus", config.backend)
    if not (isinstance(cls, type) and issubclass(cls, ServoBus)):
        raise ServoConfigError(f"{config.key_path}.backend: {config.backend!r} is not a ServoBus backend")
    return cls(config, clock=clock)
