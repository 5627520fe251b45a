"""USB (UVC) cameras through OpenCV's VideoCapture on V4L2, and video files as cameras.

This module owns one `cv2.VideoCapture`: resolving the configured device (a path, an index,
or a udev symlink such as /dev/v4l/by-id/... or /dev/head-left, resolved again on every
reopen because a replugged camera may come back under another /dev/videoN), requesting
FourCC (MJPG, YUYV), size and rate and logging what the driver granted, and keeping the
frame it hands on fresh.

Freshness: V4L2 keeps several filled buffers (4 by default), so a `read()` can return a
frame several periods old. The capture thread grabs continuously and, when a grab returns a
frame that was already waiting in the queue (its driver timestamp is older than a frame
period, or, without a usable timestamp, the grab did not have to wait), grabs again before
decoding: the frame held is the newest the driver has.

A regular file (a recorded or generated video) opens as a camera too: its frames are
delivered at its frame rate on the camera's clock and it loops at the end. Tests use it.

Unplugged and plugged back: a configured path (device node or udev symlink, or a file) that
no longer exists makes the next grab fail as lost (`CameraLostError`), as does a grab the
driver fails; the base class then reopens with back-off, each attempt resolving the path
afresh, so the camera comes back under its udev name whatever /dev/videoN it got, with its
config applied again (FourCC, size, rate, and exposure and gain, the exposure set manual).

Exposure control on V4L2 through OpenCV's V4L2 backend (modules/videoio/src/cap_v4l.cpp,
the same in OpenCV 4 and 5): `CAP_PROP_AUTO_EXPOSURE` is rounded to an integer and written
to V4L2_CID_EXPOSURE_AUTO, a menu: 0 auto, 1 manual, 2 shutter priority, 3 aperture priority
(uvcvideo maps UVC's auto exposure modes onto it; UVC webcams mostly offer manual and
aperture priority, their "auto"). `CAP_PROP_EXPOSURE` is V4L2_CID_EXPOSURE_ABSOLUTE, in
100 us units. The widespread "0.25 manual, 0.75 auto" comes from OpenCV's normalized
ranges, the default of OpenCV 3: values in [0, 1) scaled to the control's range (the
auto exposure menu scaled by 4, so 0.25 is 1 and 0.75 is 3). OpenCV 4 and later normalize
only with the environment variable OPENCV_VIDEOIO_V4L_RANGE_NORMALIZED=1 (or CAP_PROP_MODE
set non-zero), and there 0.75 rounds to 1, manual, and 0.25 to 0, which UVC cameras refuse.
A capture that reports normalized ranges (CAP_PROP_MODE reads non-zero) is switched to
real values at open (CAP_PROP_MODE 0), so `exposure_us` means microseconds; should that be
refused, the menu is written scaled (value / 4) and the exposure's unit is logged as unknown.

Locking (`lock_exposure`): the exposure and gain the camera's auto exposure has reached are
read (CAP_PROP_EXPOSURE, CAP_PROP_GAIN), the auto exposure switched to manual and both
written back; unlocking switches it to the auto mode it was in (aperture priority if it
was not in one). A driver with V4L2_CID_AUTOGAIN has it switched off and on with them
(`drivers.cameras.v4l2_controls`: OpenCV has no property for it, and UVC cameras no auto gain).
"""
from __future__ import annotations

import dataclasses
import fcntl
import logging
import os
import re
import stat
import struct
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np

from drivers.cameras.camera import Camera, Capabilities, Grab
from drivers.cameras.config import CameraConfig
from drivers.cameras.v4l2_controls import AUTOGAIN, V4L2Controls
from drivers.errors import CameraConfigError, CameraError, CameraLostError

log = logging.getLogger(__name__)

CaptureFactory = Callable[[Any, int], Any]  # (source, api preference) -> a VideoCapture
ControlsFactory = Callable[[str], V4L2Controls]  # device node -> its controls
_PACING_STEP_S = 0.02
_DEFAULT_FPS = 30.0


