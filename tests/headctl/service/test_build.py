"""Building the head from a config (headctl.service.build) and supervising it on a manual clock."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from drivers.cameras.camera import StreamHealth
from drivers.clock import ManualClock
from drivers.errors import CameraError
from drivers.cameras.config import SceneConfig
from drivers.sim.camera import SimulatedCamera
from drivers.sim.passers_by import PassersByConfig
from drivers.sim.room_light import CONSTANT_LIGHT, LightConfig
from drivers.sim.scene import shared_scene
from drivers.sim.servos import SimulatedServoBus
from headctl.config.head import load_config
from headctl.experiments.online import SimulatedHeadRig
from headctl.service.build import SIM_START_JOINTS, HeadDevices, build_head
from headctl.service.events import EventHub, EventLog
from headctl.service.looks import LookQueue
from headctl.service.parts import LearningLog, ServiceParts
from headctl.service.status import FaultWatcher
from headctl.service.supervision.supervisor import Supervisor
from headctl.service.supervision.systemd import SystemdNotifier
from tests.support import SIM_IDEAL


def test_the_simulated_head_is_built_through_the_backend_table_and_renders_its_servos():
    config = load_config(SIM_IDEAL)
    clock = ManualClock()
    devices = HeadDevices.build(config, clock)
    assert isinstance(devices.bus, SimulatedServoBus) and devices.world is not None
    assert all(isinstance(c, SimulatedCamera) for c in devices.cameras.values())
    with devices:
        devices.bus.enable()
        assert devices.world.true_joints() == pytest.approx(SIM_START_JOINTS)
        left = devices.cameras["left"]
        before = left.render(devices.world.true_joints())
        devices.bus.write_goals({"pan": 10.0})
        clock.advance(2.0)
        assert devices.world.true_joints()["pan"] == pytest.approx(10.0)
        assert not np.array_equal(left.render(devices.world.true_joints()), before)  # the view turned
        devices.world.stalled.add("left")
        with pytest.raises(CameraError, match="camera left: stalled"):
            devices.world.pose_source("left")()
        devices.world.pose_source("right")()  # the other eye still sees


def test_a_config_with_the_photo_room_gives_the_cameras_the_photo_room(tmp_path):
    config = load_config(SIM_IDEAL)
    photos = dataclasses.replace(config, cameras=dataclasses.replace(config.cameras, scene=SceneConfig(room="photos")))
    joints = dict(SIM_START_JOINTS)
    views = {}
    for name, cfg in (("generated", config), ("photos", photos)):
        devices = HeadDevices.build(cfg, ManualClock())
        assert devices.world is not None
        with devices:
            views[name] = devices.cameras["left"].render(joints)
        left = cfg.cameras.left  # nothing moves, the light is constant: the room shared by every camera
        assert devices.world.scene is shared_scene(left.seed, left.image == "colour", name)
    assert views["generated"].shape == views["photos"].shape
    assert np.mean(np.abs(views["generated"].astype(float) - views["photos"].astype(float))) > 10  # another room


def test_the_experiments_build_the_head_the_service_builds():
    config = load_config(SIM_IDEAL)
    with SimulatedHeadRig(seed=0, config=load_config(SIM_IDEAL)) as rig:
        service_head = build_head(config, rig.bus, rig.pairs)
        np.testing.assert_array_equal(rig.head.pose_low, service_head.pose_low)
        np.testing.assert_array_equal(rig.head.pose_high, service_head.pose_high)
        assert rig.bus.config.joints == config.servo_bus.joints
        assert rig.model.limits.vergence == config.fixation.vergence_range


class StubCamera:
    """A camera whose health a test sets; counts the supervisor's restarts."""

    def __init__(self) -> None:
        self.health = StreamHealth.STREAMING
        self.last_error = None
        self.restarts = 0

    def latest(self):
        return None

    def disable(self) -> None:
        pass

    def enable(self) -> None:
        self.restarts += 1


def supervised(camera: StubCamera):
    clock = ManualClock()
    config = load_config(SIM_IDEAL)
    parts = ServiceParts(config=config, clock=clock, hub=EventHub(), warnings=EventLog(), looks=LookQueue(),
                         learning=LearningLog(clock), started_s=0.0,
                         devices=HeadDevices(bus=None, cameras={"left": camera}, world=None))  # type: ignore[arg-type]
    return Supervisor(parts, SystemdNotifier({}), FaultWatcher(parts, parts.hub)), parts, clock


def test_a_silent_camera_is_restarted_at_most_once_per_stall_time():
    camera = StubCamera()
    supervisor, parts, clock = supervised(camera)
    stall_s = parts.config.service.camera_stall_s
    supervisor.tick()
    assert camera.restarts == 0
    clock.advance(stall_s + 0.1)
    supervisor.tick()
    assert camera.restarts == 1 and parts.camera_restarts["left"] == 1
    clock.advance(stall_s / 2)
    supervisor.tick()
    assert camera.restarts == 1  # not again so soon
    clock.advance(stall_s)
    supervisor.tick()
    assert camera.restarts == 2


def test_a_fault_is_published_when_it_appears_and_when_it_clears():
    camera = StubCamera()
    supervisor, parts, _ = supervised(camera)
    seen: list[dict] = []
    parts.hub.subscribe(seen.append)
    camera.health = StreamHealth.FAILED
    supervisor.tick()
    supervisor.tick()
    camera.health = StreamHealth.STREAMING
    supervisor.tick()
    assert [(e["type"], e["key"]) for e in seen] == [("fault", "camera:left"), ("fault_cleared", "camera:left")]


def test_the_worlds_room_has_the_configs_light_and_passers_by():
    config = load_config(SIM_IDEAL)
    room = SceneConfig(light=LightConfig(model="home"), passers_by=PassersByConfig(model="home"))
    lit = dataclasses.replace(config, cameras=dataclasses.replace(config.cameras, scene=room))
    world = HeadDevices.build(lit, ManualClock()).world
    assert world is not None and world.scene is not None
    assert world.scene.light is not CONSTANT_LIGHT and world.scene.motion is not None
    left = config.cameras.left
    assert world.scene is not shared_scene(left.seed, left.image == "colour", "generated")  # a room of its own
