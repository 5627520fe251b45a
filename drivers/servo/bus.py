"""The servo-bus interface of the head: joint names, states, units, limits and recovery.

This module owns everything a servo backend shares:

* the four joint names (`JOINTS`, `drivers.servo.joints`); vergence is composed above this layer;
* the config a bus is built from (`ServoBusConfig`), defined in `drivers.servo.config` and
  checked against its backend by `drivers.backends`;
* joint states (`JointState`, `BusState`), with the meanings of a servo's hardware error
  bits as its backend decodes them (`ServoBus.decode_hardware_error`);
* the abstract `ServoBus`, whose public methods are template methods working in joint
  units (degrees, degrees/s, never ticks). Joint <-> servo frame conversion (direction,
  zero offset), limits (clamp or refuse), logging, the lifecycle, reboot recovery and
  reopening a bus that went down, or driving around a missing servo, live here, once. A
  backend implements the small hooks `_connect`, `_probe_servo`, `_joints_changed`,
  `_disconnect`, `_configure`, `_read_servos`, `_write_servo_goals`, `_set_torque` and
  `_reboot_servo`, over the joints that answer (`present_joints`), in the servo frame:
  degrees from the servo's centre position, before direction and zero offset are applied.

All methods are safe to call from several threads: one lock serialises bus traffic.
"""
from __future__ import annotations

import abc
import dataclasses
import functools
import logging
import math
from collections.abc import Callable, Iterable, Mapping
from typing import Any, ClassVar, TypeVar

from drivers import backends
from drivers.base import Device, Lifecycle
from drivers.clock import SYSTEM_CLOCK, Clock
from drivers.servo.faults import (
    LEFT_TO_A_PERSON,
    REBOOT_FAILED,
    REBOOTED,
    REBOOTING,
    REPORTED,
    EpisodeRecorder,
    FaultLog,
    cleared_detail,
)
from drivers.servo.config import ServoBusConfig as ServoBusConfig
from drivers.servo.joints import JOINTS as JOINTS
from drivers.servo.missing import MissingServo, MissingServos
from drivers.servo.state import BusState as BusState, JointState as JointState
from drivers.servo.recovery import Fault, FaultRecovery
from drivers.errors import (
    BusDownError,
    DriverError,
    JointLimitError,
    ServoCommError,
    ServoConfigError,
    ServoError,
    ServoHardwareError,
    ServoTimeoutError,
)

log = logging.getLogger(__name__)

# Per-packet traffic is logged below DEBUG (docs/development.md, "Code conventions").
TRACE = 5

# Reopening a bus that went down: first retry after this, doubling up to the maximum.
REOPEN_BACKOFF_FIRST_S = 0.1
REOPEN_BACKOFF_MAX_S = 5.0

T = TypeVar("T")


