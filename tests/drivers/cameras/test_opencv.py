"""The OpenCV backend: a generated video file played as a camera on an injected clock, device
resolution (index, path, udev symlink), granted settings logged, the drain that keeps the
held frame the newest the driver has (on a scripted V4L2-like capture on a ManualClock), and
a camera unplugged and plugged back (its path vanishing and coming back) reopened by its udev
name with its config applied again."""
from __future__ import annotations

import collections
import logging
import os
import shutil
import time

import cv2
import numpy as np
import pytest

from drivers.cameras.camera import StreamHealth, create_camera
from drivers.cameras.config import CameraConfig
from drivers.clock import ManualClock
from drivers.errors import CameraConfigError, CameraLostError, CameraTimeoutError
from drivers.cameras.opencv import OpenCVCamera, resolve_source

FPS = 25.0
N_FRAMES = 40


def frame_level(index: int) -> int:
    return 20 + 5 * index


@pytest.fixture(scope="module")
def video(tmp_path_factory):
    """An MJPG AVI whose frame i carries a block of grey level 20 + 5 i (and some texture)."""
    path = str(tmp_path_factory.mktemp("video") / "head.avi")
    writer = cv2.VideoWriter(path, cv2.VideoWriter_fourcc(*"MJPG"), FPS, (160, 120))
    assert writer.isOpened(), "cv2.VideoWriter cannot write MJPG AVI"
    rng = np.random.default_rng(0)
    texture = rng.integers(0, 255, (120, 160, 3), dtype=np.uint8)
    for i in range(N_FRAMES):
        image = texture.copy()
        image[40:80, 60:100] = frame_level(i)
        writer.write(image)
    writer.release()
    return path


def decoded_index(image: np.ndarray) -> int:
    block = image[50:70, 70:90].astype(float).mean()
    return int(round((block - 20) / 5))


def test_video_file_frames_follow_the_clock_in_order_and_loop(video):
    clock = ManualClock(100.0)
    config = CameraConfig.from_mapping({"backend": "opencv", "device": video, "image": "colour"}, "cameras.left")
    with create_camera(config, name="left", clock=clock) as cam:
        assert not cam.capabilities.exposure and not cam.capabilities.device_timestamps
        cam.enable()
        frame = cam.wait_frame(after_s=100.0 + 1.9, timeout_s=10)  # past the end: it loops
        history = cam.history()
    assert frame.image.shape == (120, 160, 3)
    for held in history:
        n = round((held.time_s - 100.0) * FPS)
        assert held.time_s == pytest.approx(100.0 + n / FPS)
        assert decoded_index(held.image) == n % N_FRAMES, f"frame at {held.time_s} s shows the wrong picture"
    assert [f.counter for f in history] == list(range(history[0].counter, history[0].counter + len(history)))


def test_udev_style_symlink_and_grey_frames(video, tmp_path):
    link = tmp_path / "head-left"
    os.symlink(video, link)
    with OpenCVCamera(CameraConfig(backend="opencv", device=str(link), fps=50.0), name="left") as cam:
        cam.enable()
        frame = cam.wait_frame(timeout_s=5)
        assert frame.image.shape == (120, 160) and not frame.is_colour
        with pytest.raises(CameraConfigError, match="left: the opencv backend has no exposure control"):
            cam.set_exposure_us(1000.0)


def test_device_resolution_and_errors(tmp_path):
    assert resolve_source(2, "x").target == 2 and resolve_source(2, "x").api == cv2.CAP_V4L2
    with pytest.raises(CameraLostError, match="left: device /dev/v4l/by-id/none does not exist"):
        OpenCVCamera(CameraConfig(backend="opencv", device="/dev/v4l/by-id/none"), name="left").open()
    # /dev/null is a character device, but not a V4L2 one.
    with pytest.raises(CameraLostError, match="right: OpenCV cannot open /dev/null"):
        OpenCVCamera(CameraConfig(backend="opencv", device="/dev/null"), name="right").open()
    with pytest.raises(CameraConfigError, match="pixel_format 'MJPEG': expected a FourCC"):
        OpenCVCamera(CameraConfig(backend="opencv", pixel_format="MJPEG"))
    with pytest.raises(CameraConfigError, match=r"cams\.l\.id: got 'Fake_1', expected nothing: id is not used by the "
                                                r"'opencv' backend"):
        create_camera(CameraConfig(backend="opencv", id="Fake_1"), key_path="cams.l")


