"""The setup assistant: a new head's joints found by looking, not by reading a datasheet (docs/setup.md).

`assist(request, partial, person)` takes a partial config (`servo_bus` without `joints`,
and `cameras`: `read_partial`), scans the bus and lists each servo; with the person's
confirmation (none asked with `yes`) it moves each a few degrees and back, slowly, torque
and velocity limited, while both cameras stream, and reads off from the image motion which
joint it turns and which way (`headctl.setup.identify`); it proposes zeros and conservative
limits, widened by the jogs asked for, and writes the config with a comment per value
(`headctl.setup.config`). What it found and how it ended is its `SetupResult`; checking the
written config is the caller's.

The person is a `Person`: told what happens, asked before anything moves, and the one who
can stop the probing (`stopping`: an interruption leaves every servo holding where it is,
torque as it was, and `Interrupted` is raised).

The simulated head stands in for an unknown one: with `servo_bus.backend: sim` the servos
are wired as `servo_bus.wiring` says, which the assistant never reads: it sees the servos
by id (`drivers.servo.probe`) and the cameras, which render from where the servos really
are. Simulated cameras beside real (or emulated) servos see a still room: every servo is
then reported as moving nothing visible, which is what a scan of `headctl emulate-servos`
gives.
"""
from __future__ import annotations

import contextlib
import dataclasses
import enum
import logging
import threading
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, ContextManager, Protocol

import numpy as np

from drivers.cameras.camera import Camera, create_camera
from drivers.cameras.config import StereoCamerasConfig
from drivers.cameras.stereo import StereoPair
from drivers.clock import SYSTEM_CLOCK
from drivers.dynamixel.tables.x_series import decode_hardware_error
from drivers.servo.config import PartialServoBusConfig, ServoBusConfig
from drivers.servo.joints import JOINTS
from drivers.servo.probe import FoundServo, MotionSafety, ServoProbe, create_servo_probe
from drivers.sim.camera import fixed_pose
from drivers.sim.servos import SimulatedServoProbe
from headctl.config.head import check_cameras, read_yaml
from headctl.errors import ConfigError
from headctl.json_types import JSONObject
from headctl.setup.config import JointProposal, eye_zeros, jog, propose, write_config
from headctl.setup.identify import Finding, Identification, SafeProbing, identify

if TYPE_CHECKING:
    from headctl.service.build import SimCameraResources

log = logging.getLogger(__name__)


class Person(Protocol):
    """Who runs the assistant: told what happens, asked before anything moves."""

    def say(self, text: str) -> None: ...

    def confirm(self, question: str) -> bool: ...

    def stopping(self, stop: threading.Event) -> ContextManager[None]:
        """While the servos are probed: the person's way to set `stop` (Ctrl-C, say)."""


@dataclass(frozen=True)
class SetupRequest:
    """What to set up: `config` a partial config (servo_bus: backend, port; joints may be
    left out; cameras), `port` overriding its servo_bus.port, `write` where the complete
    config goes (None: proposed, nothing written); the scan's `bauds`, `protocols` and `ids`
    (None: every one); the probing move; `jogs`: (joint, degrees from the proposed zero) to
    move to and widen the limit to."""

    config: Path
    port: str | None = None
    write: Path | None = None
    yes: bool = False  # move the servos without asking
    bauds: tuple[int, ...] | None = None
    protocols: tuple[float, ...] | None = None
    ids: range | None = None
    step_deg: float = 3.0
    jogs: tuple[tuple[str, float], ...] = ()
    frame_timeout_s: float = 3.0


class SetupOutcome(enum.Enum):
    WRITTEN = "written"
    PROPOSED = "proposed, nothing written"
    NO_SERVOS = "no servos found"
    DECLINED = "nothing moved"
    JOINTS_MISSING = "not every joint found"
    UNKNOWN_JOG = "a jog names no joint"
    MIXED_BUS_SETTINGS = "servos at different baud rates or protocols"


@dataclass(frozen=True)
class SetupResult:
    outcome: SetupOutcome
    found: tuple[FoundServo, ...] = ()
    identification: Identification | None = None
    proposals: Mapping[str, JointProposal] = field(default_factory=dict)
    written: Path | None = None
    detail: str = ""  # UNKNOWN_JOG: what to tell