@dataclass(frozen=True)
class Source:
    """What to hand `cv2.VideoCapture`: an index or path, the API, and whether it is a file."""

    target: int | str
    api: int
    is_file: bool
    label: str


def resolve_source(device: int | str | None, name: str) -> Source:
    """A configured device (index, path or udev symlink) resolved to what OpenCV opens."""
    if device is None:
        device = 0
    if isinstance(device, int):
        return Source(device, cv2.CAP_V4L2, False, f"/dev/video{device}")
    path = os.path.realpath(device)
    try:
        mode = os.stat(path).st_mode
    except OSError as err:
        raise CameraLostError(f"{name}: device {device} does not exist ({err.strerror})") from err
    if stat.S_ISREG(mode):
        return Source(path, cv2.CAP_ANY, True, device)
    if not stat.S_ISCHR(mode):
        raise CameraConfigError(f"{name}: device {device} ({path}) is neither a video device nor a video file")
    match = re.fullmatch(r"/dev/video(\d+)", path)
    label = device if path == device else f"{device} -> {path}"
    return Source(int(match.group(1)) if match else path, cv2.CAP_V4L2, False, label)


# V4L2_CID_EXPOSURE_AUTO's menu (enum v4l2_exposure_auto_type, linux/v4l2-controls.h).
V4L2_EXPOSURE_AUTO = 0
V4L2_EXPOSURE_MANUAL = 1
V4L2_EXPOSURE_SHUTTER_PRIORITY = 2
V4L2_EXPOSURE_APERTURE_PRIORITY = 3
_AUTO_MODES = (V4L2_EXPOSURE_APERTURE_PRIORITY, V4L2_EXPOSURE_AUTO, V4L2_EXPOSURE_SHUTTER_PRIORITY)
_NORMALIZED_MENU_SCALE = 4.0  # cap_v4l.cpp's range for CAP_PROP_AUTO_EXPOSURE when normalizing
_UNREADABLE = -1.0  # what OpenCV's V4L2 backend returns for a control it cannot read


def fourcc_text(code: float) -> str:
    value = int(code)
    return "".join(chr((value >> 8 * i) & 0xFF) for i in range(4)).strip("\0") or "?"


# V4L2 ioctls for listing formats (linux/videodev2.h): _IOWR('V', nr, struct).
_VIDIOC_ENUM_FMT = 0xC0405602  # struct v4l2_fmtdesc, 64 bytes
_VIDIOC_ENUM_FRAMESIZES = 0xC02C564A  # struct v4l2_frmsizeenum, 44 bytes
_FMTDESC = struct.Struct("=III32sII3I")  # index, type, flags, description, pixelformat, mbus_code, reserved
_FRMSIZE = struct.Struct("=III6I2I")  # index, pixel_format, type, discrete/stepwise union, reserved
_BUF_TYPE_VIDEO_CAPTURE = 1
_FRMSIZE_TYPE_DISCRETE = 1
_ENUM_LIMIT = 256  # far more than any camera offers: the loops end on EINVAL long before


