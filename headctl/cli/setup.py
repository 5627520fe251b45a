"""`headctl setup`: set a new head up by looking, not by reading a datasheet (docs/setup.md).

From a partial config (`servo_bus` without `joints`, and `cameras`): scan the bus and list
each servo; with the person's confirmation (`--yes` for none) move each a few degrees and
back, slowly, torque and velocity limited, while both cameras stream, and read off from the
image motion which joint it turns and which way (`headctl.setup.identify`); propose zeros
and conservative limits, widened by `--jog JOINT DEG` (`headctl.setup.config`); write the
config with a comment per value and run `headctl check` on it.

Ctrl-C at any moment leaves every servo holding where it is, torque as it was, and exits 130.

The simulated head stands in for an unknown one: with `servo_bus.backend: sim` the servos
are wired as `servo_bus.wiring` says, which the assistant never reads: it sees the servos
by id (`drivers.servo.probe`) and the cameras, which render from where the servos really
are. Simulated cameras beside real (or emulated) servos see a still room: every servo is
then reported as moving nothing visible, which is what a scan of `headctl emulate-servos`
gives.
"""
from __future__ import annotations

import argparse
import contextlib
import dataclasses
import signal
import sys
import threading
import time
from collections.abc import Callable, Iterator, Mapping
from pathlib import Path
from typing import Any

import numpy as np

from drivers.cameras.camera import Camera, create_camera
from drivers.cameras.config import StereoCamerasConfig
from drivers.clock import SYSTEM_CLOCK
from drivers.errors import DriverError
from drivers.dynamixel.tables.x_series import decode_hardware_error
from drivers.servo.config import PartialServoBusConfig, ServoBusConfig
from drivers.servo.joints import JOINTS
from drivers.servo.probe import FoundServo, MotionSafety, ServoProbe, create_servo_probe
from drivers.sim.camera import fixed_pose
from drivers.sim.servos import SimulatedServoProbe
from drivers.cameras.stereo import StereoPair
from headctl.config.head import check_cameras, read_yaml
from headctl.errors import ConfigError, HeadctlError
from headctl.setup.config import eye_zeros, jog, propose, write_config
from headctl.setup.identify import Finding, Identification, Interrupted, SafeProbing, identify


def register(sub: argparse._SubParsersAction) -> None:
    """Add `setup` to `sub`."""
    setup = sub.add_parser(
        "setup", help="set a new head up: find each servo's joint, direction, zero and limits from the images",
        description="Scan the bus, move each servo a few degrees and back (slowly, torque limited) while both "
                    "cameras stream, name its joint and direction from the image motion, propose zeros and "
                    "limits, write the config with a comment per value and check it. Ctrl-C leaves every servo "
                    "holding where it is. Walk-through: docs/setup.md.")
    setup.add_argument("--config", required=True, metavar="FILE",
                       help="a partial config: servo_bus (backend, port; joints may be left out) and cameras")
    setup.add_argument("--port", help="override servo_bus.port (e.g. /dev/head-servos)")
    setup.add_argument("--write", metavar="OUT", help="write the complete config here and run headctl check on it")
    setup.add_argument("--yes", action="store_true", help="move the servos without asking")
    setup.add_argument("--baud", type=lambda t: [int(b) for b in t.split(",")], metavar="B[,B...]",
                       help="scan only these baud rates (default: every one)")
    setup.add_argument("--protocol", choices=["1.0", "2.0"], action="append",
                       help="scan only this protocol (may be given twice; default both)")
    setup.add_argument("--ids", type=lambda t: range(int(t.split("-")[0]), int(t.split("-")[-1]) + 1),
                       metavar="LO-HI", help="ids a Protocol 1.0 scan pings (default 0-252)")
    setup.add_argument("--step", type=float, default=3.0, metavar="DEG", help="probing move (default 3 deg)")
    setup.add_argument("--jog", nargs=2, action="append", default=[], metavar=("JOINT", "DEG"),
                       help="move JOINT to DEG (joint frame, from the proposed zero) and widen its limit to it; "
                            "may be repeated")
    setup.add_argument("--frame-timeout", type=float, default=3.0, metavar="S", help="seconds to wait for a pair")
    setup.set_defaults(func=_setup)