class QueueCapture:
    """A V4L2-like capture on a ManualClock: a frame arrives every period; up to four wait in
    the driver's queue; grab() takes the oldest waiting one or blocks (advances the clock)."""

    def __init__(self, clock: ManualClock, period_s: float, stamps: bool) -> None:
        self.clock, self.period_s, self.stamps = clock, period_s, stamps
        self.next_index = 1
        self.queue: collections.deque = collections.deque(maxlen=4)
        self.current = (0, 0.0)
        self.props = {cv2.CAP_PROP_FRAME_WIDTH: 640, cv2.CAP_PROP_FRAME_HEIGHT: 480, cv2.CAP_PROP_FPS: 1 / period_s,
                      cv2.CAP_PROP_FOURCC: cv2.VideoWriter_fourcc(*"YUYV")}

    def _arrive(self) -> None:
        while self.next_index * self.period_s <= self.clock.monotonic() + 1e-12:
            self.queue.append((self.next_index, self.next_index * self.period_s))
            self.next_index += 1

    def isOpened(self) -> bool:
        return True

    def grab(self) -> bool:
        self._arrive()
        if not self.queue:
            self.clock.advance(self.next_index * self.period_s - self.clock.monotonic())
            self._arrive()
        self.current = self.queue.popleft()
        return True

    def retrieve(self):
        return True, np.full((6, 8, 3), self.current[0], np.uint8)

    def get(self, prop):
        if prop == cv2.CAP_PROP_POS_MSEC:
            return self.current[1] * 1e3 if self.stamps else 0.0
        return self.props.get(prop, 0.0)

    def set(self, prop, value) -> bool:
        if prop in (cv2.CAP_PROP_FRAME_WIDTH, cv2.CAP_PROP_FRAME_HEIGHT):
            return False  # this "camera" only does 640 x 480
        self.props[prop] = value
        return True

    def release(self) -> None:
        pass


@pytest.mark.parametrize("stamps", [True, False], ids=["driver-timestamps", "grab-durations"])
def test_capture_drains_the_driver_queue_so_the_frame_is_never_stale(stamps):
    clock = ManualClock(0.0)
    period_s = 0.04
    capture = QueueCapture(clock, period_s, stamps)
    cam = OpenCVCamera(CameraConfig(backend="opencv", device=0, fps=25.0), name="left", clock=clock,
                       capture_factory=lambda target, api: capture)
    with cam:
        first = cam._grab(1.0)
        assert first.image[0, 0, 0] == 1
        clock.advance(3.5 * period_s)  # a slow consumer: three frames wait in the queue
        grab = cam._grab(1.0)
        newest_waiting = 4
        assert grab.image[0, 0, 0] >= newest_waiting, "a stale frame from the driver queue was delivered"
        assert clock.monotonic() - grab.time_s < period_s
        assert cam.stats()["stale_frames_dropped"] >= 2


def test_granted_settings_are_logged(caplog):
    clock = ManualClock(0.0)
    capture = QueueCapture(clock, 0.04, True)
    config = CameraConfig(backend="opencv", device=0, pixel_format="MJPG", width=1280, height=720, fps=25.0)
    with caplog.at_level(logging.INFO, logger="drivers.cameras.opencv"):
        with OpenCVCamera(config, name="left", clock=clock, capture_factory=lambda target, api: capture):
            pass
    text = caplog.text
    assert "left: /dev/video0: asked MJPG 1280 x 720 at 25.0 fps; granted MJPG 640 x 480 at 25.00 fps" in text
    assert "left: width 1280 asked, 640 granted by /dev/video0" in text


