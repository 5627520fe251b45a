"""The simulated servo bus: four servos with a motion model and no serial port at all.

`SimulatedServoBus` is a first-class `ServoBus` backend on the motion model of
`drivers.sim.servo_motion`. The simulated head and the daemon use it; its fault-injection hooks
(`inject_bus_down`, `restore_bus`, `inject_hardware_error`, `remove_servo`, `add_servo`, and a
brown-out: `inject_power_loss`, `restore_power`) let their tests exercise the recovery paths of
`drivers.servo.bus` without hardware.

Which servo turns which joint, which way and from where (`servo_bus.wiring`, else as
`joints` says) belongs to the simulated world: the bus drives each joint's servo by the id
its config gives, and `SimulatedServoProbe` offers the same servos by id to `headctl setup`,
which has to find the wiring out from the cameras.

Time comes from an injectable clock, so tests run faster than real time with a
`drivers.clock.ManualClock`. The simulated servos are the physical head: they persist
across `open()`/`close()` like real servos do.

What real servos add to the motion (play, dead band, the tilt's droop, the encoder's
resolution and wobble, the adapter's latency timer) is `servo_bus.mechanics`
(`drivers.sim.servo_mechanics`; the default preset, `ideal`, adds none): the servos report what
their encoders read, the simulated world's truth (`true_position`, `true_joints_at`) is where
the joints really are.

Where the joints were at a past time (a simulated frame's exposure, rendered later): the bus
records its servos' motion in a `JointTrace`, and `true_joints_at` replays it.
"""
from __future__ import annotations

import logging
import math
import threading
from collections.abc import Iterable, Mapping

import numpy as np

from drivers.clock import SYSTEM_CLOCK, Clock
from drivers.errors import BusDownError, JointLimitError, ServoConfigError, ServoHardwareError, ServoTimeoutError, blaming
from drivers.dynamixel.tables import x_series
from drivers.servo.bus import JointState, ServoBus
from drivers.servo.config import ServoBusConfig, WiredServo
from drivers.servo.joints import JOINTS
from drivers.servo.probe import FoundServo, MotionSafety, ServoStatus
from drivers.sim.servo_mechanics import ServoMechanics
from drivers.sim.servo_motion import AxisState, GearedAxis, JointTrace, ProfileAxis

log = logging.getLogger(__name__)

# Hardware Error Status bits that cut torque under the X-series default Shutdown (63) = 52:
# overheating, electrical shock, overload.
DEFAULT_SHUTDOWN_BITS = 0b0011_0100


class _SimServo:
    """One simulated servo, in the servo frame (degrees from its centre)."""

    def __init__(self, axis: GearedAxis) -> None:
        self.axis = axis
        self.goal_deg = axis.position  # the Goal Position register, kept while torque is off
        self.torque_on = False
        self.hardware_error_bits = 0
        self.temperature_c = 35.0
        self.input_voltage_v = 12.0
        self.ram_defaults = False  # booted since the bus last configured it (a power loss, a reboot)


def wiring_of(config: ServoBusConfig) -> dict[int, WiredServo]:
    """The simulated head's true wiring: `servo_bus.wiring`, else each joint's servo
    mounted as `joints` says."""
    if config.wiring is not None:
        return dict(config.wiring)
    return {jc.servo_id: WiredServo(joint, jc.direction, jc.zero_offset) for joint, jc in config.joints.items()}


def mechanics_of(config: ServoBusConfig) -> ServoMechanics:
    """The simulated servos' mechanics as `servo_bus.mechanics` says, on the config's wire."""
    return ServoMechanics(config.mechanics, baud=config.baud, latency_timer_ms=config.latency_timer_ms,
                          return_delay_us=config.return_delay_us)


def physical_servos(wiring: Mapping[int, WiredServo], initial_positions: Mapping[str, float] | None,
                    now: float, mechanics: ServoMechanics,
                    initial_axes: Mapping[str, AxisState] | None = None) -> dict[int, _SimServo]:
    """The servos by id, at rest. Each is in its joint's state of `initial_axes` (joint frame,
    as `SimulatedServoBus.true_axis` gives it: the servos of a dead servo process's bus); else
    held where its joint's `initial_positions` (joint frame) puts its controller, the output at
    the shaft (`ServoMechanics.axis`); else at its centre, like a fresh servo (and the emulator).
    The tilt's servo carries the head's weight."""
    positions, axes = dict(initial_positions or {}), dict(initial_axes or {})

    def start(wired: WiredServo) -> AxisState | float:
        if wired.joint in axes:
            return axes[wired.joint].mapped(wired.servo_angle)
        return wired.servo_angle(positions[wired.joint]) if wired.joint in positions else 0.0

    return {servo_id: _SimServo(mechanics.axis(start(wired), now, loaded=wired.joint == "tilt",
                                               joint_angle=wired.joint_angle, direction=wired.direction))
            for servo_id, wired in wiring.items()}


