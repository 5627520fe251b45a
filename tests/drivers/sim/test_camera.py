"""The simulated camera backend: config, frame grid on an injected clock, pose source,
stereo pairs taken after a given time, errors reported, synchronous rendering."""
from __future__ import annotations

import threading

import numpy as np
import pytest

from calib_free.sim.head_model import HeadModel
from drivers.cameras.camera import StreamHealth, create_camera
from drivers.cameras.config import CameraConfig, StereoCamerasConfig
from drivers.cameras.stereo import StereoPair
from drivers.clock import ManualClock
from drivers.errors import CameraConfigError, CameraError, CameraLostError, CameraTimeoutError
from drivers.sim.camera import SimulatedCamera, fixed_pose
from drivers.sim.scene import Scene, StereoRenderer, shared_scene

HEAD = HeadModel.default(160, 120)
REST = {"pan": 0.0, "tilt": 0.0, "left_eye": 2.0, "right_eye": -2.0}
MOVED = {"pan": 12.0, "tilt": -6.0, "left_eye": 4.0, "right_eye": -4.0}


class SwitchingPose:
    """A pose source that jumps from one pose to another when the clock reaches `at_s`."""

    def __init__(self, clock: ManualClock, at_s: float) -> None:
        self.clock, self.at_s = clock, at_s

    def __call__(self) -> dict[str, float]:
        return MOVED if self.clock.monotonic() >= self.at_s else REST


def make_pair(clock, pose_source, fps=(16.0, 16.0), image="grey", **kwargs):
    cams = []
    for eye, rate in zip(("left", "right"), fps):
        config = CameraConfig.from_mapping({"backend": "sim", "eye": eye, "fps": rate, "image": image,
                                            "width": 160, "height": 120, "seed": 3})
        cams.append(create_camera(config, clock=clock, head=HEAD, pose_source=pose_source,
                                  paced_by_clock=False, **kwargs))
    return cams


def test_frames_fall_on_the_clock_grid_and_follow_the_clock():
    clock = ManualClock(10.0)
    left, right = make_pair(clock, fixed_pose(**REST))
    with left, right:
        left.enable()
        right.enable()
        first = left.wait_frame(after_s=10.0)
        assert first.time_s == pytest.approx(10.0) and first.exposure_start_s == first.time_s
        assert first.image.shape == (120, 160) and first.image.dtype == np.uint8
        clock.advance(0.26)  # 4 frame periods and a bit, at 16 fps: frame 10.25 s is the latest
        frame = left.wait_frame(after_s=10.2)
        assert frame.time_s == pytest.approx(10.25)
        assert frame.counter > first.counter and frame.device_time_ns is None
        assert right.wait_frame(after_s=10.2).time_s == pytest.approx(10.25)
        assert left.health is StreamHealth.STREAMING


def test_pair_after_t_never_contains_a_frame_exposed_before_t():
    """Frames taken while the head moved must never be used: the pose changes at t."""
    clock = ManualClock(0.0)
    t_settled = 0.5
    pose = SwitchingPose(clock, t_settled)
    left, right = make_pair(clock, pose)
    with left, right, StereoPair(left, right, tolerance_s=0.001) as pair:
        left.enable()
        right.enable()
        before = pair.wait_pair(after_s=0.0)
        assert before.left.time_s < t_settled
        # The waiter starts before the head settles; the clock then runs past t.
        result: dict = {}
        waiter = threading.Thread(target=lambda: result.setdefault("pair", pair.wait_pair(after_s=t_settled, timeout_s=10)))
        waiter.start()
        while waiter.is_alive() and clock.monotonic() < 2.0:
            clock.advance(0.0625)  # one frame period, exact in binary
            for camera in (left, right):  # let each frame render before time moves on
                camera.wait_frame(after_s=clock.monotonic())
        waiter.join(10)
        got = result["pair"]
        assert got.left.exposure_start_s >= t_settled and got.right.exposure_start_s >= t_settled
        assert got.skew_s <= 0.001
        with StereoRenderer(HEAD, Scene(seed=3, colour=False), parallel=False) as renderer:
            want_left, want_right = renderer.render(MOVED)
        assert np.array_equal(got.left.image, want_left) and np.array_equal(got.right.image, want_right)
        # The first pair after t: its frames are the earliest exposed after t, not the latest.
        assert got.left.time_s == pytest.approx(t_settled)


