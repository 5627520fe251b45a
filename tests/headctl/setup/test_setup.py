"""`headctl setup` in process: random wirings of the simulated head found from the images.

The assistant runs on a `ManualClock` over the simulated servos by id and two small
simulated cameras rendering from where the servos really are; the wiring is drawn at random
and compared with what the assistant wrote only at the end.
"""
from __future__ import annotations

import random
from pathlib import Path

import numpy as np
import pytest

from drivers.cameras.camera import create_camera
from drivers.cameras.config import CameraConfig, StereoCamerasConfig
from drivers.clock import ManualClock
from drivers.servo.config import PartialServoBusConfig
from drivers.servo.joints import JOINTS
from drivers.servo.probe import create_servo_probe
from drivers.sim.room import room_scene
from drivers.sim.servos import SimulatedServoProbe
from headctl.cli.main import build_parser
from headctl.config.head import DEFAULT_CONFIG, load_config, read_yaml
from headctl.service.build import SIM_START_JOINTS, sim_head_model
from headctl.setup.config import eye_zeros, propose, write_config
from headctl.setup.identify import Finding, SafeProbing, Shift, classify, identify

WIDTH, HEIGHT = 160, 120
PACKAGED = read_yaml(DEFAULT_CONFIG)  # configs/sim.yaml, the realistic world


def camera_section(realistic: bool = False) -> dict:
    """Two small simulated cameras; `realistic`: the packaged sim.yaml's webcams and room (its
    sensor, timing, exposure control and scene), at this size, without the ideal one's noise."""
    eye = {"backend": "sim", "width": WIDTH, "height": HEIGHT, "fps": 30, "lens": "foveated", "seed": 0,
           "noise_std": 2.0}
    if not realistic:
        return {"left": {**eye, "eye": "left"}, "right": {**eye, "eye": "right"}}
    packaged = PACKAGED["cameras"]
    keys = ("sensor", "timing", "exposure_control")
    eye.pop("noise_std")
    return {side: {**eye, "eye": side, **{k: packaged[side][k] for k in keys if k in packaged[side]}}
            for side in ("left", "right")} | {"scene": packaged["scene"]}


def random_wiring(rng: random.Random, extra: int = 0) -> dict[int, dict]:
    ids = rng.sample(range(1, 40), 4 + extra)
    joints = list(JOINTS) + ["none"] * extra
    rng.shuffle(joints)
    return {i: {"joint": joint, "direction": rng.choice((1, -1)), "zero_offset": round(rng.uniform(-20, 20), 1)}
            for i, joint in zip(ids, joints)}


class RenderedPairs:
    """Both eyes rendered on demand from where the simulated servos really are."""

    def __init__(self, probe: SimulatedServoProbe, clock: ManualClock, realistic: bool = False) -> None:
        section = camera_section(realistic)
        model = sim_head_model(CameraConfig.from_mapping(section["left"]))
        scene = (room_scene(StereoCamerasConfig.from_mapping(section).scene, 0, False, clock=clock)
                 if realistic else None)
        self.cameras = [create_camera(CameraConfig.from_mapping(section[side]), name=side, clock=clock,
                                      head=model, pose_source=lambda: {}, scene=scene) for side in ("left", "right")]
        for camera in self.cameras:
            camera.open()
        self.probe, self.clock = probe, clock
        self.noise_std = 0.0 if realistic else 2.0  # the webcam's sensor has its own
        self.rng = np.random.default_rng(0)

    def wait_pair(self, after_s: float, timeout_s: float) -> tuple[np.ndarray, np.ndarray]:
        self.clock.sleep(max(0.0, after_s - self.clock.monotonic()) + 1 / 30)
        joints = {joint: self.probe.true_position(joint) for joint in JOINTS}
        left, right = (c.render(joints).astype(np.float32) for c in self.cameras)  # type: ignore[attr-defined]
        noisy = [np.clip(im + self.rng.normal(0, self.noise_std, im.shape), 0, 255).astype(np.uint8)
                 for im in (left, right)]
        return noisy[0], noisy[1]

    def close(self) -> None:
        for camera in self.cameras:
            camera.close()


def centre_ray_off_axis_deg(joint: str) -> float:
    """How far (deg, horizontally) the ray through the image centre of the realistic eye of
    `joint` lies from its optical axis: its lens sits off-centre over the sensor and rolled
    (`drivers.sim.camera_effects.lens_error`). Setup makes the image centres parallel, so each
    eye's zero differs from its axis's by this much."""
    side = {"left_eye": "left", "right_eye": "right"}[joint]
    config = CameraConfig.from_mapping(camera_section(True)[side])
    camera = create_camera(config, name=side, clock=ManualClock(), head=sim_head_model(config), pose_source=lambda: {})
    lens = camera.unit_lens  # type: ignore[attr-defined]
    ray = lens.unproject(np.array([lens.principal_point]))[0]
    return abs(float(np.degrees(np.arctan2(ray[0], ray[2]))))


