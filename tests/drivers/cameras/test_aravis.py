"""The Aravis backend against Aravis's own fake cameras: the in-process Fake interface, and
`arv-fake-gv-camera-0.8` on loopback (GigE Vision discovery, GVCP control, GVSP stream),
including a camera that disappears and comes back while the driver keeps running."""
from __future__ import annotations

import os
import shutil
import subprocess
import threading
import time

import numpy as np
import pytest

INSTALL = "run ./setup.sh (it installs gir1.2-aravis-0.8, aravis-tools and PyGObject<3.51)"
try:
    from drivers.cameras import aravis as aravis_camera
except (ImportError, ValueError) as err:  # ValueError: gi without the Aravis 0.8 typelib
    pytest.fail(f"the Aravis backend does not import ({err}): {INSTALL}", pytrace=False)

from drivers.cameras.camera import StreamHealth, create_camera
from drivers.cameras.config import CameraConfig
from drivers.errors import CameraConfigError, CameraLostError

FAKE_GV = "arv-fake-gv-camera-0.8"


def fake_config(**overrides) -> CameraConfig:
    settings = {"backend": "aravis", "id": "Fake_1", "width": 320, "height": 240, "fps": 100.0}
    settings.update(overrides)
    return CameraConfig.from_mapping(settings, "cameras.left")


def test_fake_camera_streams_mono8_with_mapped_timestamps():
    with create_camera(fake_config(pixel_format="Mono8", exposure_us=2000.0, gain_db=1.0), name="left") as cam:
        cam.enable()
        first = cam.wait_frame(timeout_s=5)
        frame = cam.wait_frame(timeout_s=5)
        now_s = time.monotonic()
        assert frame.image.shape == (240, 320) and frame.image.dtype == np.uint8
        assert frame.counter > first.counter and frame.time_s > first.time_s
        # Arrival time mapped from Aravis's wall-clock stamp onto the monotonic clock.
        assert now_s - 1.0 < frame.time_s <= now_s
        assert frame.exposure_start_s < frame.time_s and frame.device_time_ns is not None
        assert cam.device_id == "Fake_1"
        stats = cam.stats()
        assert stats["aravis_completed_buffers"] >= 2 and "aravis_underruns" in stats and "aravis_failures" in stats
        cam.set_exposure_us(1000.0)


@pytest.mark.parametrize("pixel_format, image, shape", [
    ("RGB8", "colour", (240, 320, 3)),
    ("BayerRG8", "colour", (240, 320, 3)),
    ("BayerGB8", "grey", (240, 320)),
    ("Mono8", "colour", (240, 320, 3)),
])
def test_fake_camera_pixel_formats_are_converted(pixel_format, image, shape):
    with create_camera(fake_config(pixel_format=pixel_format, image=image), name="left") as cam:
        cam.enable()
        frame = cam.wait_frame(timeout_s=5)
        assert frame.image.shape == shape and frame.image.dtype == np.uint8
        assert frame.image.std() > 0  # the fake camera's pattern came through


def test_unsupported_format_and_missing_camera_are_clear_errors():
    with pytest.raises(CameraConfigError, match="left: pixel_format 'Mono16': expected one of Mono8"):
        create_camera(fake_config(pixel_format="Mono16"), name="left")
    cam = create_camera(fake_config(id="Fake_9"), name="left")
    with pytest.raises(CameraLostError, match=r"left: no aravis device with id 'Fake_9'; devices seen: .*Fake_1"):
        cam.open()
    assert not cam.is_open


