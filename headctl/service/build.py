"""Building a head from its config: the servo bus, the two cameras and the `Head` over them.

Every backend, the simulated head's included, is reached through the backend table
(`drivers.backends`) by the name its config gives. What the simulated backends need beyond
their config -- a geometric head model and the servos' true positions for the cameras to
render from, the pose the servos start at -- is the simulated world (`SimulatedWorld`), made
here from the same config. `headctl run`, `headctl check` and the online experiments all
build their head with these functions.
"""
from __future__ import annotations

import contextlib
import dataclasses
import logging
from collections.abc import Callable, Mapping
from typing import Protocol, TypedDict

from drivers.servo.joints import JOINTS
from calib_free.sim.head_model import HeadModel, JointLimits
from drivers.cameras.camera import Camera, create_camera
from drivers.cameras.config import CameraConfig
from drivers.clock import SYSTEM_CLOCK, Clock
from drivers.errors import CameraError
from drivers.servo.bus import ServoBus, create_servo_bus
from drivers.sim.camera import PoseSource
from drivers.sim.room import room_scene
from drivers.sim.scene import Scene
from drivers.sim.servo_motion import AxisState
from drivers.sim.servos import SimulatedServoBus
from headctl.config.head import HeadConfig
from headctl.service.head import Head, HeadObserver, JointBus, PairSource

log = logging.getLogger(__name__)

SIDES = ("left", "right")
# The simulated head starts with the eyes slightly converged: within the vergence range that
# the room's far walls need (1 deg at 3 m with a 60 mm baseline).
SIM_START_JOINTS: Mapping[str, float] = {"pan": 0.0, "tilt": 0.0, "left_eye": 5.0, "right_eye": -5.0}
SIM_VERGENCE_RANGE = (1.0, 20.0)


class SimulatedServos(Protocol):
    """The simulated servos as the simulated world sees them: a `SimulatedServoBus`, or the
    servo process that runs one (`headctl.service.servo_io.process.ServoLoopProcess`)."""

    def true_position(self, joint: str) -> float: ...

    def true_joints_at(self, time_s: float) -> dict[str, float]: ...

    def inject_bus_down(self) -> None: ...

    def restore_bus(self) -> None: ...

    def inject_power_loss(self) -> None: ...

    def restore_power(self, bits: int = 0) -> None: ...

    def inject_hardware_error(self, joint: str, bits: int) -> None: ...

    def remove_servo(self, joint: str) -> None: ...

    def add_servo(self, joint: str) -> None: ...


class SimulatedWorld:
    """What the simulated backends share: the head model the cameras render through, the
    servos' true positions they render from, and the faults a test may inject."""

    def __init__(self, config: HeadConfig, servos: SimulatedServos, clock: Clock = SYSTEM_CLOCK) -> None:
        self.model = sim_head_model(config.cameras.left, config.fixation.vergence_range)
        self.servos = servos
        self.stalled: set[str] = set()
        # The room `cameras.scene` names, with the objects moving in it (`sim_objects`), its
        # passers-by and its light (drivers.sim.room).
        left = config.cameras.left
        self.scene: Scene | None = room_scene(config.cameras.scene, left.seed, left.image == "colour",
                                              config.sim_objects, clock)

    def true_joints(self) -> dict[str, float]:
        return {joint: self.servos.true_position(joint) for joint in JOINTS}

    def true_joints_at(self, time_s: float) -> dict[str, float]:
        """Where the joints were at `time_s` (a frame's exposure, rendered later)."""
        return self.servos.true_joints_at(time_s)

    def pose_source(self, side: str) -> EyePose:
        return EyePose(self, side)


class EyePose:
    """One simulated camera's pose source (`drivers.sim.camera.TimedPoseSource`): the world's
    joints now, or at a frame's exposure; fails while the camera is stalled."""

    def __init__(self, world: SimulatedWorld, side: str) -> None:
        self.world, self.side = world, side

    def _check(self) -> None:
        if self.side in self.world.stalled:
            raise CameraError(f"camera {self.side}: stalled (injected fault)")

    def __call__(self) -> dict[str, float]:
        self._check()
        return self.world.true_joints()

    def at(self, time_s: float) -> dict[str, float]:
        self._check()
        return self.world.true_joints_at(time_s)


def sim_head_model(camera: CameraConfig, vergence_range: tuple[float, float] | None = None) -> HeadModel:
    """The simulated head's geometry for cameras of this size and lens; its vergence range is
    the config's (default: from 1 deg, as the room's far walls need)."""
    limits = JointLimits(vergence=vergence_range or SIM_VERGENCE_RANGE)
    return HeadModel.default(int(camera.width or 320), int(camera.height or 240), lens=camera.lens, limits=limits)