def v4l2_formats(path: str, ioctl: Callable[..., Any] = fcntl.ioctl) -> list[str]:
    """The capture formats a V4L2 device offers, each with its frame sizes ("MJPG: 640x480, ...").

    Asks the driver (VIDIOC_ENUM_FMT, VIDIOC_ENUM_FRAMESIZES) without starting a stream, so
    it also works while another process streams from the camera.
    """
    fd = os.open(path, os.O_RDWR | os.O_NONBLOCK)
    try:
        formats = []
        for index in range(_ENUM_LIMIT):
            desc = bytearray(_FMTDESC.pack(index, _BUF_TYPE_VIDEO_CAPTURE, 0, b"", 0, 0, 0, 0, 0))
            try:
                ioctl(fd, _VIDIOC_ENUM_FMT, desc)
            except OSError:  # EINVAL: no more formats (or not a capture node)
                break
            _, _, _, description, pixel_format, *_ = _FMTDESC.unpack(desc)
            sizes = []
            for size_index in range(_ENUM_LIMIT):
                size = bytearray(_FRMSIZE.pack(size_index, pixel_format, 0, *([0] * 8)))
                try:
                    ioctl(fd, _VIDIOC_ENUM_FRAMESIZES, size)
                except OSError:
                    break
                _, _, kind, *union, _, _ = _FRMSIZE.unpack(size)
                if kind == _FRMSIZE_TYPE_DISCRETE:
                    sizes.append(f"{union[0]}x{union[1]}")
                else:  # continuous or stepwise: one range
                    sizes.append(f"{union[0]}x{union[3]} to {union[1]}x{union[4]}")
                    break
            name = description.split(b"\0", 1)[0].decode(errors="replace")
            formats.append(f"{fourcc_text(pixel_format)} ({name}): {', '.join(sizes) or 'sizes not listed'}")
        return formats
    finally:
        os.close(fd)


def list_v4l2_devices(dev_dir: str = "/dev") -> list[dict[str, Any]]:
    """V4L2 devices with their stable names (/dev/v4l/by-id: vendor, model, serial) and formats."""
    found = []
    by_id = os.path.join(dev_dir, "v4l", "by-id")
    links: dict[str, list[str]] = {}
    if os.path.isdir(by_id):
        for entry in sorted(os.listdir(by_id)):
            links.setdefault(os.path.realpath(os.path.join(by_id, entry)), []).append(os.path.join(by_id, entry))
    for entry in sorted(os.listdir(dev_dir)) if os.path.isdir(dev_dir) else []:
        if not re.fullmatch(r"video\d+", entry):
            continue
        path = os.path.join(dev_dir, entry)
        info: dict[str, Any] = {"device": path, "links": links.get(path, []), "name": "", "formats": []}
        try:
            with open(f"/sys/class/video4linux/{entry}/name") as f:
                info["name"] = f.read().strip()
        except OSError:
            pass
        try:
            info["formats"] = v4l2_formats(path)
        except OSError as err:
            info["formats"] = [f"cannot query: {err.strerror}"]
        found.append(info)
    return found