def test_pairs_only_match_within_the_tolerance():
    clock = ManualClock(0.0)
    left, right = make_pair(clock, fixed_pose(**REST), fps=(16.0, 12.0))
    with left, right, StereoPair(left, right, tolerance_s=0.002) as pair:
        left.enable()
        right.enable()
        for _ in range(5):
            clock.advance(0.0625)
            left.wait_frame(after_s=clock.monotonic())
        got = pair.wait_pair(after_s=0.01, timeout_s=5)
        # 16 and 12 fps grids meet every 0.25 s.
        assert got.skew_s <= 0.002 and got.left.time_s == pytest.approx(0.25)
        with pytest.raises(CameraTimeoutError, match="no pair exposed after .* within"):
            pair.wait_pair(after_s=0.26, timeout_s=0.2)


def test_wait_frame_times_out_naming_the_camera():
    clock = ManualClock(0.0)
    left, _ = make_pair(clock, fixed_pose())
    with left:
        left.enable()
        left.wait_frame(after_s=0.0)
        with pytest.raises(CameraTimeoutError, match="left: no frame exposed after"):
            left.wait_frame(after_s=1.0, timeout_s=0.1)


def test_pose_source_errors_reach_the_callback_and_streaming_goes_on():
    clock = ManualClock(0.0)
    errors: list[BaseException] = []
    reported = threading.Event()
    calls = {"n": 0}

    def flaky_pose():
        calls["n"] += 1
        if calls["n"] == 2:
            raise RuntimeError("servo bus closed")
        return REST

    def on_error(camera, err):
        errors.append(err)
        reported.set()

    left, _ = make_pair(clock, flaky_pose, on_error=on_error)
    with left:
        left.enable()
        left.wait_frame(after_s=0.0)
        clock.advance(0.0625)
        assert reported.wait(5)
        clock.advance(0.0625)
        frame = left.wait_frame(after_s=0.125)
        assert frame.time_s == pytest.approx(0.125)
    assert isinstance(errors[0], CameraError) and "left: the pose source failed" in str(errors[0])
    assert left.stats()["errors"] == 1 and left.last_error is errors[0]


def test_paced_camera_on_a_manual_clock_runs_faster_than_real_time():
    clock = ManualClock(0.0)
    config = CameraConfig(backend="sim", eye="left", fps=100.0)
    with SimulatedCamera(config, clock=clock, head=HEAD, pose_source=fixed_pose()) as cam:
        cam.enable()
        frame = cam.wait_frame(after_s=0.5, timeout_s=10)  # 0.5 simulated seconds
        assert frame.time_s >= 0.5


def test_colour_frames_and_synchronous_render_agree():
    clock = ManualClock(0.0)
    left, right = make_pair(clock, fixed_pose(**REST), image="colour")
    with left, right:
        left.enable()
        frame = left.wait_frame(after_s=0.0)
        assert frame.is_colour and frame.image.shape == (120, 160, 3)
        assert np.array_equal(left.render(REST), frame.image)
        assert not np.array_equal(right.render(REST), frame.image)


def test_config_errors_name_the_key():
    with pytest.raises(CameraConfigError, match="cyclops: a simulated camera needs eye"):
        SimulatedCamera(CameraConfig(backend="sim"), name="cyclops", head=HEAD, pose_source=fixed_pose())
    with pytest.raises(CameraConfigError, match="width 320 differs"):
        SimulatedCamera(CameraConfig(backend="sim", eye="left", width=320), head=HEAD, pose_source=fixed_pose())
    with pytest.raises(CameraConfigError, match="left: a simulated camera needs head="):
        create_camera(CameraConfig(backend="sim", eye="left"))
    with pytest.raises(CameraConfigError, match=r"cameras\.left\.lens: got 'fisheye', expected 'foveated' or"):
        CameraConfig.from_mapping({"backend": "sim", "lens": "fisheye"}, "cameras.left")
    with pytest.raises(CameraConfigError, match=r"cameras\.left\.serial: got 'X', expected nothing: serial is not used "
                                                r"by the 'sim' backend"):
        create_camera(CameraConfig(backend="sim", eye="left", serial="X"), key_path="cameras.left",
                      head=HEAD, pose_source=fixed_pose())