def build_servo_bus(config: HeadConfig, clock: Clock = SYSTEM_CLOCK, *,
                    initial_positions: Mapping[str, float] | None = None,
                    initial_axes: Mapping[str, AxisState] | None = None) -> ServoBus:
    """The servo bus the config names (not opened); a simulated one's servos start at
    `initial_positions` (default `SIM_START_JOINTS`), or in the states `initial_axes` gives
    (`SimulatedServoBus.true_axis`: a restarted servo process's)."""
    resources: dict[str, object] = {}
    if config.simulated:
        resources["initial_positions"] = initial_positions or SIM_START_JOINTS
        if initial_axes:
            resources["initial_axes"] = initial_axes
    return create_servo_bus(config.servo_bus, clock=clock, **resources)


class SimCameraResources(TypedDict, total=False):
    """What a simulated camera takes beside its config (`drivers.sim.camera.SimulatedCamera`)."""
    head: HeadModel
    pose_source: PoseSource
    scene: Scene


def build_cameras(config: HeadConfig, world: SimulatedWorld | None, clock: Clock = SYSTEM_CLOCK,
                  ) -> dict[str, Camera]:
    """The left and right cameras the config names (not opened); simulated ones render `world`."""
    cameras: dict[str, Camera] = {}
    for side in SIDES:
        camera_config: CameraConfig = getattr(config.cameras, side)
        resources: SimCameraResources = {}
        if camera_config.backend == "sim":
            if world is None:
                raise CameraError(f"camera {side}: a simulated camera needs the simulated servo bus")
            resources = {"head": world.model, "pose_source": world.pose_source(side)}
            if world.scene is not None:
                resources["scene"] = world.scene
        cameras[side] = create_camera(camera_config, name=side, key_path=f"cameras.{side}", clock=clock,
                                      **resources)
    return cameras


@dataclasses.dataclass
class HeadDevices:
    """A head's devices, built from its config; `open()` opens the bus and the cameras (states
    readable, nothing moves), `close()` closes what was opened, in reverse order."""

    bus: ServoBus | None  # None: a servo process owns it
    cameras: dict[str, Camera]
    world: SimulatedWorld | None
    _stack: contextlib.ExitStack = dataclasses.field(default_factory=contextlib.ExitStack, repr=False)

    @classmethod
    def build(cls, config: HeadConfig, clock: Clock = SYSTEM_CLOCK) -> "HeadDevices":
        bus = build_servo_bus(config, clock)
        world = None
        if config.simulated:
            if not isinstance(bus, SimulatedServoBus):
                raise CameraError(f"{config.servo_bus.key_path}.backend: the simulated cameras need the simulated "
                                  f"servo bus, got {type(bus).__name__}")
            world = SimulatedWorld(config, bus, clock)
        return cls(bus, build_cameras(config, world, clock), world)

    @classmethod
    def cameras_of(cls, config: HeadConfig, servos: SimulatedServos | None,
                   clock: Clock = SYSTEM_CLOCK) -> "HeadDevices":
        """The cameras alone, for a service whose servo process owns the bus; simulated cameras
        render the servos that process simulates."""
        world = SimulatedWorld(config, servos, clock) if config.simulated and servos is not None else None
        return cls(None, build_cameras(config, world, clock), world)

    def open(self, cameras: bool = True) -> "HeadDevices":
        try:
            if self.bus is not None:
                self._stack.enter_context(self.bus)
            if cameras:
                for camera in self.cameras.values():
                    self._stack.enter_context(camera)
        except BaseException:
            self._stack.close()
            raise
        return self

    def close(self) -> None:
        self._stack.close()

    def __enter__(self) -> "HeadDevices":
        return self.open()

    def __exit__(self, *exc: object) -> None:
        self.close()


def build_head(config: HeadConfig, bus: JointBus, pairs: PairSource, clock: Clock = SYSTEM_CLOCK, *,
               interrupt: Callable[[], None] | None = None, observer: HeadObserver | None = None,
               goals_in_force: Callable[[], Mapping[str, float]] | None = None) -> Head:
    """The `Head` over `bus` and `pairs`, with the config's joint and vergence limits."""
    return Head(bus, pairs, config.servo_bus.joints, clock=clock, vergence_range=config.fixation.vergence_range,
                interrupt=interrupt, observer=observer, goals_in_force=goals_in_force)