def _say(text: str) -> None:
    print(text, flush=True)


class _CameraPairs:
    """Pairs from two streaming cameras, as `setup_identify.PairSource`."""

    def __init__(self, stereo: StereoPair) -> None:
        self.stereo = stereo

    def wait_pair(self, after_s: float, timeout_s: float) -> tuple[np.ndarray, np.ndarray]:
        frames = self.stereo.wait_pair(after_s, timeout_s)
        return frames.left.image, frames.right.image


@contextlib.contextmanager
def _sigint_sets(event: threading.Event) -> Iterator[None]:
    """Ctrl-C sets `event` (the probing stops at its next check, servos held); a second one
    interrupts at once."""
    def handler(signum: int, frame: Any) -> None:
        if event.is_set():
            raise KeyboardInterrupt
        event.set()

    previous = signal.signal(signal.SIGINT, handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


def _parse(args: argparse.Namespace) -> tuple[Any, ServoBusConfig, StereoCamerasConfig]:
    path = Path(args.config)
    try:
        document = read_yaml(path)
        if not isinstance(document, dict):
            raise ConfigError(key_path="", value=document, expected="a mapping with servo_bus and cameras")
        bus: ServoBusConfig = PartialServoBusConfig.from_mapping(document.get("servo_bus"), "servo_bus")
        if args.port:
            bus = dataclasses.replace(bus, port=args.port)
        cameras = StereoCamerasConfig.from_mapping(document.get("cameras"), "cameras")
        check_cameras(cameras)
    except ConfigError as err:
        if err.file is None:
            err.file = path
        raise
    return document, bus, cameras


def _build_cameras(cameras: StereoCamerasConfig, probe: ServoProbe) -> dict[str, Camera]:
    from headctl.service.build import SIM_START_JOINTS, sim_head_model

    built: dict[str, Camera] = {}
    for side in ("left", "right"):
        config = getattr(cameras, side)
        resources: dict[str, Any] = {}
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


def print_scan(probe: ServoProbe, found: list[FoundServo]) -> None:
    _say(f"{'id':>3}  {'model':<11} {'fw':>3}  {'protocol':>8} {'baud':>8}  {'position':>9}  {'temp':>5}  "
         f"{'voltage':>7}  hardware error")
    for s in found:
        st = probe.status(s.servo_id)
        errors = ", ".join(decode_hardware_error(st.hardware_error_bits)) or "none"
        _say(f"{s.servo_id:>3}  {s.model_name:<11} {s.firmware:>3}  {s.protocol:>8.1f} {s.baud:>8}  "
             f"{st.position_deg:>+8.1f}°  {st.temperature_c:>4.0f}C  {st.input_voltage_v:>6.1f}V  {errors}")


def print_findings(result: Identification) -> None:
    for f in result.findings:
        if f.outcome is Finding.IDENTIFIED:
            _say(f"  id {f.servo.servo_id}: {f.joint}, direction {f.direction:+d} ({f.detail})")
        else:
            _say(f"  id {f.servo.servo_id}: NOT ATTRIBUTED: {f.outcome.value} ({f.detail})")


def _setup(args: argparse.Namespace) -> int:
    try:
        document, bus, cameras = _parse(args)
    except ConfigError as err:
        print(f"headctl setup: {err}", file=sys.stderr)
        return 2
    resources: dict[str, Any] = {}
    if bus.backend == "sim":
        from headctl.service.build import SIM_START_JOINTS
        resources["initial_positions"] = SIM_START_JOINTS
    elif bus.backend == "dynamixel":
        resources["bauds"] = args.baud
        resources["protocols"] = [float(p) for p in args.protocol] if args.protocol else None
    interrupt = threading.Event()
    written: list[Path] = []
    try:
        with contextlib.ExitStack() as stack:
            probe = stack.enter_context(create_servo_probe(bus, clock=SYSTEM_CLOCK, ids=args.ids, **resources))
            _say(f"scanning {bus.port} ({bus.backend}) ...")
            found = probe.scan()
            if not found:
                _say(f"no servos found on {bus.port}; check power, wiring and the baud rate")
                return 1
            _say(f"{len(found)} servo(s) found:")
            print_scan(probe, found)
            if not args.yes:
                answer = input(f"Move each servo by {args.step:g} deg and back, one at a time, slowly and torque "
                               "limited? Keep clear of the head. [y/N] ")
                if answer.strip().lower() not in ("y", "yes"):
                    _say("nothing moved")
                    return 1
            built = _build_cameras(cameras, probe)
            for camera in built.values():
                stack.enter_context(camera)
                camera.enable()
            stereo = stack.enter_context(StereoPair(built["left"], built["right"], cameras.tolerance_s))
            stack.enter_context(_sigint_sets(interrupt))
            probing = stack.enter_context(SafeProbing(probe, SYSTEM_CLOCK, MotionSafety(), interrupt))
            status = _assist(args, document, bus, probing, _CameraPairs(stereo), found, written)
    except Interrupted:
        _say("interrupted: every servo moved was left holding where it is, torque as it was; nothing written")
        return 130
    except (DriverError, HeadctlError, OSError) as err:
        print(f"headctl setup: {err}", file=sys.stderr)
        return 1
    if status or not written:
        return status
    _say(f"wrote {written[0]}; checking it:")  # the bus is closed now, for check to open
    return _check(written[0])


def _assist(args: argparse.Namespace, document: Any, bus: ServoBusConfig, probing: SafeProbing,
            pairs: _CameraPairs, found: list[FoundServo], written: list[Path]) -> int:
    _say("probing each servo (the cameras watch):")
    started = time.monotonic()
    result = identify(probing, pairs, found, step_deg=args.step, frame_timeout_s=args.frame_timeout, say=_say)
    print_findings(result)
    missing = result.missing(JOINTS)
    if missing:
        _say(f"not every joint found ({', '.join(missing)} missing): nothing written. Check that each servo turns "
             "something the cameras see, and that the cameras face a textured scene.")
        return 1
    joints = result.joints
    eyes = eye_zeros(probing, pairs, joints["left_eye"], joints["right_eye"], frame_timeout_s=args.frame_timeout,
                     say=_say)
    proposals = propose(joints, eyes)
    for joint, deg in args.jog:
        if joint not in proposals:
            print(f"headctl setup: --jog {joint}: expected one of {', '.join(JOINTS)}", file=sys.stderr)
            return 2
        jog(probing, proposals[joint], float(deg), say=_say)
    _say(f"proposed joints ({time.monotonic() - started:.1f} s of probing):")
    for joint, p in proposals.items():
        _say(f"  {joint:<9} id {p.servo_id:>3}  direction {p.direction:+d}  zero_offset {p.zero_offset:+7.2f}  "
             f"limits [{p.min_angle:+.1f}, {p.max_angle:+.1f}]")
    if not args.write:
        _say("(no --write: nothing written)")
        return 0
    bauds = {f.servo.baud for f in joints.values()}
    protocols = {f.servo.protocol for f in joints.values()}
    if len(bauds) > 1 or len(protocols) > 1:
        _say(f"the four servos answer at different baud rates or protocols ({sorted(bauds)}, {sorted(protocols)}): "
             "set them alike (DYNAMIXEL Wizard) and run setup again; nothing written")
        return 1
    settings: dict[str, Any] = {"backend": bus.backend, "port": bus.port}
    if bus.backend == "dynamixel":
        settings |= {"baud": bauds.pop(), "protocol": protocols.pop()}
    out = Path(args.write)
    write_config(document, Path(args.config), settings, proposals, out)
    written.append(out)
    return 0


def _check(path: Path) -> int:
    from headctl.cli.main import build_parser

    check_args = build_parser().parse_args(["check", "--config", str(path)])
    status: int = check_args.func(check_args)
    return status
