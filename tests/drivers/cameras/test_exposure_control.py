"""Exposure control in the camera interface: `exposure_control` in the config, and the
lock / unlock template methods over a backend's hooks, on a backend that records its calls."""
from __future__ import annotations

import pytest

from drivers.cameras.camera import Camera, Capabilities, ExposureMode, create_camera
from drivers.cameras.config import CameraConfig
from drivers.errors import CameraConfigError, CameraError, DeviceStateError


class HoldingCamera(Camera):
    """A backend that can hold its exposure; it records the hooks called, in order."""

    backend_name = "holding"
    capabilities = Capabilities(exposure=True, exposure_lock=True)
    CONFIG_KEYS = frozenset({"exposure_us"})

    def __init__(self, config, **kwargs):
        super().__init__(config, **kwargs)
        self.calls: list[str] = []
        self.unlock_fails = 0

    def _lock_exposure(self):
        self.calls.append("lock")

    def _unlock_exposure(self):
        if self.unlock_fails:
            self.unlock_fails -= 1
            raise CameraError(f"{self.name}: the device did not answer")
        self.calls.append("unlock")

    def _set_exposure_us(self, exposure_us):
        self.calls.append(f"exposure {exposure_us:g}")


class FixedCamera(HoldingCamera):
    """The same backend without an exposure lock."""

    backend_name = "fixed"
    capabilities = Capabilities(exposure=True)


def holding(**config) -> HoldingCamera:
    return HoldingCamera(CameraConfig(backend="holding", **config), name="left")


@pytest.mark.parametrize("data, message", [
    ({"exposure_control": "manual"},
     r"cameras\.left\.exposure_us: missing, expected an exposure time in us: exposure_control: manual"),
    ({"exposure_control": "lock_per_fixation", "exposure_us": 8000},
     r"cameras\.left\.exposure_control: got 'lock_per_fixation', expected manual .*exposure_us 8000 fixes"),
    ({"exposure_control": "locked"},
     r"cameras\.left\.exposure_control: got 'locked', expected 'auto' or 'lock_per_fixation' or 'manual'"),
])
def test_exposure_control_config_errors_name_the_key(data, message):
    with pytest.raises(CameraConfigError, match=message):
        CameraConfig.from_mapping(data, "cameras.left")


def test_exposure_control_is_a_key_of_every_backend():
    for backend in ("sim", "opencv", "aravis"):
        config = CameraConfig.from_mapping({"backend": backend, "exposure_control": "auto"}, "cameras.left")
        assert config.exposure_control == "auto"
    assert CameraConfig().exposure_control == "auto"


def test_lock_then_unlock_calls_each_hook_once_and_tracks_the_mode():
    cam = holding()
    with cam:
        assert cam.exposure_mode is ExposureMode.AUTO and cam.calls == []  # auto: the device left as it is
        cam.lock_exposure()
        cam.lock_exposure()  # held already: nothing more to do
        assert cam.exposure_mode is ExposureMode.LOCKED and cam.calls == ["lock"]
        cam.unlock_exposure()
        cam.unlock_exposure()
        assert cam.exposure_mode is ExposureMode.AUTO and cam.calls == ["lock", "unlock"]


def test_a_manual_exposure_is_never_locked_nor_unlocked():
    cam = holding(exposure_us=8000.0, exposure_control="manual")
    with cam:
        assert cam.exposure_mode is ExposureMode.MANUAL and cam.calls == ["exposure 8000"]
        cam.lock_exposure()
        cam.unlock_exposure()
        assert cam.calls == ["exposure 8000"] and cam.exposure_mode is ExposureMode.MANUAL
    cam = holding()
    with cam:
        cam.lock_exposure()
        cam.set_exposure_us(2000.0)  # a caller's value replaces the held one
        cam.unlock_exposure()
        assert cam.exposure_mode is ExposureMode.MANUAL and cam.calls == ["lock", "exposure 2000"]


def test_lock_per_fixation_starts_the_device_in_auto_exposure():
    """A device keeps its controls while powered: one left held by a process that died is let
    run again when opened."""
    cam = holding(exposure_control="lock_per_fixation")
    with cam:
        assert cam.calls == ["unlock"] and cam.exposure_mode is ExposureMode.AUTO


def test_a_failed_unlock_stays_locked_and_the_next_unlock_tries_again():
    cam = holding()
    with cam:
        cam.lock_exposure()
        cam.unlock_fails = 1
        with pytest.raises(CameraError, match="left: the device did not answer"):
            cam.unlock_exposure()
        assert cam.exposure_mode is ExposureMode.LOCKED
        cam.unlock_exposure()
        assert cam.exposure_mode is ExposureMode.AUTO and cam.calls == ["lock", "unlock"]


def test_a_camera_without_the_lock_says_so_and_refuses_lock_per_fixation_at_open():
    cam = FixedCamera(CameraConfig(backend="fixed"), name="right")
    with cam:
        assert not cam.capabilities.exposure_lock
        with pytest.raises(CameraConfigError, match="right: the fixed backend cannot hold its exposure"):
            cam.lock_exposure()
    config = CameraConfig(backend=f"{__name__}:FixedCamera", exposure_control="lock_per_fixation")
    cam = create_camera(config, name="right")  # built: the device is not asked before it opens
    with pytest.raises(CameraConfigError, match="right: exposure_control: lock_per_fixation, but this fixed camera "
                                                "cannot hold its exposure"):
        cam.open()
    assert not cam.is_open


def test_lock_needs_an_open_camera():
    cam = holding()
    with pytest.raises(DeviceStateError, match="left: the device is closed"):
        cam.lock_exposure()