def run_assistant(wiring: dict[int, dict], tmp_path: Path, mechanics: dict | None = None,
                  realistic_cameras: bool = False):
    clock = ManualClock()
    bus_section = {"backend": "sim", "port": "sim:test", "wiring": wiring}
    if mechanics is not None:
        bus_section["mechanics"] = mechanics
    partial = {"servo_bus": bus_section, "cameras": camera_section(realistic_cameras),
               "fixation": {"vergence_range": [1, 20]}, "state_dir": str(tmp_path / "state")}
    bus = PartialServoBusConfig.from_mapping(partial["servo_bus"])
    probe = create_servo_probe(bus, clock=clock, initial_positions=SIM_START_JOINTS)
    assert isinstance(probe, SimulatedServoProbe)
    pairs = RenderedPairs(probe, clock, realistic_cameras)
    try:
        with SafeProbing(probe, clock) as probing:
            found = probe.scan()
            result = identify(probing, pairs, found)
            if result.missing(JOINTS):
                return result, None, probe
            joints = result.joints
            proposals = propose(joints, eye_zeros(probing, pairs, joints["left_eye"], joints["right_eye"]))
        tmp_path.mkdir(parents=True, exist_ok=True)
        out = tmp_path / "head.yaml"
        write_config(partial, None, {"backend": "sim", "port": "sim:test"}, proposals, out)
        return result, out, probe
    finally:
        pairs.close()


# The realistic servos (docs/sim-world.md, "Servos"): the neck's zeros are read off the encoders
# at the start, where the tilt already droops under the head's weight and a reading is a tick off.
XM430_HEAD = {"model": "xm430_head"}
HEAVY_HEAD = {"model": "xm430_head", "sag_deg_at_horizontal": 1.0, "backlash_deg": 0.5, "read_wobble_ticks": 2}


@pytest.mark.parametrize(("mechanics", "wirings", "neck_abs", "realistic_cameras"), [
    (None, 20, {"pan": 0.3, "tilt": 0.3}, False),
    (XM430_HEAD, 20, {"pan": 0.3, "tilt": 0.3 + 0.35}, False),
    (HEAVY_HEAD, 5, {"pan": 0.3, "tilt": 0.3 + 1.0}, False),
    # The whole realistic world of configs/sim.yaml: its servos, webcams and room.
    (PACKAGED["servo_bus"]["mechanics"], 20, {"pan": 0.3, "tilt": 0.3 + 0.35}, True),
], ids=["ideal", "xm430_head", "heavy_head", "realistic"])
def test_random_wirings_are_found_and_the_config_checks(tmp_path, mechanics, wirings, neck_abs,
                                                        realistic_cameras):
    rng = random.Random(2026)
    for n in range(wirings):
        wiring = random_wiring(rng)
        result, out, probe = run_assistant(wiring, tmp_path / str(n), mechanics, realistic_cameras)
        assert out is not None, [f.detail for f in result.findings]
        config = load_config(out)
        args = build_parser().parse_args(["check", "--no-connect", "--config", str(out)])
        assert args.func(args) == 0
        for servo_id, wired in wiring.items():
            jc = config.servo_bus.joints[wired["joint"]]
            assert jc.servo_id == servo_id, (n, wiring)
            assert jc.direction == wired["direction"], (n, wiring)
            if wired["joint"] in ("pan", "tilt"):  # the start pose is straight ahead
                assert jc.zero_offset == pytest.approx(wired["zero_offset"], abs=neck_abs[wired["joint"]])
            else:  # parallel against a room 1-3 m away: biased by up to 1 deg
                lens = centre_ray_off_axis_deg(wired["joint"]) if realistic_cameras else 0.0
                assert jc.zero_offset == pytest.approx(wired["zero_offset"], abs=1.5 + lens)
            # Every servo back where it started, torque as it was (off), settings restored.
            status = probe.status(servo_id)
            assert not status.torque_on and not status.moving
            assert probe.torque_limit(servo_id) is None
        assert config.servo_bus.joints["pan"].min_angle <= 0.0 <= config.servo_bus.joints["pan"].max_angle


def test_a_servo_that_moves_nothing_visible_is_reported_not_guessed(tmp_path):
    wiring = random_wiring(random.Random(7), extra=1)
    result, out, _probe = run_assistant(wiring, tmp_path)
    blind = next(i for i, w in wiring.items() if w["joint"] == "none")
    by_id = {f.servo.servo_id: f for f in result.findings}
    assert by_id[blind].outcome is Finding.NOTHING_VISIBLE and by_id[blind].joint is None
    assert out is not None  # the four others still make a head
    config = load_config(out)
    assert blind not in {jc.servo_id for jc in config.servo_bus.joints.values()}


def test_motion_like_no_joint_or_like_another_servo_is_not_guessed():
    assert classify(Shift(5, 5, 0.9), Shift(5, 5, 0.9))[0] is Finding.UNATTRIBUTED  # diagonal
    assert classify(Shift(8, 0, 0.9), Shift(-8, 0, 0.9))[0] is Finding.UNATTRIBUTED  # opposite
    assert classify(Shift(8, 0, 0.9), Shift(1.5, 0, 0.9))[0] is Finding.UNATTRIBUTED  # unlike amounts
    assert classify(Shift(0, 6, 0.9), Shift(0, 0, 1.0))[0] is Finding.UNATTRIBUTED  # one eye, vertically
    assert classify(Shift(0.3, 0.2, 0.9), Shift(0.1, 0, 1.0))[0] is Finding.NOTHING_VISIBLE
    assert classify(Shift(-8, 0, 0.9), Shift(0, 0, 1.0))[1:3] == ("left_eye", 1)
    assert classify(Shift(0, -8, 0.9), Shift(0.2, -8.3, 0.9))[1:3] == ("tilt", -1)