@dataclass(frozen=True)
class PartialConfig:
    """The partial config as read: the YAML document and its servo bus and cameras."""

    document: JSONObject
    bus: ServoBusConfig
    cameras: StereoCamerasConfig


class CameraPairs:
    """Pairs from two streaming cameras, as `headctl.setup.identify.PairSource`."""

    def __init__(self, stereo: StereoPair) -> None:
        self.stereo = stereo

    def wait_pair(self, after_s: float, timeout_s: float) -> tuple[np.ndarray, np.ndarray]:
        frames = self.stereo.wait_pair(after_s, timeout_s)
        return frames.left.image, frames.right.image


def read_partial(path: Path, port: str | None = None) -> PartialConfig:
    """The partial config in `path`; ConfigError (naming the file) if it does not read."""
    try:
        document = read_yaml(path)
        if not isinstance(document, dict):
            raise ConfigError(key_path="", value=document, expected="a mapping with servo_bus and cameras")
        bus: ServoBusConfig = PartialServoBusConfig.from_mapping(document.get("servo_bus"), "servo_bus")
        if port:
            bus = dataclasses.replace(bus, port=port)
        cameras = StereoCamerasConfig.from_mapping(document.get("cameras"), "cameras")
        check_cameras(cameras)
    except ConfigError as err:
        if err.file is None:
            err.file = path
        raise
    return PartialConfig(document, bus, cameras)


def build_cameras(cameras: StereoCamerasConfig, probe: ServoProbe) -> dict[str, Camera]:
    """Both cameras; simulated ones render from the simulated servos' true positions, or a
    still room beside any other servos."""
    from headctl.service.build import SIM_START_JOINTS, sim_head_model

    built: dict[str, Camera] = {}
    for side in ("left", "right"):
        config = getattr(cameras, side)
        resources: SimCameraResources = {}
        if config.backend == "sim":
            pose: Callable[[], Mapping[str, float]]
            if isinstance(probe, SimulatedServoProbe):
                sim = probe

                def pose() -> Mapping[str, float]:
                    return {joint: sim.true_position(joint) for joint in JOINTS}
            else:  # emulated or real servos: nothing in the simulated room moves
                pose = fixed_pose(**SIM_START_JOINTS)
            resources = {"head": sim_head_model(config), "pose_source": pose}
        built[side] = create_camera(config, name=side, key_path=f"cameras.{side}", **resources)
    return built


def scan_lines(probe: ServoProbe, found: list[FoundServo]) -> list[str]:
    """The scan as a table: one line a servo, under a header."""
    lines = [f"{'id':>3}  {'model':<11} {'fw':>3}  {'protocol':>8} {'baud':>8}  {'position':>9}  {'temp':>5}  "
             f"{'voltage':>7}  hardware error"]
    for s in found:
        st = probe.status(s.servo_id)
        errors = ", ".join(decode_hardware_error(st.hardware_error_bits)) or "none"
        lines.append(f"{s.servo_id:>3}  {s.model_name:<11} {s.firmware:>3}  {s.protocol:>8.1f} {s.baud:>8}  "
                     f"{st.position_deg:>+8.1f}°  {st.temperature_c:>4.0f}C  {st.input_voltage_v:>6.1f}V  {errors}")
    return lines


def finding_lines(result: Identification) -> list[str]:
    """What each servo was found to turn, one line a servo."""
    lines = []
    for f in result.findings:
        if f.outcome is Finding.IDENTIFIED:
            lines.append(f"  id {f.servo.servo_id}: {f.joint}, direction {f.direction:+d} ({f.detail})")
        else:
            lines.append(f"  id {f.servo.servo_id}: NOT ATTRIBUTED: {f.outcome.value} ({f.detail})")
    return lines