@pytest.fixture
def gv_camera():
    """Starts (and restarts, on request) a fake GigE Vision camera on 127.0.0.1."""
    if shutil.which(FAKE_GV) is None:
        pytest.fail(f"{FAKE_GV} is missing: {INSTALL}", pytrace=False)
    serial = f"T{os.getpid() % 100000}"

    class Server:
        process: subprocess.Popen | None = None

        def start(self) -> None:
            self.process = subprocess.Popen([FAKE_GV, "-i", "127.0.0.1", "-s", serial],
                                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)

        def kill(self) -> None:
            if self.process is not None:
                self.process.kill()
                self.process.wait(5)
                self.process = None

        def wait_visible(self, timeout_s: float = 15.0) -> None:
            """Until Aravis's discovery (about 1 s a round) sees the camera."""
            deadline = time.monotonic() + timeout_s
            while not any(d.serial == serial for d in aravis_camera._devices(refresh=True)):
                assert self.process is not None and self.process.poll() is None, f"{FAKE_GV} exited"
                assert time.monotonic() < deadline, f"{FAKE_GV} -s {serial} not discovered in {timeout_s} s"

    server = Server()
    server.serial = serial
    server.start()
    try:
        server.wait_visible()
        yield server
    finally:
        server.kill()


def test_gige_camera_on_loopback_disappears_and_streams_again(gv_camera):
    lost = threading.Event()
    errors: list[BaseException] = []

    def on_error(camera, err):
        errors.append(err)
        if isinstance(err, CameraLostError):
            lost.set()

    config = CameraConfig.from_mapping({"backend": "aravis", "serial": gv_camera.serial, "width": 256, "height": 192,
                                        "fps": 50, "reconnect_backoff_max_s": 0.5, "reconnect_give_up_s": 60})
    with create_camera(config, name="right", on_error=on_error) as cam:
        cam.enable()
        frame = cam.wait_frame(timeout_s=10)
        assert frame.image.shape == (192, 256)
        assert cam.device_id.endswith(gv_camera.serial)
        gv_camera.kill()
        assert lost.wait(20), "control-lost was not reported"
        assert "control of aravis device" in str(errors[0]) and cam.health is StreamHealth.RECONNECTING
        back_s = time.monotonic()
        gv_camera.start()
        frame = cam.wait_frame(after_s=back_s, timeout_s=30)
        assert frame.image.shape == (192, 256), "the size was applied again on reopen"
        assert cam.health is StreamHealth.STREAMING and cam.stats()["reconnects"] == 1


@pytest.mark.parametrize("name, red_at", [("BayerRG8", (0, 0)), ("BayerGR8", (0, 1)), ("BayerBG8", (1, 1)),
                                          ("BayerGB8", (1, 0))])
def test_bayer_patterns_are_demosaiced_with_the_right_colours(name, red_at):
    """GenICam names a Bayer pattern by its first row, OpenCV by its second: a red scene
    mosaicked the GenICam way must come out red."""
    import cv2

    code = next(code for fmt, code, _ in aravis_camera._CONVERSIONS.values() if fmt == name)
    mosaic = np.zeros((8, 8), np.uint8)
    mosaic[red_at[0]::2, red_at[1]::2] = 255
    assert cv2.cvtColor(mosaic, code)[3, 3].tolist() == [0, 0, 255]


# --- exposure lock: ExposureAuto and GainAuto ------------------------------------------------
_EXPOSURE_AUTO = """
	<Enumeration Name="ExposureAuto" NameSpace="Standard">
		<EnumEntry Name="Off" NameSpace="Standard"><Value>0</Value></EnumEntry>
		<EnumEntry Name="Once" NameSpace="Standard"><Value>1</Value></EnumEntry>
		<EnumEntry Name="Continuous" NameSpace="Standard"><Value>2</Value></EnumEntry>
		<pValue>ExposureAutoRegister</pValue>
	</Enumeration>
	<IntReg Name="ExposureAutoRegister" NameSpace="Custom">
		<Address>0x140</Address><Length>4</Length><AccessMode>RW</AccessMode><pPort>Device</pPort>
		<Sign>Unsigned</Sign><Endianess>BigEndian</Endianess>
	</IntReg>
"""