def test_v4l2_formats_are_read_from_the_driver(tmp_path):
    """`headctl cameras` lists formats with VIDIOC_ENUM_FMT / VIDIOC_ENUM_FRAMESIZES; here a
    scripted ioctl answers as a UVC driver does (discrete YUYV sizes, a stepwise MJPG range)."""
    import errno

    from drivers.cameras import opencv as oc

    node = tmp_path / "video0"
    node.write_bytes(b"")
    table = [(b"YUYV 4:2:2", "YUYV", [(640, 480), (1280, 720)]), (b"Motion-JPEG", "MJPG", None)]
    by_code = {cv2.VideoWriter_fourcc(*fourcc): sizes for _, fourcc, sizes in table}

    def fake_ioctl(fd, request, buf):
        if request == oc._VIDIOC_ENUM_FMT:
            index, kind, *_ = oc._FMTDESC.unpack(buf)
            if kind != 1 or index >= len(table):
                raise OSError(errno.EINVAL, "Invalid argument")
            desc, fourcc, _ = table[index]
            buf[:] = oc._FMTDESC.pack(index, kind, 0, desc, cv2.VideoWriter_fourcc(*fourcc), 0, 0, 0, 0)
        elif request == oc._VIDIOC_ENUM_FRAMESIZES:
            index, code, *_ = oc._FRMSIZE.unpack(buf)
            sizes = by_code[code]
            if sizes is None and index == 0:
                buf[:] = oc._FRMSIZE.pack(index, code, 3, 160, 1920, 16, 120, 1080, 8, 0, 0)
            elif sizes is not None and index < len(sizes):
                buf[:] = oc._FRMSIZE.pack(index, code, 1, *sizes[index], 0, 0, 0, 0, 0, 0)
            else:
                raise OSError(errno.EINVAL, "Invalid argument")
        else:
            raise AssertionError(f"unexpected ioctl 0x{request:08x}")

    assert oc.v4l2_formats(str(node), ioctl=fake_ioctl) == [
        "YUYV (YUYV 4:2:2): 640x480, 1280x720",
        "MJPG (Motion-JPEG): 160x120 to 1920x1080",
    ]


def wait_health(cam, health, timeout_s=10.0):
    deadline = time.monotonic() + timeout_s
    while cam.health is not health:
        assert time.monotonic() < deadline, f"{cam.name}: health {cam.health.value}, waited for {health.value}"
        time.sleep(0.01)


@pytest.mark.parametrize("vanishing", ["udev-symlink", "file"])
def test_a_vanished_path_is_lost_and_reopened_once_it_is_back(video, tmp_path, vanishing):
    played = tmp_path / "head.avi"
    shutil.copy(video, played)
    link = tmp_path / "head-left"
    os.symlink(played, link)
    config = CameraConfig(backend="opencv", device=str(link), fps=50.0, reconnect_backoff_max_s=0.05)
    errors = []
    with OpenCVCamera(config, name="left", on_error=lambda cam, err: errors.append(err)) as cam:
        assert cam.capabilities.reconnect
        cam.enable()
        cam.wait_frame(timeout_s=5)
        gone = link if vanishing == "udev-symlink" else played
        aside = tmp_path / "aside"
        os.rename(gone, aside)
        wait_health(cam, StreamHealth.RECONNECTING)
        assert isinstance(errors[0], CameraLostError) and f"left: {link} vanished" in str(errors[0])
        with pytest.raises(CameraTimeoutError):
            cam.wait_frame(timeout_s=0.3)  # nothing from a vanished device
        os.rename(aside, gone)
        frame = cam.wait_frame(timeout_s=5)
        assert cam.health is StreamHealth.STREAMING and cam.stats()["reconnects"] == 1
        assert frame.image.shape == (120, 160)


class RecordingCapture:
    """A V4L2-like capture that records what it was set to; its device can be unplugged."""

    def __init__(self, target) -> None:
        self.target, self.unplugged, self.sets = target, False, []
        self.props = {cv2.CAP_PROP_FRAME_WIDTH: 640, cv2.CAP_PROP_FRAME_HEIGHT: 480, cv2.CAP_PROP_FPS: 100.0,
                      cv2.CAP_PROP_FOURCC: cv2.VideoWriter_fourcc(*"MJPG")}

    def isOpened(self) -> bool:
        return True

    def grab(self) -> bool:
        time.sleep(0.01)  # one frame period of a 100 fps camera
        return not self.unplugged

    def retrieve(self):
        return True, np.zeros((480, 640, 3), np.uint8)

    def get(self, prop):
        return self.props.get(prop, 0.0)

    def set(self, prop, value) -> bool:
        self.sets.append((prop, value))
        self.props[prop] = value
        return True

    def release(self) -> None:
        pass