class SimulatedServoBus(ServoBus):
    """A `ServoBus` over simulated servos; see the module docstring.

    `initial_positions` (joint frame, degrees; default: each servo at its centre) is where
    the servos' controllers hold when the simulation starts, each output at its shaft (the tilt's
    drooping from it); `initial_axes` (`true_axis` of another bus) puts a joint's servo in that
    state instead, the play's as well. `max_velocity_dps` is the speed a profile velocity of 0
    ("as fast as possible") stands for.
    """

    capabilities = frozenset({"reboot", "hardware_error", "temperature", "input_voltage", "watchdog",
                              "fault_injection"})
    reports_true_motion = True
    # No servo models and no retries; the wire's settings time the bus with `mechanics.bus_timing`.
    CONFIG_KEYS = frozenset({"watchdog_ms", "wiring", "mechanics", "baud", "latency_timer_ms", "return_delay_us"})
    JOINT_CONFIG_KEYS = frozenset({"profile_velocity", "profile_acceleration"})

    @classmethod
    def decode_hardware_error(cls, bits: int) -> tuple[str, ...]:
        """The simulated servos report hardware errors as X-series servos do."""
        return x_series.decode_hardware_error(bits)

    def __init__(self, config: ServoBusConfig, *, clock: Clock = SYSTEM_CLOCK, name: str | None = None,
                 initial_positions: Mapping[str, float] | None = None,
                 initial_axes: Mapping[str, AxisState] | None = None, max_velocity_dps: float = 330.0) -> None:
        super().__init__(config, clock=clock, name=name or f"sim-servo-bus({config.port})")
        self.max_velocity_dps = max_velocity_dps
        now = clock.monotonic()
        self._wiring = wiring_of(config)
        self._mechanics = mechanics_of(config)
        by_id = physical_servos(self._wiring, initial_positions, now, self._mechanics, initial_axes)
        for joint in JOINTS:
            if config.joints[joint].servo_id not in by_id:
                raise ServoConfigError(key_path=f"{config.joint_path(joint)}.id", value=config.joints[joint].servo_id,
                                       expected=f"an id on the simulated bus ({', '.join(map(str, sorted(by_id)))})")
        # Each configured joint drives the servo of its id, whichever joint that servo turns.
        self._servos = {joint: by_id[config.joints[joint].servo_id] for joint in JOINTS}
        self._by_id = by_id
        self._unpowered = False  # a brown-out: every servo silent until `restore_power()`
        self._wired = {wired.joint: by_id[servo_id] for servo_id, wired in self._wiring.items()}
        self._wired_as = {wired.joint: wired for wired in self._wiring.values()}
        # Guards the simulated hardware: fault hooks are called from test or daemon threads.
        self._sim_lock = threading.Lock()
        self._linked = False
        self._adapter_present = True
        # Joints whose servo is off the bus (it answers nothing): `wiring.<id>.off_bus` at start.
        self._absent = {joint for joint in JOINTS if self._wiring[config.joints[joint].servo_id].off_bus}
        self._last_contact_s = now
        self._trace = JointTrace()
        self._sample(now, change=True)

    # -- fault injection -----------------------------------------------------------------
    def inject_bus_down(self) -> None:
        """The adapter vanishes: every bus call fails with `BusDownError` until `restore_bus()`."""
        with self._sim_lock:
            self._adapter_present = False
            self._linked = False
        log.info("%s: injected fault: adapter unplugged", self.name)

    def restore_bus(self) -> None:
        """The adapter is back; the bus reopens on its next back-off attempt."""
        with self._sim_lock:
            self._adapter_present = True
        log.info("%s: injected fault cleared: adapter back", self.name)

    def remove_servo(self, joint: str) -> None:
        """`joint`'s servo leaves the bus (its cable unplugged, its power gone; called before
        `open()`, missing at start): it stops where it is and every transaction that needs
        its reply fails with `ServoTimeoutError` naming it, until `add_servo(joint)`."""
        with self._sim_lock:
            now = self.clock.monotonic()
            servo = self._servos[joint]
            servo.axis.advance_to(now)
            servo.torque_on = False
            servo.axis.hold()
            self._absent.add(joint)
            self._sample(now, change=True)
        log.info("%s: injected fault: %s off the bus", self.name, self.describe(joint))

    def add_servo(self, joint: str) -> None:
        """`joint`'s servo is back, just powered up: RAM defaults (torque off, goal at the
        present position, no hardware error)."""
        with self._sim_lock:
            now = self.clock.monotonic()
            servo = self._servos[joint]
            servo.axis.advance_to(now)
            servo.goal_deg = servo.axis.position
            servo.hardware_error_bits = 0
            self._absent.discard(joint)
        log.info("%s: injected fault cleared: %s back on the bus", self.name, self.describe(joint))

    def _require_present(self, joints: Iterable[str]) -> None:
        """As a servo that does not answer: the first absent one of `joints` times out."""
        for joint in joints:
            if joint in self._absent:
                err = ServoTimeoutError(f"{self.describe(joint)}: no reply (the simulated servo is off the bus)")
                raise blaming(err, joint)

    def inject_power_loss(self) -> None:
        """Every servo loses power (a brown-out): torque off where it is, and no answer to any
        packet (reads time out) until `restore_power()`."""
        with self._sim_lock:
            now = self.clock.monotonic()
            for servo in self._by_id.values():
                servo.axis.advance_to(now)
                servo.axis.hold()
                servo.torque_on = False
            self._unpowered = True
            self._sample(now, change=True)
        log.info("%s: injected fault: the servos lost power", self.name)

    def restore_power(self, bits: int = 0) -> None:
        """Power is back: every servo boots with its RAM defaults (torque off, Goal Position :=
        present, profiles unlimited) and Hardware Error Status `bits` (0x01: the input voltage
        error a brown-out may leave)."""
        with self._sim_lock:
            now = self.clock.monotonic()
            for servo in self._by_id.values():
                servo.axis.advance_to(now)
                servo.axis.hold()
                servo.goal_deg = servo.axis.position
                servo.axis.max_velocity = self.max_velocity_dps
                servo.axis.max_acceleration = math.inf
                servo.hardware_error_bits = bits
                servo.ram_defaults = True
            self._unpowered = False
            self._sample(now, change=True)
        log.info("%s: injected fault cleared: the servos have power again (hardware error 0x%02x)", self.name, bits)

    def inject_hardware_error(self, joint: str, bits: int) -> None:
        """Raise Hardware Error Status `bits` on `joint`; shutdown bits cut its torque."""
        with self._sim_lock:
            now = self.clock.monotonic()
            servo = self._servos[joint]
            servo.axis.advance_to(now)
            servo.hardware_error_bits |= bits
            if bits & DEFAULT_SHUTDOWN_BITS:
                servo.torque_on = False
                servo.axis.hold()
                self._sample(now, change=True)
        log.info("%s: injected hardware error 0x%02x on %s (%s)", self.name, bits, joint,
                 "; ".join(self.decode_hardware_error(bits)))

    def true_position(self, joint: str) -> float:
        """Where the simulated joint really is now (joint frame, degrees), bus or no bus: as
        the servo wired to it (`servo_bus.wiring`) has it, whatever `joints` believes. The
        output, what the cameras see (`true_axis(joint).output`)."""
        return self.true_axis(joint).output

    def true_axis(self, joint: str) -> AxisState:
        """The mechanical state of the servo wired to `joint` now (joint frame): its controller's
        position and its output, from which `initial_axes` rebuilds it as it is."""
        with self._sim_lock:
            self._sample(self.clock.monotonic())
            return self._wired[joint].axis.state.mapped(self._wired_as[joint].joint_angle)

    def true_joints_at(self, time_s: float) -> dict[str, float]:
        """Where the simulated joints really were at `time_s` (joint frame, degrees; at most
        now): from the motion model when no servo has moved on past it, else replayed from the
        trace of their motion (`JointTrace`)."""
        with self._sim_lock:
            time_s = min(time_s, self.clock.monotonic())
            if all(servo.axis.time_s <= time_s for servo in self._wired.values()):
                return self._sample(time_s)
            joints = self._trace.at(time_s)
            assert joints is not None  # sampled since construction
            return joints

    def true_trace(self) -> np.ndarray:
        """A copy of the trace's rows (`JointTrace.rows`), for a reader in another process."""
        with self._sim_lock:
            return self._trace.rows.copy()

    def _sample(self, time_s: float, change: bool = False) -> dict[str, float]:
        """Move every servo forward to `time_s` and record their motion in the trace, a `change`
        of course (goals, torque, a hold) always (lock held); the joints' positions."""
        axes = {}
        for joint, servo in self._wired.items():
            servo.axis.advance_to(time_s)
            if joint not in JOINTS:  # a servo that turns nothing the cameras see
                continue
            wired, axis = self._wired_as[joint], servo.axis
            axes[joint] = (wired.joint_angle(axis.position), wired.direction * axis.velocity,
                           wired.joint_angle(axis.goal), axis.max_velocity, axis.max_acceleration,
                           wired.joint_angle(axis.output), axis.backlash,
                           self._mechanics.values.sag_deg_at_horizontal if axis.load is not None else 0.0)
        self._trace.add(time_s, axes, change)
        return {joint: values[5] for joint, values in axes.items()}

    # -- ServoBus hooks ------------------------------------------------------------------
    def _connect(self) -> None:
        with self._sim_lock:
            if not self._adapter_present:
                raise BusDownError(f"{self.name}: simulated adapter is unplugged")
            self._linked = True
            self._last_contact_s = self.clock.monotonic()

    def _probe_servo(self, joint: str) -> None:
        with self._sim_lock:
            self._contact()
            self._require_present([joint])

    def _disconnect(self) -> None:
        with self._sim_lock:
            self._linked = False

    def _configure(self, joints: Iterable[str]) -> None:
        with self._sim_lock:
            now = self._contact()
            joints = list(joints)
            self._require_present(joints)
            for joint in joints:
                jc = self.config.joints[joint]
                servo = self._servos[joint]
                servo.axis.advance_to(now)
                servo.axis.max_velocity = jc.profile_velocity or self.max_velocity_dps
                servo.axis.max_acceleration = jc.profile_acceleration or math.inf
                servo.ram_defaults = False
            self._sample(now, change=True)

    def _read_servos(self) -> dict[str, JointState]:
        with self._sim_lock:
            now = self._contact()
            self._require_present(self.present_joints)
            self._sample(now)
            states = {}
            for joint in self.present_joints:
                servo = self._servos[joint]
                servo.axis.advance_to(now)
                states[joint] = JointState(
                    position=self._mechanics.reading(servo.axis.shaft), velocity=servo.axis.velocity,
                    moving=servo.axis.moving, torque_on=servo.torque_on, hardware_error_bits=servo.hardware_error_bits,
                    temperature_c=servo.temperature_c, input_voltage_v=servo.input_voltage_v,
                    power_cycled=servo.ram_defaults,
                )
        self._wire_time(self._mechanics.read_cost_s(len(states)))
        return states

    def _wire_time(self, cost_s: float) -> None:
        """The time a transaction keeps its caller (`mechanics.bus_timing`), on the bus's clock,
        outside the simulation's lock (the servos move on meanwhile)."""
        if cost_s:
            self.clock.sleep(cost_s)

    def _write_servo_goals(self, goals_deg: Mapping[str, float]) -> None:
        with self._sim_lock:
            now = self._contact()
            for joint, goal in goals_deg.items():
                if joint in self._absent:  # a write expects no reply: it is lost, as on a real bus
                    continue
                servo = self._servos[joint]
                servo.axis.advance_to(now)
                servo.goal_deg = goal
                if servo.torque_on:
                    self._mechanics.command(servo.axis, goal)
            self._sample(now, change=True)  # the motion turns toward the new goals here
        self._wire_time(self._mechanics.write_cost_s(len(goals_deg)))

    def _set_torque(self, joints: Iterable[str], on: bool) -> None:
        with self._sim_lock:
            now = self._contact()
            joints = list(joints)
            self._require_present(joints)
            try:
                for joint in joints:
                    servo = self._servos[joint]
                    servo.axis.advance_to(now)
                    if on and servo.hardware_error_bits & DEFAULT_SHUTDOWN_BITS:
                        raise ServoHardwareError(
                            f"{self.describe(joint)}: torque refused, hardware error "
                            f"0x{servo.hardware_error_bits:02x}: " + "; ".join(self.decode_hardware_error(
                                servo.hardware_error_bits)))
                    servo.torque_on = on
                    if on:
                        # Like a real servo: torque on drives toward the Goal Position register.
                        self._mechanics.command(servo.axis, servo.goal_deg)
                    else:
                        servo.axis.hold()
            finally:
                self._sample(now, change=True)

    def _reboot_servo(self, joint: str) -> None:
        with self._sim_lock:
            now = self._contact()
            self._require_present([joint])
            servo = self._servos[joint]
            servo.axis.advance_to(now)
            servo.axis.hold()
            servo.goal_deg = servo.axis.position
            servo.torque_on = False
            servo.hardware_error_bits = 0
            servo.axis.max_velocity = self.max_velocity_dps  # RAM defaults, until configured
            servo.axis.max_acceleration = math.inf
            servo.ram_defaults = True
            self._sample(now, change=True)

    def _contact(self) -> float:
        """One packet on the bus: check the link, apply the Bus Watchdog, return now."""
        if not self._linked:
            raise BusDownError(f"{self.name}: simulated adapter is unplugged")
        if self._unpowered:
            raise ServoTimeoutError(f"{self.name}: no servo answered (the servos have no power)")
        now = self.clock.monotonic()
        watchdog_s = self.config.watchdog_ms / 1000.0
        if watchdog_s and now - self._last_contact_s > watchdog_s:
            # The host fell silent longer than the watchdog: each torqued servo stopped
            # where it was at that moment. The driver re-arms the watchdog as soon as it
            # speaks again (as the Dynamixel backend does), so the trip ends here.
            trip_s = self._last_contact_s + watchdog_s
            for joint, servo in self._servos.items():
                if servo.torque_on and servo.axis.moving:
                    servo.axis.advance_to(trip_s)
                    servo.axis.hold()
                    servo.goal_deg = servo.axis.position
                    log.warning("%s: bus watchdog expired on %s after %.3f s of silence: servo stopped",
                                self.name, joint, now - self._last_contact_s)
                    self._sample(trip_s, change=True)
        self._last_contact_s = now
        return now