class OpenCVCamera(Camera):
    """A V4L2 camera (or a video file) through cv2.VideoCapture; config `device`."""

    backend_name = "opencv"
    CONFIG_KEYS = frozenset({"device", "pixel_format", "width", "height", "fps", "exposure_us", "gain_db",
                             "buffers", "reconnect_backoff_max_s", "reconnect_give_up_s"})

    def __init__(self, config: CameraConfig, *, capture_factory: CaptureFactory | None = None,
                 controls_factory: ControlsFactory | None = None, **kwargs: Any) -> None:
        super().__init__(config, **kwargs)
        if config.pixel_format is not None and len(config.pixel_format) != 4:
            raise CameraConfigError(f"{self.name}: pixel_format {config.pixel_format!r}: expected a FourCC such "
                                    "as MJPG or YUYV")
        self._factory = capture_factory or cv2.VideoCapture
        self._controls_factory = controls_factory or V4L2Controls
        self._controls: V4L2Controls | None = None
        self._autogain = False  # the driver has V4L2_CID_AUTOGAIN
        self._menu_scale = 1.0  # 1 / 4 on a capture that stays normalized
        self._auto_mode = V4L2_EXPOSURE_APERTURE_PRIORITY  # the auto exposure mode unlocking restores
        self._cap: Any = None
        self._source: Source | None = None
        self._period_s = 1.0 / (config.fps or _DEFAULT_FPS)
        self._exposure_s = (config.exposure_us or 0.0) * 1e-6
        self._next_due_s = 0.0
        self._stale_dropped = 0
        # Declared per instance: a file has no exposure or gain; a device has both (and an
        # exposure lock once open shows it has an auto exposure control). Both are reopened
        # when their path vanishes and comes back.
        is_file = isinstance(config.device, str) and os.path.isfile(config.device)
        self.capabilities = Capabilities(device_timestamps=not is_file, exposure=not is_file, gain=not is_file,
                                         frame_rate=True, colour=True, reconnect=True)

    # -- hooks --------------------------------------------------------------------------------
    def _open_device(self) -> None:
        source = resolve_source(self.config.device, self.name)
        cap = self._factory(source.target, source.api)
        self._cap, self._source = cap, source
        if not cap.isOpened():
            raise CameraLostError(f"{self.name}: OpenCV cannot open {source.label}")
        if source.is_file:
            self._open_file(cap, source)
        else:
            self._configure_device(cap, source)

    def _open_file(self, cap: Any, source: Source) -> None:
        file_fps = cap.get(cv2.CAP_PROP_FPS)
        fps = self.config.fps or (file_fps if file_fps > 0 else _DEFAULT_FPS)
        self._period_s = 1.0 / fps
        width, height = int(cap.get(cv2.CAP_PROP_FRAME_WIDTH)), int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT))
        for key, wanted, actual in (("width", self.config.width, width), ("height", self.config.height, height)):
            if wanted is not None and wanted != actual:
                raise CameraConfigError(f"{self.name}: {key} {wanted} asked but the file {source.label} is "
                                        f"{actual} px")
        log.info("%s: video file %s, %d x %d, %d frames, played at %.2f fps in a loop", self.name,
                 source.label, width, height, int(cap.get(cv2.CAP_PROP_FRAME_COUNT)), fps)

    def _configure_device(self, cap: Any, source: Source) -> None:
        config = self.config
        # FourCC first: V4L2 picks the sizes and rates offered by the format.
        if config.pixel_format is not None:
            cap.set(cv2.CAP_PROP_FOURCC, cv2.VideoWriter.fourcc(*config.pixel_format))
        if config.width is not None:
            cap.set(cv2.CAP_PROP_FRAME_WIDTH, config.width)
        if config.height is not None:
            cap.set(cv2.CAP_PROP_FRAME_HEIGHT, config.height)
        if config.fps is not None:
            cap.set(cv2.CAP_PROP_FPS, config.fps)
        granted = {
            "pixel_format": fourcc_text(cap.get(cv2.CAP_PROP_FOURCC)),
            "width": int(cap.get(cv2.CAP_PROP_FRAME_WIDTH)),
            "height": int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT)),
            "fps": cap.get(cv2.CAP_PROP_FPS),
        }
        if granted["fps"] > 0:
            self._period_s = 1.0 / granted["fps"]
        log.info("%s: %s: asked %s %s x %s at %s fps; granted %s %d x %d at %.2f fps", self.name,
                 source.label, config.pixel_format, config.width, config.height, config.fps,
                 granted["pixel_format"], granted["width"], granted["height"], granted["fps"])
        for key in ("pixel_format", "width", "height"):
            wanted = getattr(config, key)
            if wanted is not None and wanted != granted[key]:
                log.warning("%s: %s %s asked, %s granted by %s", self.name, key, wanted, granted[key],
                            source.label)
        self._find_exposure_controls(cap, source)

    def _find_exposure_controls(self, cap: Any, source: Source) -> None:
        """Real units rather than OpenCV's normalized ones; whether this device can hold its
        exposure (an auto exposure control), and whether it has an automatic gain."""
        self._menu_scale = 1.0
        if cap.get(cv2.CAP_PROP_MODE) != 0:  # cap_v4l.cpp reads back its palette when normalizing
            cap.set(cv2.CAP_PROP_MODE, 0)
            if cap.get(cv2.CAP_PROP_MODE) != 0:
                self._menu_scale = 1.0 / _NORMALIZED_MENU_SCALE
                log.warning("%s: %s: OpenCV keeps normalized property ranges (OPENCV_VIDEOIO_V4L_RANGE_NORMALIZED): "
                            "exposure_us and gain_db are fractions of the controls' ranges here", self.name,
                            source.label)
            else:
                log.info("%s: %s: OpenCV's normalized property ranges switched off (CAP_PROP_MODE 0)", self.name,
                         source.label)
        node = f"/dev/video{source.target}" if isinstance(source.target, int) else source.target
        self._controls = self._controls_factory(node)
        autogain = self._controls.query(AUTOGAIN)
        self._autogain = autogain is not None and not autogain.disabled
        has_auto_exposure = cap.get(cv2.CAP_PROP_AUTO_EXPOSURE) != _UNREADABLE
        self.capabilities = dataclasses.replace(self.capabilities, exposure_lock=has_auto_exposure)
        log.info("%s: %s: auto exposure control %s, automatic gain control %s", self.name, source.label,
                 "found" if has_auto_exposure else "missing (the exposure cannot be held)",
                 "found" if self._autogain else "missing")

    def _set_auto_exposure(self, cap: Any, mode: int) -> bool:
        """Write V4L2_CID_EXPOSURE_AUTO's menu `mode` through OpenCV; False if the driver refused it."""
        return bool(cap.set(cv2.CAP_PROP_AUTO_EXPOSURE, mode * self._menu_scale))

    def _lock_exposure(self) -> None:
        cap = self._require_cap()
        mode = round(cap.get(cv2.CAP_PROP_AUTO_EXPOSURE) / self._menu_scale)
        exposure = cap.get(cv2.CAP_PROP_EXPOSURE)
        gain = cap.get(cv2.CAP_PROP_GAIN)
        if mode in _AUTO_MODES:
            self._auto_mode = mode
        if self._autogain:
            assert self._controls is not None
            self._controls.set(AUTOGAIN, 0)
        if not self._set_auto_exposure(cap, V4L2_EXPOSURE_MANUAL):
            raise CameraError(f"{self.name}: {self.config.device} refused manual exposure "
                              f"(CAP_PROP_AUTO_EXPOSURE {V4L2_EXPOSURE_MANUAL * self._menu_scale:g})")
        # Written back: the values the auto exposure had reached are held, whatever the driver
        # does with them when the mode changes.
        if exposure != _UNREADABLE:
            cap.set(cv2.CAP_PROP_EXPOSURE, exposure)
            if self._menu_scale == 1.0:
                self._exposure_s = exposure * 100e-6
        if gain != _UNREADABLE:
            cap.set(cv2.CAP_PROP_GAIN, gain)
        log.debug("%s: exposure held at %g, gain at %g (auto mode was %d)", self.name, exposure, gain, mode)

    def _unlock_exposure(self) -> None:
        cap = self._require_cap()
        # The mode it was in; else aperture priority (what UVC cameras call auto), else full auto.
        for mode in dict.fromkeys((self._auto_mode, *_AUTO_MODES)):
            if self._set_auto_exposure(cap, mode):
                break
        else:
            raise CameraError(f"{self.name}: {self.config.device} refused every auto exposure mode "
                              f"({', '.join(str(m) for m in _AUTO_MODES)})")
        if self._autogain:
            assert self._controls is not None
            self._controls.set(AUTOGAIN, 1)

    def _set_exposure_us(self, exposure_us: float) -> None:
        cap = self._require_cap()
        # V4L2 through OpenCV: manual exposure, in 100 us units (V4L2_CID_EXPOSURE_ABSOLUTE).
        self._set_auto_exposure(cap, V4L2_EXPOSURE_MANUAL)
        cap.set(cv2.CAP_PROP_EXPOSURE, exposure_us / 100.0)
        granted_us = cap.get(cv2.CAP_PROP_EXPOSURE) * 100.0
        self._exposure_s = max(exposure_us, granted_us) * 1e-6
        log.info("%s: exposure %.0f us asked, %.0f us granted", self.name, exposure_us, granted_us)

    def _set_gain_db(self, gain_db: float) -> None:
        cap = self._require_cap()
        if self._autogain:  # a driver's automatic gain would overrule (or refuse) the value
            assert self._controls is not None
            self._controls.set(AUTOGAIN, 0)
        cap.set(cv2.CAP_PROP_GAIN, gain_db)
        log.info("%s: gain %.2f asked, %.2f granted (device units)", self.name, gain_db, cap.get(cv2.CAP_PROP_GAIN))

    def _require_cap(self) -> Any:
        if self._cap is None:
            raise CameraLostError(f"{self.name}: {self.config.device} is not open")
        return self._cap

    def _start_stream(self) -> None:
        self._next_due_s = self.clock.monotonic()

    def _close_device(self) -> None:
        cap, self._cap = self._cap, None
        if cap is not None:
            cap.release()

    def _grab(self, timeout_s: float) -> Grab | None:
        cap = self._require_cap()
        source = self._source
        assert source is not None
        device = self.config.device
        # One stat a frame: an open capture (a file's descriptor above all) may go on reading
        # after its node or udev link vanished; the camera is lost all the same.
        if isinstance(device, str) and not os.path.exists(device):
            raise CameraLostError(f"{self.name}: {device} vanished (unplugged?)")
        if source.is_file:
            return self._grab_file(cap, source, timeout_s)
        return self._grab_device(cap, source)

    def _grab_file(self, cap: Any, source: Source, timeout_s: float) -> Grab | None:
        deadline_s = time.monotonic() + timeout_s
        while self.clock.monotonic() < self._next_due_s:
            if time.monotonic() >= deadline_s or self.wait_stop(0.0):
                return None
            self.clock.sleep(min(self._next_due_s - self.clock.monotonic(), _PACING_STEP_S))
        ok, image = cap.read()
        if not ok:  # the end: loop, like a camera that never stops
            cap.set(cv2.CAP_PROP_POS_FRAMES, 0)
            ok, image = cap.read()
            if not ok:
                raise CameraError(f"{self.name}: cannot read a frame from {source.label}")
        due_s = self._next_due_s
        self._next_due_s = due_s + self._period_s
        return Grab(image, due_s, due_s)

    def _grab_device(self, cap: Any, source: Source) -> Grab | None:
        queued_limit = max(self.config.buffers, 4)
        for drained in range(queued_limit + 1):
            before_s = self.clock.monotonic()
            if not cap.grab():
                raise CameraLostError(f"{self.name}: {source.label} stopped delivering frames")
            after_s = self.clock.monotonic()
            stamp_s = self._driver_time_s(cap, after_s)
            age_s = after_s - stamp_s if stamp_s is not None else None
            waited = after_s - before_s >= 0.5 * self._period_s
            fresh = age_s < self._period_s if age_s is not None else waited
            if fresh or drained == queued_limit:
                break
            self._stale_dropped += 1
        ok, image = cap.retrieve()
        if not ok or image is None:
            raise CameraError(f"{self.name}: a frame from {source.label} did not decode")
        time_s = stamp_s if stamp_s is not None else after_s
        device_ns = int(cap.get(cv2.CAP_PROP_POS_MSEC) * 1e6) or None
        return Grab(np.asarray(image), time_s, time_s - self._exposure_s - self._period_s, device_ns)

    def _driver_time_s(self, cap: Any, now_s: float) -> float | None:
        """The V4L2 buffer timestamp as monotonic seconds, if it plausibly is one.

        uvcvideo stamps buffers with CLOCK_MONOTONIC, which OpenCV reports as POS_MSEC; a
        driver stamping otherwise (or none) gives a value far from now, and is not used.
        """
        stamp_s: float = cap.get(cv2.CAP_PROP_POS_MSEC) * 1e-3
        if stamp_s > 0 and 0 <= now_s - stamp_s < 5.0:
            return stamp_s
        return None

    def _backend_stats(self) -> dict[str, int]:
        return {"stale_frames_dropped": self._stale_dropped}