def test_a_replugged_device_is_found_by_its_udev_name_and_configured_again(tmp_path):
    link = tmp_path / "head-left"  # udev's name for the camera; the node behind it changes
    os.symlink("/dev/null", link)
    captures = []

    def factory(target, api):
        captures.append(RecordingCapture(target))
        return captures[-1]

    config = CameraConfig(backend="opencv", device=str(link), pixel_format="MJPG", width=640, height=480,
                          fps=100.0, exposure_us=5000.0, gain_db=3.0, reconnect_backoff_max_s=0.05)
    with OpenCVCamera(config, name="left", capture_factory=factory) as cam:
        cam.enable()
        cam.wait_frame(timeout_s=5)
        captures[0].unplugged = True  # the driver fails its grabs, and the node goes
        os.unlink(link)
        wait_health(cam, StreamHealth.RECONNECTING)
        time.sleep(0.2)  # several reopen attempts, all failing on the missing path
        assert len(captures) == 1
        os.symlink("/dev/zero", link)  # back, under another node
        cam.wait_frame(timeout_s=5)
        assert cam.health is StreamHealth.STREAMING and cam.stats()["reconnects"] == 1
    assert [c.target for c in captures] == ["/dev/null", "/dev/zero"]
    wanted = [(cv2.CAP_PROP_FOURCC, cv2.VideoWriter.fourcc(*"MJPG")), (cv2.CAP_PROP_FRAME_WIDTH, 640),
              (cv2.CAP_PROP_FRAME_HEIGHT, 480), (cv2.CAP_PROP_FPS, 100.0),
              (cv2.CAP_PROP_AUTO_EXPOSURE, 1), (cv2.CAP_PROP_EXPOSURE, 50.0), (cv2.CAP_PROP_GAIN, 3.0)]
    assert captures[1].sets == captures[0].sets == wanted, "the replugged camera's config was not applied again"


class V4L2Capture(RecordingCapture):
    """A UVC-like device as OpenCV's V4L2 backend shows it: in aperture priority (auto
    exposure 3) with the exposure (100 us units) and gain its auto exposure reached;
    `normalized`: OpenCV scaling properties to [0, 1) (CAP_PROP_MODE then reads the palette,
    and `sticky` ones refuse to switch it off); `auto_exposure` None: no such control."""

    def __init__(self, target, auto_exposure=3, normalized=False, sticky=False) -> None:
        super().__init__(target)
        self.normalized, self.sticky = normalized, sticky
        self.props.update({cv2.CAP_PROP_EXPOSURE: 156.0, cv2.CAP_PROP_GAIN: 40.0})
        if auto_exposure is not None:
            self.props[cv2.CAP_PROP_AUTO_EXPOSURE] = auto_exposure / 4 if normalized else auto_exposure

    def get(self, prop):
        if prop == cv2.CAP_PROP_MODE:
            return float(self.props[cv2.CAP_PROP_FOURCC]) if self.normalized else 0.0
        return self.props.get(prop, -1.0)  # OpenCV's V4L2 backend: -1 for a control it cannot read

    def set(self, prop, value) -> bool:
        if prop == cv2.CAP_PROP_MODE:
            self.sets.append((prop, value))
            if not self.sticky:
                self.normalized = bool(value)
            return True
        return super().set(prop, value)


class FakeControls:
    """`V4L2Controls` of a driver with (or without) V4L2_CID_AUTOGAIN."""

    def __init__(self, autogain: bool) -> None:
        self.autogain, self.sets = autogain, []

    def query(self, control_id):
        from drivers.cameras.v4l2_controls import AUTOGAIN, ControlInfo

        return ControlInfo(AUTOGAIN, "Gain, Automatic", 0, 1, 1, 0) if self.autogain and control_id == AUTOGAIN else None

    def set(self, control_id, value):
        self.sets.append((control_id, value))


def v4l2_camera(capture, controls=None, **config):
    return OpenCVCamera(CameraConfig(backend="opencv", device=0, **config), name="left",
                        capture_factory=lambda target, api: capture,
                        controls_factory=lambda node: controls or FakeControls(False))