# --- the interface ---------------------------------------------------------------------
class ServoBus(Device, abc.ABC):
    """The four joints of the head on one bus, in joint units.

    Lifecycle (`drivers.base`): `open()` connects and configures the servos (states become
    readable), `enable()` turns torque on after setting each goal to the present position
    (no jump), `disable()` turns torque off, `close()` leaves torque as configured.

    If the bus goes down (adapter unplugged), calls raise `BusDownError` and the bus
    reopens itself with a growing back-off on later calls; once back, torque is restored
    (if the bus was enabled) only after positions have been read back.

    A servo silent at open (a reopen), or whose reads fail alone for 0.5 s, is recorded in
    `missing` (`drivers.servo.missing`); only a port that cannot open, a wrong model or no
    servo answering fail the open. The others are driven; a missing joint has no state (it
    is named in `BusState.missing`), is sent no goal, and is pinged from `read_state()` with
    back-off; once it answers it is configured and, if enabled, torqued at goal := present.

    Hardware errors: `fault_log` (`drivers.servo.faults.FaultLog`) records every episode,
    even one rebooted away inside a single `read_state()`, with what recovery did and when
    it cleared; `recovery.reboots` counts automatic reboots by (joint, reason) and
    `recovery.given_up` names the joints left to a person. All three may be read from any
    thread without the bus's lock.
    """

    # What a backend offers, declared rather than discovered by exceptions.
    capabilities: ClassVar[frozenset[str]] = frozenset()
    # True on a simulation that tells where its servos really are (`true_position`, and the
    # trace of their motion, `true_trace`): what simulated cameras render from.
    reports_true_motion: ClassVar[bool] = False
    # Config keys this backend uses beyond the common ones (`drivers.backends.SERVO_BUS_COMMON_KEYS`,
    # `SERVO_JOINT_COMMON_KEYS`); others set in a config are refused when it loads.
    CONFIG_KEYS: ClassVar[frozenset[str]] = frozenset()
    JOINT_CONFIG_KEYS: ClassVar[frozenset[str]] = frozenset()
    # The servo models (`joints.<joint>.model`) this backend drives; None: it does not check models.
    MODELS: ClassVar[frozenset[str] | None] = None

    @classmethod
    def decode_hardware_error(cls, bits: int) -> tuple[str, ...]:
        """The meanings of a servo's hardware error bits, as this backend's servos define them
        (a backend overrides this; here the bits are only named)."""
        return (f"hardware error bits 0x{bits:02x}",) if bits else ()

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
        self.recovery = FaultRecovery()  # the one owner of automatic reboots
        self.fault_log = FaultLog()
        self._episodes = EpisodeRecorder(self.fault_log, self.name)
        self._clamping: set[str] = set()
        self._torque_off_pending = False  # disable() failed while the bus was down
        self._missing = MissingServos({j: c.servo_id for j, c in config.joints.items()}, self.name)
        self.power_losses = 0  # times servos were found to have lost power and come back
        self.last_power_loss: str | None = None  # what the last one was and what was done

    # -- public API ----------------------------------------------------------------------
    @property
    def is_down(self) -> bool:
        """True while the bus is down and being reopened."""
        return self._down_reason is not None

    @property
    def missing(self) -> Mapping[str, MissingServo]:
        """The joints whose servo does not answer (any thread may read it)."""
        return self._missing.snapshot()

    @property
    def present_joints(self) -> tuple[str, ...]:
        """The joints whose servo answers, in `JOINTS` order."""
        return tuple(j for j in JOINTS if j not in self._missing)

    def describe(self, joint: str) -> str:
        """'joint pan (id 1) on /dev/head-servos': how messages name a joint."""
        return f"joint {joint} (id {self.config.joints[joint].servo_id}) on {self.name}"

    def read_state(self) -> BusState:
        """Position, velocity, moving flag, hardware errors, temperature and input voltage
        of every joint, read in one bus transaction.

        A hardware error is logged with its meaning and recorded in `fault_log`; with
        `reboot_on_hardware_error` the servo is rebooted as the recovery policy says and (if
        enabled) re-torqued before the state is returned, so the state may read clear while
        the log holds the episode. Missing joints due a ping are pinged first.
        """
        with self._lifecycle_lock:
            self.require_open()
            state = self._io(self._read_watching_missing)
            return self._after_read(state)

    def write_goals(self, goals: Mapping[str, float]) -> dict[str, float]:
        """Send goal positions (degrees) for some or all joints in one transaction.

        Goals outside a joint's limits are clamped (and logged) or the whole command is
        refused with `JointLimitError`, as configured; such a goal, or one for a missing
        joint, is never sent. Returns the goals actually sent. Needs an enabled bus.
        """
        with self._lifecycle_lock:
            self.require_enabled()
            checked = self._check_goals(goals)
            missing = self._missing.snapshot()
            sent = {j: a for j, a in checked.items() if j not in missing}
            servo_goals = {j: self.config.joints[j].servo_angle(a) for j, a in sent.items()}
            log.log(TRACE, "%s: goals %s (missing: %s)", self.name, sent, sorted(set(checked) - set(sent)))
            if servo_goals:
                self._io(lambda: self._write_servo_goals(servo_goals))
            return sent

    def reboot(self, joint: str) -> None:
        """Reboot one servo (clears its hardware error, restores RAM defaults), configure
        it again, and if the bus is enabled restore its torque after reading it back."""
        with self._lifecycle_lock:
            self.require_open()
            self._check_joint(joint)
            missing = self._missing.snapshot().get(joint)
            if missing is not None:
                raise ServoTimeoutError(f"{missing.describe()}; not rebooted (it is pinged again with back-off)")
            self._io(lambda: self._reboot_and_restore(joint, "requested"))
            self.recovery.rebooted_by_hand(joint)
            self._episodes.rebooted_by_hand(joint)

    # -- lifecycle hooks of Device, as templates over the servo hooks --------------------
    def _open(self) -> None:
        self._down_reason = None
        self._faults.clear()
        self._shut_down.clear()
        self._connect_servos()
        log.info("%s: servo bus open (%s)%s", self.name, ", ".join(self.describe(j) for j in self.present_joints),
                 "; missing: " + ", ".join(self._missing.snapshot()) if self._missing.snapshot() else "")

    def _connect_servos(self) -> None:
        """Connect, ping each servo, record the silent ones, configure the others."""
        self._connect()
        self._connected = True
        try:
            self._missing.probe_all(JOINTS, self._probe_servo, self.clock.monotonic(), self.name)
        except ServoCommError:
            self._connected = False  # no servo answered: nothing to leave in a safe state
            raise
        self._configure(self.present_joints)
        self._joints_changed()

    def _enable(self) -> None:
        self._io(self._enable_now)

    def _enable_now(self) -> None:
        state = self._read_state_once()
        now_s = self.clock.monotonic()
        verdicts: dict[str, str] = {}
        for joint, joint_state in state.joints.items():
            if not joint_state.hardware_error_bits:
                continue
            if not self.config.reboot_on_hardware_error:
                verdicts[joint] = REPORTED
            elif joint in self.recovery.given_up:
                verdicts[joint] = LEFT_TO_A_PERSON
            else:
                verdicts[joint] = REBOOTING
                self.recovery.note_reboot(joint, "at enable: " + ", ".join(joint_state.hardware_errors), now_s)
        self._record_episodes(state, now_s, verdicts)
        for joint, verdict in verdicts.items():
            if verdict == REBOOTING:
                self._auto_reboot(joint, "hardware error at enable")
        try:
            # A servo whose error cut its torque refuses it: the backend raises
            # ServoHardwareError naming it.
            self._restore_torque(self.present_joints)
        except DriverError:
            # All or nothing: do not leave some joints torqued on a bus that is not enabled.
            try:
                self._set_torque(self.present_joints, False)
            except DriverError as err:
                log.warning("%s: could not undo a partial enable: %s", self.name, err)
            raise
        self._torque_off_pending = False
        log.info("%s: torque on", self.name)

    def _disable(self) -> None:
        try:
            self._io(lambda: self._set_torque(self.present_joints, False))
        except BusDownError:
            # Torque goes off as soon as the bus is back (see _reopen_if_due).
            self._torque_off_pending = True
            raise
        log.info("%s: torque off", self.name)

    def _close(self) -> None:
        try:
            if self._connected and not self.is_down:
                if not self.config.torque_on_close:
                    self._set_torque(self.present_joints, False)
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
            self._connect_servos()
            if self.is_enabled:
                self._restore_torque(self.present_joints)
            elif self._torque_off_pending:
                self._set_torque(self.present_joints, False)
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

    def _read_watching_missing(self) -> BusState:
        """Ping the missing joints that are due, then read; a joint failing alone long
        enough is recorded missing and the others read at once."""
        self._ping_missing()
        present = self.present_joints
        try:
            state = self._read_state_once()
        except BusDownError:
            raise
        except ServoError as err:
            now_s = self.clock.monotonic()
            dropped = self._missing.read_failed(err.joints, present, now_s)
            if not dropped:
                raise
            for joint in dropped:
                self._missing.add(joint, err, now_s, f": left the bus (its reads failed alone for "
                                                     f"{self._missing.drop_after_s:g} s)")
                self._faults.pop(joint, None)
                self._shut_down.discard(joint)
            self._joints_changed()
            state = self._read_state_once()
        self._missing.read_ok()
        return state

    def _ping_missing(self) -> None:
        """Ping each missing joint whose back-off has passed; one that answers is configured,
        and given goal := present position and torque if the bus is enabled."""
        now_s = self.clock.monotonic()
        for entry in self._missing.ping_due(now_s, self._probe_and_configure):
            joint, torque = entry.joint, ""
            try:
                self._joints_changed()
                if self.is_enabled:
                    self._restore_torque([joint])
                    torque = "; torque on at its present position"
            except BusDownError:
                raise
            except ServoError as err:
                torque = f"; torque not restored: {err}"
            log.warning("%s: answers again after %.1f s; configured%s", self.describe(joint), now_s - entry.since_s,
                        torque)

    def _probe_and_configure(self, joint: str) -> None:
        self._probe_servo(joint)
        self._configure([joint])

    def _read_state_once(self) -> BusState:
        start_s = self.clock.monotonic()
        servo_states = self._read_servos()
        end_s = self.clock.monotonic()
        joints = {}
        missing = self._missing.snapshot()
        for joint in JOINTS:
            if joint in missing:
                continue
            jc = self.config.joints[joint]
            raw = servo_states[joint]
            joints[joint] = dataclasses.replace(
                raw, position=jc.joint_angle(raw.position), velocity=jc.direction * raw.velocity,
                hardware_errors=self.decode_hardware_error(raw.hardware_error_bits),
            )
        return BusState(time_s=(start_s + end_s) / 2.0, joints=joints,
                        missing={j: m.describe() for j, m in missing.items()})

    def _after_read(self, state: BusState) -> BusState:
        """Log hardware errors once per change; reboot as the recovery policy says
        (`drivers.servo.recovery`); record every episode and what was done about it
        (`fault_log`); restore torque lost without an error."""
        for joint, joint_state in state.joints.items():
            bits = joint_state.hardware_error_bits
            if bits and self._faults.get(joint) != bits:
                log.error("%s", self._hardware_error(joint, bits, "reported"))
            elif not bits and joint in self._faults:
                log.info("%s: hardware error cleared", self.describe(joint))
        self._note_faults(state)
        now_s = self.clock.monotonic()
        faults = {j: Fault(self.decode_hardware_error(bits), state[j].torque_on) for j, bits in self._faults.items()}
        if self.config.reboot_on_hardware_error:
            verdicts = self.recovery.assess(faults, now_s)
        else:
            verdicts = {joint: REPORTED for joint in faults}
        self._record_episodes(state, now_s, verdicts)
        # A servo whose RAM is back at its defaults, or whose torque is off without a hardware
        # error while the bus is enabled, lost power and came back (a brown-out): initialised
        # again before any reboot, so that the torque policy holds for the reboots too.
        lost = [j for j, s in state.joints.items()
                if s.power_cycled or (self.is_enabled and not s.torque_on and j not in self._faults)]
        acted = bool(lost)
        if lost:
            self._io(functools.partial(self._power_back, lost))
        for joint, verdict in verdicts.items():
            if verdict == REBOOTING:
                self._io(functools.partial(self._auto_reboot, joint, faults[joint].reason))
                acted = True
        if acted:
            state = self._io(self._read_state_once)
            self._note_faults(state)
            self._record_episodes(state, self.clock.monotonic(), {})
        return state

    def _power_back(self, joints: list[str]) -> None:
        """Servos that lost power and came back: their settings written again (`_configure`),
        their goals := the positions read back (no jump), torque as `power_loss_torque` says
        when the bus is enabled (`off`: torque off on every joint and the bus no longer
        enabled, for a person to enable again)."""
        self._configure(joints)
        restore = self.is_enabled and self.config.power_loss_torque == "restore"
        if restore:
            refused = []
            for joint in joints:  # one at a time: a servo in shutdown refuses, the others go on
                try:
                    self._restore_torque([joint])
                except ServoHardwareError as err:
                    refused.append(joint)
                    log.warning("%s", err)
            torque = "torque restored" + (f" except on {', '.join(refused)} (hardware error)" if refused else "")
        else:
            self._write_servo_goals(self._goals_at_present(joints))
            torque = "torque left off"
            if self.is_enabled:
                self._set_torque(self.present_joints, False)
                self._state = Lifecycle.OPEN
                torque = "torque off on every joint (servo_bus.power_loss_torque: off): enable it again by hand"
        self.power_losses += 1
        self.last_power_loss = (f"{', '.join(self.describe(j) for j in joints)}: lost power and came back "
                                f"(RAM at its defaults): settings written again, goals := present positions, "
                                f"{torque}")
        log.warning("%s: %s", self.name, self.last_power_loss)

    def _record_episodes(self, state: BusState, now_s: float, verdicts: Mapping[str, str]) -> None:
        """Open, update and close the joints' episodes in `fault_log` from a state just read.
        A faulted joint without a verdict keeps what recovery last did (the read right after
        its reboot)."""
        for joint, joint_state in state.joints.items():
            bits = joint_state.hardware_error_bits
            if not bits:
                self._episodes.clear(joint, now_s, functools.partial(cleared_detail, self.describe, now_s))
                continue
            verdict = verdicts.get(joint)
            current = self._episodes.current(joint)
            shown = verdict or (current.recovery if current else REPORTED)
            self._episodes.seen(joint, self.config.joints[joint].servo_id, bits, joint_state.hardware_errors,
                                joint_state.torque_on, now_s, verdict,
                                self._episode_detail(joint, bits, joint_state.torque_on, shown))

    def _auto_reboot(self, joint: str, reason: str) -> None:
        """An automatic reboot, recorded in the joint's episode whether it works or not."""
        try:
            self._reboot_and_restore(joint, reason)
        except (DriverError, OSError) as err:
            self._episodes.acted(joint, REBOOT_FAILED, self.clock.monotonic(),
                                 f"{self.describe(joint)}: automatic reboot failed: {err}")
            raise
        self._episodes.acted(joint, REBOOTED, self.clock.monotonic(),
                             f"{self.describe(joint)}: rebooted ({reason})"
                             + (", torque restored at the position read back" if self.is_enabled else ""))

    def _episode_detail(self, joint: str, bits: int, torque_on: bool, recovery: str) -> str:
        meanings = "; ".join(self.decode_hardware_error(bits))
        return (f"{self.describe(joint)}: hardware error 0x{bits:02x} ({meanings}), "
                f"{'torque on' if torque_on else 'torque off'}: {self.recovery.explain(recovery)}")

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
        self._write_servo_goals(self._goals_at_present(joints))
        self._set_torque(joints, True)

    def _goals_at_present(self, joints: Iterable[str]) -> dict[str, float]:
        """Goals (servo frame) where the joints are, within their limits: a joint resting on a
        limit reads a tick beyond it now and then (the reading wobbles)."""
        present, config = self._read_servos(), self.config.joints
        return {j: config[j].servo_angle(min(max(config[j].joint_angle(present[j].position), config[j].min_angle),
                                             config[j].max_angle)) for j in joints}

    def _check_joint(self, joint: str) -> None:
        if joint not in self.config.joints:
            raise ServoConfigError(f"{self.name}: no joint {joint!r}; expected one of {', '.join(JOINTS)}")

    def _hardware_error(self, joint: str, bits: int, what: str) -> ServoHardwareError:
        meanings = "; ".join(self.decode_hardware_error(bits))
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
        """Open the transport (the servos are pinged one by one after it: `_probe_servo`)."""

    def _probe_servo(self, joint: str) -> None:
        """Check that `joint`'s servo answers (else `ServoCommError`: it is recorded missing)
        and is of the configured model (else `ServoModelError`: the open fails)."""

    def _joints_changed(self) -> None:
        """`present_joints` changed (open, reopen, a servo missing or back) and are
        configured: build the group transactions over them."""

    def _disconnect(self) -> None:
        """Release the transport. Must tolerate a partial connect and a dead port."""

    def _configure(self, joints: Iterable[str]) -> None:
        """(Re)apply per-servo settings (profiles, limits, ...), leaving torque as it was."""

    @abc.abstractmethod
    def _read_servos(self) -> dict[str, JointState]:
        """The present joints' states in the servo frame, in one transaction; a failure
        blaming some servos names their joints in the error's `joints`."""

    @abc.abstractmethod
    def _write_servo_goals(self, goals_deg: Mapping[str, float]) -> None:
        """Send goal positions (servo frame) in one transaction; no reply expected."""

    @abc.abstractmethod
    def _set_torque(self, joints: Iterable[str], on: bool) -> None:
        """Torque on or off for the given joints."""

    @abc.abstractmethod
    def _reboot_servo(self, joint: str) -> None:
        """Reboot one servo and return once it answers again."""


def create_servo_bus(config: ServoBusConfig, *, clock: Clock = SYSTEM_CLOCK, **resources: Any) -> ServoBus:
    """Construct (not open) the backend `config.backend` names.

    `resources` are what a backend needs beyond its config and cannot read from YAML (the
    simulated head's starting pose); a backend not taking them refuses them."""
    cls = backends.backend_class("servo_bus", config.backend, config)
    if not (isinstance(cls, type) and issubclass(cls, ServoBus)):
        raise ServoConfigError(f"{config.key_path}.backend: {config.backend!r} is not a ServoBus backend")
    return cls(config, clock=clock, **resources)