def assist(request: SetupRequest, partial: PartialConfig, person: Person) -> SetupResult:
    """Scan, probe, propose and (with `request.write`) write; see the module docstring.
    `partial`: `request.config` as read (`read_partial`).

    Raises `Interrupted` when the person stops the probing, and DriverError, HeadctlError or
    OSError as the devices fail."""
    bus = partial.bus
    resources: dict[str, object] = {}
    if bus.backend == "sim":
        from headctl.service.build import SIM_START_JOINTS
        resources["initial_positions"] = SIM_START_JOINTS
    elif bus.backend == "dynamixel":
        resources["bauds"] = list(request.bauds) if request.bauds is not None else None
        resources["protocols"] = list(request.protocols) if request.protocols is not None else None
    stop = threading.Event()
    with contextlib.ExitStack() as stack:
        probe = stack.enter_context(create_servo_probe(bus, clock=SYSTEM_CLOCK, ids=request.ids, **resources))
        person.say(f"scanning {bus.port} ({bus.backend}) ...")
        found = probe.scan()
        if not found:
            person.say(f"no servos found on {bus.port}; check power, wiring and the baud rate")
            return SetupResult(SetupOutcome.NO_SERVOS)
        person.say(f"{len(found)} servo(s) found:")
        for line in scan_lines(probe, found):
            person.say(line)
        if not request.yes and not person.confirm(
                f"Move each servo by {request.step_deg:g} deg and back, one at a time, slowly and torque "
                "limited? Keep clear of the head. [y/N] "):
            person.say("nothing moved")
            return SetupResult(SetupOutcome.DECLINED, tuple(found))
        built = build_cameras(partial.cameras, probe)
        for camera in built.values():
            stack.enter_context(camera)
            camera.enable()
        stereo = stack.enter_context(StereoPair(built["left"], built["right"], partial.cameras.tolerance_s))
        stack.enter_context(person.stopping(stop))
        probing = stack.enter_context(SafeProbing(probe, SYSTEM_CLOCK, MotionSafety(), stop))
        return _probe_and_propose(request, partial, probing, CameraPairs(stereo), found, person)


def _probe_and_propose(request: SetupRequest, partial: PartialConfig, probing: SafeProbing, pairs: CameraPairs,
                       found: list[FoundServo], person: Person) -> SetupResult:
    person.say("probing each servo (the cameras watch):")
    started = time.monotonic()
    result = identify(probing, pairs, found, step_deg=request.step_deg, frame_timeout_s=request.frame_timeout_s,
                      say=person.say)
    for line in finding_lines(result):
        person.say(line)
    missing = result.missing(JOINTS)
    if missing:
        person.say(f"not every joint found ({', '.join(missing)} missing): nothing written. Check that each servo "
                   "turns something the cameras see, and that the cameras face a textured scene.")
        return SetupResult(SetupOutcome.JOINTS_MISSING, tuple(found), result)
    joints = result.joints
    eyes = eye_zeros(probing, pairs, joints["left_eye"], joints["right_eye"], frame_timeout_s=request.frame_timeout_s,
                     say=person.say)
    proposals = propose(joints, eyes)
    for joint, deg in request.jogs:
        if joint not in proposals:
            return SetupResult(SetupOutcome.UNKNOWN_JOG, tuple(found), result, proposals,
                               detail=f"--jog {joint}: expected one of {', '.join(JOINTS)}")
        jog(probing, proposals[joint], deg, say=person.say)
    person.say(f"proposed joints ({time.monotonic() - started:.1f} s of probing):")
    for joint, p in proposals.items():
        person.say(f"  {joint:<9} id {p.servo_id:>3}  direction {p.direction:+d}  zero_offset {p.zero_offset:+7.2f}  "
                   f"limits [{p.min_angle:+.1f}, {p.max_angle:+.1f}]")
    if request.write is None:
        person.say("(no --write: nothing written)")
        return SetupResult(SetupOutcome.PROPOSED, tuple(found), result, proposals)
    bauds = {f.servo.baud for f in joints.values()}
    protocols = {f.servo.protocol for f in joints.values()}
    if len(bauds) > 1 or len(protocols) > 1:
        person.say(f"the four servos answer at different baud rates or protocols ({sorted(bauds)}, "
                   f"{sorted(protocols)}): set them alike (DYNAMIXEL Wizard) and run setup again; nothing written")
        return SetupResult(SetupOutcome.MIXED_BUS_SETTINGS, tuple(found), result, proposals)
    bus = partial.bus
    settings: dict[str, str | int | float] = {"backend": bus.backend, "port": bus.port}
    if bus.backend == "dynamixel":
        settings |= {"baud": bauds.pop(), "protocol": protocols.pop()}
    write_config(partial.document, request.config, settings, proposals, request.write)
    return SetupResult(SetupOutcome.WRITTEN, tuple(found), result, proposals, request.write)


__all__ = ["CameraPairs", "PartialConfig", "Person", "SetupOutcome", "SetupRequest", "SetupResult", "assist",
           "build_cameras", "finding_lines", "read_partial", "scan_lines"]