def test_lock_holds_the_exposure_and_gain_reached_and_unlock_restores_the_auto_mode():
    capture = V4L2Capture(0, auto_exposure=3)
    with v4l2_camera(capture) as cam:
        assert cam.capabilities.exposure_lock
        capture.sets.clear()
        cam.lock_exposure()
        # Manual (V4L2 menu 1, as OpenCV 4+ writes it), then the values the auto exposure reached.
        assert capture.sets == [(cv2.CAP_PROP_AUTO_EXPOSURE, 1), (cv2.CAP_PROP_EXPOSURE, 156.0),
                                (cv2.CAP_PROP_GAIN, 40.0)]
        capture.sets.clear()
        cam.unlock_exposure()
        assert capture.sets == [(cv2.CAP_PROP_AUTO_EXPOSURE, 3)]  # aperture priority again


def test_a_device_in_full_auto_gets_full_auto_back():
    capture = V4L2Capture(0, auto_exposure=0)
    with v4l2_camera(capture) as cam:
        cam.lock_exposure()
        capture.sets.clear()
        cam.unlock_exposure()
        assert capture.sets == [(cv2.CAP_PROP_AUTO_EXPOSURE, 0)]


def test_an_automatic_gain_is_switched_off_and_on_with_the_exposure():
    from drivers.cameras.v4l2_controls import AUTOGAIN

    capture, controls = V4L2Capture(0), FakeControls(autogain=True)
    with v4l2_camera(capture, controls) as cam:
        cam.lock_exposure()
        assert controls.sets == [(AUTOGAIN, 0)]
        cam.unlock_exposure()
        assert controls.sets == [(AUTOGAIN, 0), (AUTOGAIN, 1)]


def test_normalized_ranges_are_switched_off_at_open():
    capture = V4L2Capture(0, normalized=True)
    with v4l2_camera(capture, exposure_us=5000.0) as cam:
        assert capture.sets[:2] == [(cv2.CAP_PROP_MODE, 0), (cv2.CAP_PROP_AUTO_EXPOSURE, 1)]
        assert (cv2.CAP_PROP_EXPOSURE, 50.0) in capture.sets  # 100 us units, not a fraction
        assert cam.capabilities.exposure_lock


def test_ranges_that_stay_normalized_get_the_menu_scaled_as_opencv_scales_it():
    """OpenCV's normalized auto exposure is the V4L2 menu over 4: 0.25 manual, 0.75 aperture priority."""
    capture = V4L2Capture(0, normalized=True, sticky=True)
    with v4l2_camera(capture) as cam:
        capture.sets.clear()
        cam.lock_exposure()
        assert capture.sets[0] == (cv2.CAP_PROP_AUTO_EXPOSURE, 0.25)
        capture.sets.clear()
        cam.unlock_exposure()
        assert capture.sets == [(cv2.CAP_PROP_AUTO_EXPOSURE, 0.75)]


def test_a_device_without_auto_exposure_cannot_lock_and_refuses_lock_per_fixation():
    capture = V4L2Capture(0, auto_exposure=None)
    with v4l2_camera(capture) as cam:
        assert not cam.capabilities.exposure_lock
        with pytest.raises(CameraConfigError, match="left: the opencv backend cannot hold its exposure"):
            cam.lock_exposure()
    cam = v4l2_camera(V4L2Capture(0, auto_exposure=None), exposure_control="lock_per_fixation")
    with pytest.raises(CameraConfigError, match="left: exposure_control: lock_per_fixation, but this opencv camera"):
        cam.open()
    # With one, lock_per_fixation opens it in its auto exposure (a held one left by a dead process runs again).
    capture = V4L2Capture(0, auto_exposure=1)
    with v4l2_camera(capture, exposure_control="lock_per_fixation"):
        assert (cv2.CAP_PROP_AUTO_EXPOSURE, 3) in capture.sets


def test_a_video_file_cannot_lock(video):
    with OpenCVCamera(CameraConfig(backend="opencv", device=video), name="left") as cam:
        assert not cam.capabilities.exposure_lock
        with pytest.raises(CameraConfigError, match="left: the opencv backend cannot hold its exposure"):
            cam.lock_exposure()
