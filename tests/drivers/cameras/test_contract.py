"""One contract for every camera backend: the simulated eye, Aravis's Fake camera and a video
file through OpenCV by default; a real head's left camera with `-m hardware` and
HEADCTL_HW_CONFIG=path/to/a YAML with a cameras: section."""
from __future__ import annotations

import dataclasses
import os
import threading
import time

import cv2
import numpy as np
import pytest

from calib_free.sim.head_model import HeadModel
from drivers.cameras.camera import Camera, Capabilities, create_camera
from drivers.cameras.config import CameraConfig
from drivers.cameras.stereo import StereoPair
from drivers.errors import CameraConfigError, DeviceStateError
from drivers.sim.camera import fixed_pose

INSTALL = "run ./setup.sh (it installs gir1.2-aravis-0.8, aravis-tools and PyGObject<3.51)"


def _video(path: str) -> str:
    writer = cv2.VideoWriter(path, cv2.VideoWriter_fourcc(*"MJPG"), 60.0, (96, 64))
    rng = np.random.default_rng(1)
    for _ in range(30):
        writer.write(rng.integers(0, 255, (64, 96, 3), dtype=np.uint8))
    writer.release()
    return path


def _hardware_camera(side: str, image: str) -> Camera:
    """The `side` camera of the head config HEADCTL_HW_CONFIG names (built as headctl does)."""
    from headctl.cli.cameras import load_cameras_config, sim_resources

    path = os.environ.get("HEADCTL_HW_CONFIG")
    if not path:
        pytest.fail("hardware camera tests need HEADCTL_HW_CONFIG=path/to/head.yaml (with a cameras: section)",
                    pytrace=False)
    config = load_cameras_config(path)
    resources = sim_resources(config, [0.0, 0.0, 0.0, 0.0]).get(side, {})
    return create_camera(dataclasses.replace(getattr(config, side), image=image), name=side,
                         key_path=f"cameras.{side}", **resources)


@pytest.fixture(params=["sim", "aravis-fake", "opencv-file", pytest.param("hardware", marks=pytest.mark.hardware)])
def make_camera(request, tmp_path):
    """A factory: make_camera(side, image) -> an unopened camera of the backend under test."""
    kind = request.param
    head = HeadModel.default(128, 96)
    video = _video(str(tmp_path / "cam.avi")) if kind == "opencv-file" else None
    if kind == "aravis-fake":
        try:
            import drivers.cameras.aravis  # noqa: F401
        except (ImportError, ValueError) as err:
            pytest.fail(f"the Aravis backend does not import ({err}): {INSTALL}", pytrace=False)
    made: list[Camera] = []

    def make(side: str = "left", image: str = "grey") -> Camera:
        if kind == "sim":
            config = CameraConfig(backend="sim", eye=side, fps=60.0, image=image)
            camera = create_camera(config, name=side, head=head, pose_source=fixed_pose(0, 0, 2, -2))
        elif kind == "aravis-fake":
            config = CameraConfig(backend="aravis", id="Fake_1", width=128, height=96, fps=60.0, image=image)
            camera = create_camera(config, name=side)
        elif kind == "opencv-file":
            camera = create_camera(CameraConfig(backend="opencv", device=video, image=image), name=side)
        else:
            camera = _hardware_camera(side, image)
        made.append(camera)
        return camera

    yield make
    for camera in made:
        camera.close()


def test_lifecycle_and_the_named_capture_thread(make_camera):
    camera = make_camera()
    assert isinstance(camera.capabilities, Capabilities) and camera.latest() is None
    with pytest.raises(DeviceStateError):
        camera.enable()
    with camera:
        with pytest.raises(DeviceStateError, match="not streaming"):
            camera.wait_frame(timeout_s=0.1)
        camera.enable()
        camera.enable()  # idempotent
        assert any(t.name == f"camera-{camera.name}" for t in threading.enumerate())
        camera.wait_frame(timeout_s=5)
        camera.disable()
        camera.enable()  # streams again after a disable
        camera.wait_frame(timeout_s=5)
    camera.close()
    assert not any(t.name == f"camera-{camera.name}" and t.is_alive() for t in threading.enumerate())


def test_frames_count_up_with_monotonic_timestamps(make_camera):
    with make_camera() as camera:
        camera.enable()
        frames = [camera.wait_frame(timeout_s=5) for _ in range(4)]
    assert [f.counter for f in frames] == sorted({f.counter for f in frames})
    assert all(b.time_s > a.time_s for a, b in zip(frames, frames[1:]))
    assert all(f.exposure_start_s <= f.time_s <= time.monotonic() for f in frames)
    assert all(f.image.ndim == 2 and f.image.dtype == np.uint8 for f in frames)


def test_a_frame_after_t_was_exposed_after_t(make_camera):
    with make_camera(image="colour") as camera:
        camera.enable()
        camera.wait_frame(timeout_s=5)
        t = time.monotonic()
        frame = camera.wait_frame(after_s=t, timeout_s=5)
    assert frame.exposure_start_s >= t and frame.is_colour and frame.image.shape[2] == 3


def test_capabilities_are_declared_not_discovered(make_camera):
    with make_camera() as camera:
        for capable, setter, value in ((camera.capabilities.exposure, camera.set_exposure_us, 5000.0),
                                       (camera.capabilities.gain, camera.set_gain_db, 0.0)):
            if capable:
                setter(value)
            else:
                with pytest.raises(CameraConfigError, match=f"{camera.name}: the .* backend has no"):
                    setter(value)


def test_two_cameras_of_a_backend_make_a_stereo_pair(make_camera):
    left, right = make_camera("left"), make_camera("right")
    with left, right, StereoPair(left, right, tolerance_s=0.1) as pair:
        left.enable()
        right.enable()
        t = time.monotonic()
        frames = pair.wait_pair(after_s=t, timeout_s=10)
    assert frames.left.camera == "left" and frames.right.camera == "right"
    assert frames.exposure_start_s >= t and frames.skew_s <= 0.1
