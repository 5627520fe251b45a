"""The camera interface itself: typed config, lifecycle, the capture thread's error paths
and reconnection with backoff, checked on a scripted backend driven by events."""
from __future__ import annotations

import queue
import threading
import time

import numpy as np
import pytest

from drivers.cameras.camera import Camera, Capabilities, Grab, StreamHealth, create_camera
from drivers.cameras.config import CameraConfig
from drivers.errors import (
    BackendNotFoundError,
    CameraConfigError,
    CameraError,
    CameraLostError,
    CameraTimeoutError,
    DeviceStateError,
)


class ScriptedCamera(Camera):
    """A backend whose grabs come from a queue the test fills: frames, errors, or 'lost'."""

    backend_name = "scripted"
    capabilities = Capabilities(reconnect=True, exposure=True)
    CONFIG_KEYS = frozenset({"device", "exposure_us"})

    def __init__(self, config, **kwargs):
        super().__init__(config, **kwargs)
        self.script: queue.Queue = queue.Queue()
        self.opens = 0
        self.reopen_failures = 0
        self.exposure_us = None
        self.reopened = threading.Event()

    def _open_device(self):
        if self.reopen_failures > 0:
            self.reopen_failures -= 1
            raise CameraLostError(f"{self.name}: still gone")
        self.opens += 1
        if self.opens > 1:
            self.reopened.set()

    def _set_exposure_us(self, exposure_us):
        self.exposure_us = exposure_us

    def _grab(self, timeout_s):
        try:
            item = self.script.get(timeout=timeout_s)
        except queue.Empty:
            return None
        if isinstance(item, BaseException):
            raise item
        return Grab(np.full((4, 6), item, np.uint8), float(item), float(item) - 0.5, int(item * 1e9))


def scripted(**config):
    errors: list[BaseException] = []
    cam = ScriptedCamera(CameraConfig(backend="scripted", grab_timeout_s=0.05, reconnect_backoff_max_s=0.05, **config),
                         name="cam0", on_error=lambda camera, err: errors.append(err))
    return cam, errors


def test_config_from_mapping_types_and_defaults():
    config = CameraConfig.from_mapping({"backend": "aravis", "serial": "GV01", "pixel_format": "BayerRG8",
                                        "width": 640, "height": 480, "fps": 30, "exposure_us": 8000,
                                        "gain_db": 3, "image": "colour"}, "cameras.left")
    assert config.fps == 30.0 and isinstance(config.fps, float) and config.image == "colour"
    assert config.device is None and config.history == 8
    assert CameraConfig.from_mapping({"backend": "opencv", "device": 0}).device == 0
    assert CameraConfig.from_mapping({"backend": "opencv", "device": "/dev/v4l/by-id/x"}).device == "/dev/v4l/by-id/x"


@pytest.mark.parametrize("data, message", [
    ({"backend": "sim", "fsp": 30}, (r"cameras\.left\.fsp: got 30, expected a known key \(cameras\.left takes "
                                     r".*fps.*\); 'fsp' is an unknown key")),
    ({"fps": "fast"}, r"cameras\.left\.fps: got 'fast', expected a number"),
    ({"width": 640.5}, r"cameras\.left\.width: got 640\.5, expected an integer"),
    ({"image": "color"}, r"cameras\.left\.image: got 'color', expected 'grey' or 'colour'"),
    ({"fps": -1}, r"cameras\.left\.fps: got -1\.0, expected a positive rate"),
    ({"id": "a", "serial": "b"}, r"cameras\.left\.serial: got 'b', expected no serial when id is given \(id 'a'\)"),
    ({"history": 1}, r"cameras\.left\.history: got 1, expected at least 2 frames"),
    ({"width": True}, r"cameras\.left\.width: got True, expected an integer \(at least 2\)"),
    ({"exposure_us": float("nan")}, r"cameras\.left\.exposure_us: got nan, expected a number"),
    ({"eye": "middle"}, r"cameras\.left\.eye: got 'middle', expected 'left' or 'right'"),
    (["backend"], r"cameras\.left: got \['backend'\], expected a mapping"),
])
def test_config_errors_name_key_path_value_and_expectation(data, message):
    with pytest.raises(CameraConfigError, match=message):
        CameraConfig.from_mapping(data, "cameras.left")


def test_unknown_backend_and_keys_a_backend_does_not_use():
    with pytest.raises(BackendNotFoundError, match="unknown camera backend 'nope'"):
        create_camera(CameraConfig(backend="nope"))
    config = CameraConfig(backend=f"{__name__}:ScriptedCamera", serial="S1")
    with pytest.raises(CameraConfigError, match=r"right\.serial: got 'S1', expected nothing: serial is not used by .* "
                                                r"which uses .*device"):
        create_camera(config, key_path="right")
    cam = create_camera(CameraConfig(backend=f"{__name__}:ScriptedCamera", device="d"))
    assert isinstance(cam, ScriptedCamera)
    # A key given at its default value is refused too: the user wrote it, so it must mean something.
    config = CameraConfig.from_mapping({"backend": "opencv", "device": 0, "seed": 0}, "cameras.left")
    with pytest.raises(CameraConfigError, match=r"cameras\.left\.seed: got 0, expected nothing: seed is not used by "
                                                r"the 'opencv' backend"):
        create_camera(config, key_path="cameras.left")