@pytest.fixture
def fake_genicam(tmp_path):
    """Aravis's Fake camera described by another GenICam file: `use(edit)` makes the next
    Fake_1 opened read its own XML through `edit`. Its XML is restored afterwards."""
    import re

    from gi.repository import Aravis

    aravis_camera.enable_fake_interface()
    stock = Aravis.Camera.new("Fake_1").get_device().get_genicam_xml()[0]
    original = tmp_path / "fake-stock.xml"
    original.write_text(stock)
    edits = {
        "with ExposureAuto": lambda xml: xml.replace("<!-- Analog control -->", _EXPOSURE_AUTO + "<!-- Analog control -->"),
        "without GainAuto": lambda xml: re.sub(r'<Enumeration Name="GainAuto".*?</Enumeration>', "",
                                               xml.replace("<pFeature>GainAuto</pFeature>", ""), flags=re.S),
    }

    def use(kind: str) -> None:
        path = tmp_path / f"fake-{kind.replace(' ', '-')}.xml"
        path.write_text(edits[kind](stock))
        Aravis.set_fake_camera_genicam_filename(str(path))

    try:
        yield use
    finally:
        Aravis.set_fake_camera_genicam_filename(str(original))


def _feature(cam, name: str) -> str:
    return cam._camera.get_device().get_string_feature_value(name)


def test_lock_holds_exposure_and_gain_at_their_values_and_unlock_lets_both_run(fake_genicam):
    fake_genicam("with ExposureAuto")
    with create_camera(fake_config(), name="left") as cam:
        assert cam.capabilities.exposure_lock
        device = cam._camera.get_device()
        device.set_string_feature_value("ExposureAuto", "Continuous")
        device.set_string_feature_value("GainAuto", "Continuous")
        device.set_float_feature_value("ExposureTimeAbs", 3000.0)  # where the automatic loop got to
        device.set_integer_feature_value("GainRaw", 4)
        cam.lock_exposure()
        assert (_feature(cam, "ExposureAuto"), _feature(cam, "GainAuto")) == ("Off", "Off")
        assert device.get_float_feature_value("ExposureTimeAbs") == 3000.0
        assert device.get_integer_feature_value("GainRaw") == 4
        cam.unlock_exposure()
        assert (_feature(cam, "ExposureAuto"), _feature(cam, "GainAuto")) == ("Continuous", "Continuous")


def test_the_stock_fake_camera_holds_its_gain_only(fake_genicam):
    with create_camera(fake_config(exposure_control="lock_per_fixation"), name="left") as cam:
        assert cam.capabilities.exposure_lock
        assert _feature(cam, "GainAuto") == "Continuous"  # opened with its automatic gain running
        cam.lock_exposure()
        assert _feature(cam, "GainAuto") == "Off"
        cam.unlock_exposure()
        assert _feature(cam, "GainAuto") == "Continuous"


def test_a_camera_without_exposure_auto_or_gain_auto_cannot_lock(fake_genicam):
    fake_genicam("without GainAuto")
    with create_camera(fake_config(), name="left") as cam:
        assert not cam.capabilities.exposure_lock
        with pytest.raises(CameraConfigError, match="left: the aravis backend cannot hold its exposure"):
            cam.lock_exposure()
    cam = create_camera(fake_config(exposure_control="lock_per_fixation"), name="left")
    with pytest.raises(CameraConfigError, match="left: exposure_control: lock_per_fixation, but this aravis camera "
                                                "cannot hold its exposure"):
        cam.open()


def test_a_manual_exposure_switches_exposure_auto_off(fake_genicam):
    fake_genicam("with ExposureAuto")
    with create_camera(fake_config(exposure_us=2500.0, gain_db=2.0, exposure_control="manual"), name="left") as cam:
        assert (_feature(cam, "ExposureAuto"), _feature(cam, "GainAuto")) == ("Off", "Off")
        assert cam._camera.get_device().get_float_feature_value("ExposureTimeAbs") == 2500.0