def scene_section(scene, backend="sim"):
    cameras = {side: {"backend": backend, "eye": side, "width": 160, "height": 120} for side in ("left", "right")}
    if backend != "sim":
        cameras = {side: {"backend": backend} for side in ("left", "right")}
    return {**cameras, "scene": scene}


def test_the_scene_section_chooses_the_room(tmp_path):
    assert StereoCamerasConfig.from_mapping(scene_section({})).scene.kind == "generated"
    assert StereoCamerasConfig.from_mapping(scene_section({"room": "photos"})).scene.kind == "photos"
    (tmp_path / "poster.png").write_bytes(b"")  # found by name; read when the room is built
    chosen = StereoCamerasConfig.from_mapping(scene_section({"textures": str(tmp_path)})).scene
    assert chosen.kind == "photos" and chosen.folder == tmp_path


@pytest.mark.parametrize("scene, backend, key, says", [
    ({"room": "attic"}, "sim", "cameras.scene.room", "'generated' or 'photos'"),
    ({"textures": "/no/such/folder"}, "sim", "cameras.scene.textures", "/no/such/folder: no such folder"),
    ({"room": "generated", "textures": "/tmp"}, "sim", "cameras.scene.room", "papers the photo room"),
    ({"room": "photos"}, "opencv", "cameras.scene", "not simulated"),
])
def test_scene_config_errors_name_the_key_and_the_path(scene, backend, key, says):
    with pytest.raises(CameraConfigError) as err:
        StereoCamerasConfig.from_mapping(scene_section(scene, backend))
    assert f"{key}:" in str(err.value) and says in str(err.value)


def test_a_simulated_camera_renders_the_photo_room():
    clock = ManualClock()
    # Seed 0: the rooms other tests build too (shared_scene keeps them for the process).
    config = CameraConfig.from_mapping({"backend": "sim", "eye": "left", "width": 160, "height": 120, "seed": 0})
    photos = create_camera(config, clock=clock, head=HEAD, pose_source=fixed_pose(**REST),
                           scene=shared_scene(0, False, "photos"), paced_by_clock=False)
    generated = create_camera(config, clock=clock, head=HEAD, pose_source=fixed_pose(**REST), paced_by_clock=False)
    with photos, generated:
        assert not np.array_equal(photos.render(REST), generated.render(REST))
        assert photos.render(REST).std() > 10


def test_an_unplugged_camera_is_lost_reopens_only_once_plugged_back_and_is_configured_again():
    clock = ManualClock(0.0)
    config = CameraConfig.from_mapping({"backend": "sim", "eye": "left", "fps": 16.0, "width": 160, "height": 120,
                                        "seed": 3, "reconnect_backoff_max_s": 0.02}, "cameras.left")
    errors: list[BaseException] = []
    cam = create_camera(config, name="left", clock=clock, head=HEAD, pose_source=fixed_pose(**REST),
                        paced_by_clock=False, on_error=lambda c, err: errors.append(err))
    assert isinstance(cam, SimulatedCamera) and cam.capabilities.reconnect
    states: list[StreamHealth] = []
    changed = threading.Event()

    def listener(frame):
        if frame is None:
            states.append(cam.health)
            changed.set()

    cam.add_listener(listener)
    with cam:
        cam.enable()
        cam.wait_frame(after_s=0.0)
        assert cam.opens == 1
        cam.unplug()
        clock.advance(0.1)
        assert changed.wait(5) and states[0] is StreamHealth.RECONNECTING
        assert isinstance(errors[0], CameraLostError) and "left: no frame" in str(errors[0])
        assert "device node is gone (unplugged)" in str(errors[0])
        with pytest.raises(CameraTimeoutError):
            cam.wait_frame(timeout_s=0.2)
        assert cam.opens == 1  # every reopen failed on the missing node
        cam.replug()
        clock.advance(0.1)
        frame = cam.wait_frame(timeout_s=5)
        assert cam.health is StreamHealth.STREAMING and cam.stats()["reconnects"] == 1
        assert cam.opens == 2 and frame.image.shape == (120, 160)