def test_lifecycle_latest_and_frames():
    cam, errors = scripted(exposure_us=5000.0)
    assert cam.latest() is None
    with pytest.raises(DeviceStateError):
        cam.set_exposure_us(100.0)
    with cam:
        assert cam.exposure_us == 5000.0  # applied from the config at open
        with pytest.raises(DeviceStateError, match="cam0: not streaming"):
            cam.wait_frame(timeout_s=0.01)
        cam.enable()
        assert cam._thread is not None and cam._thread.name == "camera-cam0"
        cam.script.put(7)
        frame = cam.wait_frame(after_s=6.0)
        assert (frame.counter, frame.time_s, frame.exposure_start_s, frame.device_time_ns) == (1, 7.0, 6.5, 7_000_000_000)
        assert cam.latest() is frame and frame.image.shape == (4, 6)
        cam.script.put(8)
        assert cam.wait_frame().counter == 2
        assert [f.counter for f in cam.history()] == [1, 2]
        with pytest.raises(CameraConfigError, match="cam0: the scripted backend has no gain control"):
            cam.set_gain_db(1.0)
    assert cam.health is StreamHealth.STOPPED and not cam.is_open
    cam.close()  # idempotent
    assert not errors


def test_a_bad_frame_is_reported_and_streaming_goes_on():
    cam, errors = scripted()
    with cam:
        cam.enable()
        cam.script.put(CameraError("cam0: incomplete buffer"))
        cam.script.put(3)
        assert cam.wait_frame(after_s=2.0).time_s == 3.0
        assert [str(e) for e in errors] == ["cam0: incomplete buffer"]
        assert cam.health is StreamHealth.STREAMING and cam.stats()["errors"] == 1


def test_a_bug_in_the_backend_fails_the_stream_and_waiters_hear_it():
    cam, errors = scripted()
    with cam:
        cam.enable()
        cam.script.put(ZeroDivisionError("division by zero"))
        with pytest.raises(CameraError, match="cam0: the stream has failed: .*ZeroDivisionError"):
            cam.wait_frame(timeout_s=5)
        assert cam.health is StreamHealth.FAILED
        assert isinstance(errors[0].__cause__, ZeroDivisionError)


def test_a_lost_camera_is_reported_reopened_with_backoff_and_streams_again():
    cam, errors = scripted()
    cam.reopen_failures = 0
    with cam:
        cam.enable()
        cam.script.put(1)
        cam.wait_frame(after_s=0.0)
        cam.reopen_failures = 3  # the camera stays away for three attempts
        cam.script.put(CameraLostError("cam0: control lost"))
        assert cam.reopened.wait(5)
        cam.script.put(2)
        frame = cam.wait_frame(after_s=1.0, timeout_s=5)
        assert frame.counter == 2 and cam.health is StreamHealth.STREAMING
        assert cam.stats()["reconnects"] == 1
        assert isinstance(errors[0], CameraLostError)


def test_giving_up_reopening_fails_the_stream():
    cam = ScriptedCamera(CameraConfig(backend="scripted", grab_timeout_s=0.05, reconnect_backoff_max_s=0.02,
                                      reconnect_give_up_s=0.1), name="cam1")
    with cam:
        cam.enable()
        cam.reopen_failures = 10**6
        cam.script.put(CameraLostError("cam1: control lost"))
        with pytest.raises(CameraError, match="cam1: the stream has failed: cam1: gave up reopening"):
            cam.wait_frame(after_s=1.0, timeout_s=5)


def test_timeout_error_is_also_a_builtin_timeout():
    cam, _ = scripted()
    with cam:
        cam.enable()
        with pytest.raises(TimeoutError):
            cam.wait_frame(timeout_s=0.05)
    assert issubclass(CameraTimeoutError, TimeoutError)


def test_a_fault_repeating_every_frame_does_not_flood_the_log(caplog):
    cam, errors = scripted()
    with cam, caplog.at_level("WARNING", logger="drivers.cameras.camera"):
        cam.enable()
        for _ in range(250):
            cam.script.put(CameraError("cam0: incomplete buffer"))
        cam.script.put(5)
        cam.wait_frame(after_s=4.0, timeout_s=5)
    assert len(errors) == 250 and cam.stats()["errors"] == 250
    assert [r.getMessage() for r in caplog.records] == [
        "cam0: incomplete buffer",
        "cam0: incomplete buffer (repeated 100 times)",
        "cam0: incomplete buffer (repeated 200 times)",
    ]


def test_grabs_that_fail_at_once_are_paced_at_the_frame_rate():
    cam, errors = scripted(fps=50.0)  # failed grabs at least 20 ms apart
    with cam:
        cam.enable()
        started = time.monotonic()
        for _ in range(20):
            cam.script.put(CameraError("cam0: cannot read a frame from clip.avi"))
        cam.script.put(7)
        cam.wait_frame(after_s=6.0, timeout_s=5)
        elapsed = time.monotonic() - started
    assert len(errors) == 20
    assert elapsed >= 0.95 * 20 * 0.02  # not a spin: the last error waited its period before the frame