class SimulatedServoProbe:
    """The simulated head's servos by id (`drivers.servo.probe.ServoProbe`), for `headctl
    setup`: the ids of `servo_bus.wiring` (else of `joints`), each answering a scan as an
    XM430-W350 at the config's baud rate. Which joint a servo turns is the simulated
    world's: `true_position(joint)` is for the simulated cameras, never for the assistant.

    Velocity and acceleration limits shape the motion as on the bus; the torque limit is
    recorded (the simulation has no load to limit); the watchdog stops a servo whose host
    fell silent, as the bus's does.
    """

    MODEL_NUMBER = 1020  # XM430-W350
    FIRMWARE = 48
    LIMITS_DEG = (-180.0, 180.0 - 360.0 / 4096)  # one turn around the centre, tick 0 to 4095

    def __init__(self, config: ServoBusConfig, *, clock: Clock = SYSTEM_CLOCK, ids: Iterable[int] | None = None,
                 initial_positions: Mapping[str, float] | None = None, max_velocity_dps: float = 330.0) -> None:
        self.config = config
        self.clock = clock
        self.name = f"sim-servo-probe({config.port})"
        self.max_velocity_dps = max_velocity_dps
        self._wiring = wiring_of(config)
        self._mechanics = mechanics_of(config)
        now = clock.monotonic()
        self._servos = physical_servos(self._wiring, initial_positions, now, self._mechanics)
        self._wanted = set(ids) if ids is not None else None
        self._lock = threading.Lock()
        self._saved: dict[int, tuple[float, float, float]] = {}  # id -> velocity, acceleration, watchdog
        self._watchdog_s: dict[int, float] = {}
        self._torque_limit: dict[int, float] = {}
        self._last_contact_s = {servo_id: now for servo_id in self._servos}
        for servo in self._servos.values():
            servo.axis.max_velocity = max_velocity_dps

    # -- the simulated world's side ------------------------------------------------------
    def true_position(self, joint: str) -> float:
        """Where the joint really is (joint frame, degrees): for the simulated cameras."""
        with self._lock:
            for servo_id, wired in self._wiring.items():
                if wired.joint == joint:
                    servo = self._servos[servo_id]
                    servo.axis.advance_to(self.clock.monotonic())
                    return wired.joint_angle(servo.axis.output)
        raise KeyError(joint)

    def torque_limit(self, servo_id: int) -> float | None:
        """The torque fraction `limit_motion` set on a servo, if any (tests look)."""
        return self._torque_limit.get(servo_id)

    # -- ServoProbe ----------------------------------------------------------------------
    def scan(self) -> list[FoundServo]:
        ids = sorted(i for i in self._servos if self._wanted is None or i in self._wanted)
        return [FoundServo(i, self.MODEL_NUMBER, "XM430-W350", self.FIRMWARE, 2.0, self.config.baud) for i in ids]

    def status(self, servo_id: int) -> ServoStatus:
        with self._lock:
            servo = self._contact(servo_id)
            return ServoStatus(position_deg=self._mechanics.reading(servo.axis.shaft), goal_deg=servo.goal_deg, moving=servo.axis.moving,
                               torque_on=servo.torque_on, hardware_error_bits=servo.hardware_error_bits,
                               temperature_c=servo.temperature_c, input_voltage_v=servo.input_voltage_v,
                               min_deg=self.LIMITS_DEG[0], max_deg=self.LIMITS_DEG[1])

    def limit_motion(self, servo_id: int, safety: MotionSafety) -> None:
        with self._lock:
            servo = self._contact(servo_id)
            if servo_id not in self._saved:
                self._saved[servo_id] = (servo.axis.max_velocity, servo.axis.max_acceleration,
                                         self._watchdog_s.get(servo_id, 0.0))
            servo.axis.max_velocity = safety.velocity_dps
            servo.axis.max_acceleration = safety.acceleration_dps2
            self._watchdog_s[servo_id] = safety.watchdog_s
            self._torque_limit[servo_id] = safety.torque_fraction

    def restore_motion(self, servo_id: int) -> None:
        with self._lock:
            servo = self._contact(servo_id)
            saved = self._saved.pop(servo_id, None)
            if saved is not None:
                servo.axis.max_velocity, servo.axis.max_acceleration, self._watchdog_s[servo_id] = saved
            self._torque_limit.pop(servo_id, None)

    def set_torque(self, servo_id: int, on: bool) -> None:
        with self._lock:
            servo = self._contact(servo_id)
            servo.torque_on = on
            if on:
                self._mechanics.command(servo.axis, servo.goal_deg)
            else:
                servo.axis.hold()

    def write_goal(self, servo_id: int, servo_deg: float) -> None:
        lo, hi = self.LIMITS_DEG
        if not (math.isfinite(servo_deg) and lo <= servo_deg <= hi):
            raise JointLimitError(f"id {servo_id} on {self.name}: goal {servo_deg:g} deg outside the servo's own "
                                  f"limits [{lo:g}, {hi:g}]; nothing sent")
        with self._lock:
            servo = self._contact(servo_id)
            servo.goal_deg = servo_deg
            if servo.torque_on:
                self._mechanics.command(servo.axis, servo_deg)

    def keep_alive(self, servo_id: int) -> None:
        with self._lock:
            self._contact(servo_id)
            self._watchdog_s[servo_id] = 0.0

    def close(self) -> None:
        """Nothing to release: the simulated servos stay as they are, like real ones."""

    def __enter__(self) -> "SimulatedServoProbe":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _contact(self, servo_id: int) -> _SimServo:
        """One packet to `servo_id`: the watchdog applied, the motion brought to now."""
        servo = self._servos.get(servo_id)
        if servo is None or (self._wanted is not None and servo_id not in self._wanted):
            raise ServoTimeoutError(f"id {servo_id} on {self.name}: no answer (no such servo)")
        now = self.clock.monotonic()
        watchdog_s = self._watchdog_s.get(servo_id, 0.0)
        if watchdog_s and servo.torque_on and now - self._last_contact_s[servo_id] > watchdog_s:
            servo.axis.advance_to(self._last_contact_s[servo_id] + watchdog_s)
            servo.axis.hold()
            servo.goal_deg = servo.axis.position
            log.warning("%s: watchdog expired on id %d after %.3f s of silence: servo stopped", self.name, servo_id,
                        now - self._last_contact_s[servo_id])
        servo.axis.advance_to(now)
        self._last_contact_s[servo_id] = now
        return servo
