"""GenICam cameras (GigE Vision, USB3 Vision) through Aravis 0.8 and PyGObject.

This module owns the Aravis side of a camera: finding the device by id or serial in
Aravis's process-wide device list, the stream and its buffer pool, converting Mono8, Bayer
and RGB8 buffers to numpy images with OpenCV, mapping Aravis's timestamps to the host
monotonic clock, and noticing a lost camera (the device's `control-lost` signal) so the
base class reopens it with backoff.

Timestamps: `get_system_timestamp()` is the host's wall-clock time (ns) when the buffer
arrived; it is mapped to `time.monotonic()` with the wall-minus-monotonic offset read at
pop time (so a wall-clock step moves nothing). `get_timestamp()` is the camera's own clock
and is kept apart as `device_time_ns`. A real camera lives in real time, so this backend
always uses the system monotonic clock, whatever clock it is given.

Exposure lock: the SFNC features ExposureAuto and GainAuto (Off / Once / Continuous), where
the camera has them (checked at open; Aravis's own Fake camera has GainAuto only). Locking
reads ExposureTime and Gain, switches the automatic ones Off and writes the values back, so
the camera holds what its automatic loop had reached; unlocking sets them Continuous. A
camera with neither cannot hold its exposure (it has no automatic one to hold: set it with
`exposure_us`).

Aravis's Fake interface (device id `Fake_1`) is enabled when a config names a `Fake_` id,
or by `enable_fake_interface()`.
"""
from __future__ import annotations

import dataclasses
import logging
import threading
import time
from dataclasses import dataclass
from typing import Any

import cv2
import gi
import numpy as np

gi.require_version("Aravis", "0.8")
from gi.repository import Aravis, GLib  # noqa: E402  (after require_version, as PyGObject requires)

from drivers.cameras.camera import Camera, Capabilities, Grab  # noqa: E402
from drivers.cameras.config import CameraConfig  # noqa: E402
from drivers.errors import CameraConfigError, CameraError, CameraLostError  # noqa: E402

log = logging.getLogger(__name__)

# Aravis's device list is process-global: one caller at a time updates and reads it.
_SYSTEM_LOCK = threading.Lock()
_list_updated = False
_fake_enabled = False
_POP_STEP_S = 0.1  # longest single wait in the stream, so a lost camera or stop() is noticed

# GenICam Bayer names give the first row's colours; OpenCV names the pattern from the second
# pixel of the second row, hence the shift (GenICam RG8 is OpenCV's BG).
_CONVERSIONS: dict[int, tuple[str, int | None, int]] = {
    Aravis.PIXEL_FORMAT_MONO_8: ("Mono8", None, 1),
    Aravis.PIXEL_FORMAT_RGB_8_PACKED: ("RGB8", cv2.COLOR_RGB2BGR, 3),
    Aravis.PIXEL_FORMAT_BAYER_RG_8: ("BayerRG8", cv2.COLOR_BayerBG2BGR, 1),
    Aravis.PIXEL_FORMAT_BAYER_BG_8: ("BayerBG8", cv2.COLOR_BayerRG2BGR, 1),
    Aravis.PIXEL_FORMAT_BAYER_GR_8: ("BayerGR8", cv2.COLOR_BayerGB2BGR, 1),
    Aravis.PIXEL_FORMAT_BAYER_GB_8: ("BayerGB8", cv2.COLOR_BayerGR2BGR, 1),
}
SUPPORTED_PIXEL_FORMATS = tuple(name for name, _, _ in _CONVERSIONS.values())
_STREAM_COUNTERS = ("n_completed_buffers", "n_failures", "n_underruns", "n_timeouts", "n_missing_frames")


@dataclass(frozen=True)
class AravisDeviceInfo:
    id: str
    serial: str
    vendor: str
    model: str
    protocol: str
    address: str
    pixel_formats: tuple[str, ...] = ()


def enable_fake_interface() -> None:
    """Expose Aravis's in-process Fake camera (`Fake_1`)."""
    global _list_updated, _fake_enabled
    with _SYSTEM_LOCK:
        if not _fake_enabled:
            Aravis.enable_interface("Fake")
            _fake_enabled = True
            _list_updated = False  # the next lookup updates the list, and finds Fake_1


def _devices(refresh: bool) -> list[AravisDeviceInfo]:
    """The devices Aravis knows, updating its list (about 1 s of GigE discovery) if asked."""
    global _list_updated
    with _SYSTEM_LOCK:
        if refresh or not _list_updated:
            Aravis.update_device_list()
            _list_updated = True
        return [
            AravisDeviceInfo(Aravis.get_device_id(i) or "", Aravis.get_device_serial_nbr(i) or "",
                             Aravis.get_device_vendor(i) or "", Aravis.get_device_model(i) or "",
                             Aravis.get_device_protocol(i) or "", Aravis.get_device_address(i) or "")
            for i in range(Aravis.get_n_devices())
        ]


def list_devices(with_formats: bool = True) -> list[AravisDeviceInfo]:
    """Every GenICam camera visible now, with its pixel formats (opening each briefly)."""
    found = []
    for info in _devices(refresh=True):
        formats: tuple[str, ...] = ()
        if with_formats:
            try:
                formats = tuple(Aravis.Camera.new(info.id).dup_available_pixel_formats_as_strings())
            except GLib.Error as err:
                log.warning("aravis device %s: cannot read its pixel formats: %s", info.id, err.message)
        found.append(AravisDeviceInfo(**{**info.__dict__, "pixel_formats": formats}))
    return found


def _stream_counters(stream: "Aravis.Stream") -> dict[str, int]:
    """The stream's counters of `_STREAM_COUNTERS` that this kind of stream keeps (a Fake
    stream keeps fewer than a GigE Vision one; asking for a missing one makes Aravis complain)."""
    kept = {stream.get_info_name(i) for i in range(stream.get_n_infos())}
    return {name: stream.get_info_uint64_by_name(name) for name in _STREAM_COUNTERS if name in kept}


class AravisCamera(Camera):
    """A GenICam camera through Aravis: config `id` or `serial` (or neither: the first found)."""

    backend_name = "aravis"
    capabilities = Capabilities(device_timestamps=True, exposure=True, gain=True, frame_rate=True,
                                colour=True, reconnect=True)
    CONFIG_KEYS = frozenset({"id", "serial", "pixel_format", "width", "height", "fps", "exposure_us",
                             "gain_db", "buffers", "reconnect_backoff_max_s", "reconnect_give_up_s"})

    def __init__(self, config: CameraConfig, **kwargs: Any) -> None:
        super().__init__(config, **kwargs)
        if config.pixel_format is not None and config.pixel_format not in SUPPORTED_PIXEL_FORMATS:
            raise CameraConfigError(f"{self.name}: pixel_format {config.pixel_format!r}: expected one of "
                                    f"{', '.join(SUPPORTED_PIXEL_FORMATS)}")
        self._camera: Aravis.Camera | None = None
        self._stream: Aravis.Stream | None = None
        self._lost = threading.Event()
        self._lost_handler: int | None = None
        self._device_id: str | None = None
        self._period_s = 0.0
        self._exposure_s = 0.0
        self._exposure_auto = False  # the camera has ExposureAuto
        self._gain_auto = False  # the camera has GainAuto
        self._totals = dict.fromkeys(_STREAM_COUNTERS, 0)  # over all streams since open()
        self._incomplete = 0

    @property
    def device_id(self) -> str | None:
        """The Aravis device id opened (resolved from the serial, if that was configured)."""
        return self._device_id

    # -- hooks --------------------------------------------------------------------------------
    def _open_device(self) -> None:
        wanted = self.config.id
        if wanted is not None and wanted.startswith("Fake_"):
            enable_fake_interface()
        device_id = self._find(refresh=self._device_id is not None)
        try:
            camera = Aravis.Camera.new(device_id)
        except GLib.Error as err:
            raise CameraLostError(f"{self.name}: cannot open aravis device {device_id}: {err.message}") from err
        self._camera, self._device_id = camera, device_id
        self._lost.clear()
        # control-lost is emitted on Aravis's heartbeat thread: only set a flag there.
        self._lost_handler = camera.get_device().connect("control-lost", lambda device: self._lost.set())
        try:
            if camera.is_uv_device():
                # Asynchronous USB transfers sustain higher rates on USB3 Vision cameras.
                camera.uv_set_usb_mode(Aravis.UvUsbMode.ASYNC)
            self._configure(camera)
        except GLib.Error as err:
            raise CameraError(f"{self.name}: configuring aravis device {device_id} failed: {err.message}") from err

    def _find(self, refresh: bool) -> str:
        config = self.config
        for attempt_refresh in ((True,) if refresh else (False, True)):
            devices = _devices(refresh=attempt_refresh)
            for info in devices:
                if (config.id is None and config.serial is None) or info.id == config.id or (
                        config.serial is not None and info.serial == config.serial):
                    return info.id
        what = f"id {config.id!r}" if config.id else f"serial {config.serial!r}" if config.serial else "any camera"
        seen = ", ".join(f"{d.id} (serial {d.serial})" for d in devices) or "none"
        raise CameraLostError(f"{self.name}: no aravis device with {what}; devices seen: {seen}")

    def _configure(self, camera: "Aravis.Camera") -> None:
        config = self.config
        if config.pixel_format is not None:
            available = list(camera.dup_available_pixel_formats_as_strings())
            if config.pixel_format not in available:
                raise CameraConfigError(f"{self.name}: pixel_format {config.pixel_format!r} not offered by "
                                        f"{self._device_id}: it offers {', '.join(available)}")
            camera.set_pixel_format_from_string(config.pixel_format)
        if config.width is not None or config.height is not None:
            _, _, width, height = camera.get_region()
            camera.set_region(0, 0, config.width or width, config.height or height)
        rate_control = camera.is_frame_rate_available()
        if config.fps is not None:
            if rate_control:
                camera.set_frame_rate(config.fps)
            else:  # free-running or triggered cameras: the rate is the camera's, not ours
                log.warning("%s: %s has no frame rate control; fps %s ignored", self.name, self._device_id, config.fps)
        x, y, width, height = camera.get_region()
        fps = camera.get_frame_rate() if rate_control else 0.0
        self._period_s = 1.0 / fps if fps > 0 else 0.0
        self._exposure_s = camera.get_exposure_time() * 1e-6 if camera.is_exposure_time_available() else 0.0
        self._exposure_auto = camera.is_exposure_auto_available()
        self._gain_auto = camera.is_gain_auto_available()
        self.capabilities = dataclasses.replace(type(self).capabilities,
                                                exposure_lock=self._exposure_auto or self._gain_auto)
        log.info("%s: aravis %s (%s %s): %s %d x %d at (%d, %d), %.2f fps (asked %s x %s, %s fps, %s)",
                 self.name, self._device_id, camera.get_vendor_name(), camera.get_model_name(),
                 camera.get_pixel_format_as_string(), width, height, x, y, fps,
                 config.width, config.height, config.fps, config.pixel_format)
        for key, wanted, granted in (("width", config.width, width), ("height", config.height, height)):
            if wanted is not None and wanted != granted:
                log.warning("%s: %s %d asked, %d granted", self.name, key, wanted, granted)

    def _set_exposure_us(self, exposure_us: float) -> None:
        camera = self._require_camera()
        try:
            if self._exposure_auto:  # a camera's own loop overrules (or refuses) the value
                camera.set_exposure_time_auto(Aravis.Auto.OFF)
            camera.set_exposure_time(exposure_us)
            self._exposure_s = camera.get_exposure_time() * 1e-6
        except GLib.Error as err:
            raise CameraConfigError(f"{self.name}: exposure {exposure_us} us refused: {err.message}") from err
        log.info("%s: exposure %.0f us asked, %.0f us granted", self.name, exposure_us, self._exposure_s * 1e6)

    def _set_gain_db(self, gain_db: float) -> None:
        camera = self._require_camera()
        try:
            if self._gain_auto:
                camera.set_gain_auto(Aravis.Auto.OFF)
            camera.set_gain(gain_db)
            granted = camera.get_gain()
        except GLib.Error as err:
            raise CameraConfigError(f"{self.name}: gain {gain_db} refused: {err.message}") from err
        log.info("%s: gain %.2f asked, %.2f granted", self.name, gain_db, granted)

    def _lock_exposure(self) -> None:
        camera = self._require_camera()
        try:
            if self._exposure_auto:
                exposure_us = camera.get_exposure_time()
                camera.set_exposure_time_auto(Aravis.Auto.OFF)
                camera.set_exposure_time(exposure_us)  # held where the automatic loop had it
                self._exposure_s = camera.get_exposure_time() * 1e-6
            if self._gain_auto:
                gain = camera.get_gain()
                camera.set_gain_auto(Aravis.Auto.OFF)
                camera.set_gain(gain)
        except GLib.Error as err:
            raise CameraError(f"{self.name}: holding the exposure of {self._device_id} failed: {err.message}") from err
        log.debug("%s: exposure and gain held (ExposureAuto %s, GainAuto %s)", self.name,
                  "Off" if self._exposure_auto else "absent", "Off" if self._gain_auto else "absent")

    def _unlock_exposure(self) -> None:
        camera = self._require_camera()
        try:
            if self._exposure_auto:
                camera.set_exposure_time_auto(Aravis.Auto.CONTINUOUS)
            if self._gain_auto:
                camera.set_gain_auto(Aravis.Auto.CONTINUOUS)
        except GLib.Error as err:
            raise CameraError(f"{self.name}: letting the exposure of {self._device_id} run again failed: "
                              f"{err.message}") from err

    def _require_camera(self) -> "Aravis.Camera":
        if self._camera is None:
            raise CameraLostError(f"{self.name}: aravis device {self._device_id} is not open")
        return self._camera

    def _start_stream(self) -> None:
        camera = self._require_camera()
        try:
            stream = camera.create_stream(None, None)
            payload = camera.get_payload()
            for _ in range(self.config.buffers):
                stream.push_buffer(Aravis.Buffer.new_allocate(payload))
            self._stream = stream
            camera.start_acquisition()
        except GLib.Error as err:
            raise CameraLostError(f"{self.name}: starting the stream of {self._device_id} failed: {err.message}") from err

    def _stop_stream(self) -> None:
        stream, self._stream = self._stream, None
        if stream is not None:
            self._add_totals(stream)
        if self._camera is not None and not self._lost.is_set():
            try:
                self._camera.stop_acquisition()
            except GLib.Error as err:
                log.info("%s: stopping acquisition on %s: %s", self.name, self._device_id, err.message)

    def _close_device(self) -> None:
        camera, self._camera = self._camera, None
        if camera is not None and self._lost_handler is not None:
            camera.get_device().disconnect(self._lost_handler)
        self._lost_handler = None

    def _grab(self, timeout_s: float) -> Grab | None:
        deadline_s = time.monotonic() + timeout_s
        while True:
            if self._lost.is_set():
                raise CameraLostError(f"{self.name}: control of aravis device {self._device_id} lost")
            stream = self._stream
            if stream is None:
                raise CameraLostError(f"{self.name}: no stream on {self._device_id}")
            step_s = min(_POP_STEP_S, deadline_s - time.monotonic())
            if step_s <= 0:
                return None
            buffer = stream.timeout_pop_buffer(int(step_s * 1e6))
            if buffer is not None:
                break
        # Read the clocks' offset now: the mapping survives a wall-clock step between frames.
        wall_minus_mono_ns = time.time_ns() - time.monotonic_ns()
        try:
            status = buffer.get_status()
            if status != Aravis.BufferStatus.SUCCESS:
                self._incomplete += 1
                log.debug("%s: buffer %s from %s", self.name, status.value_nick, self._device_id)
                return None
            image = self._decode(buffer)
            arrival_s = min((buffer.get_system_timestamp() - wall_minus_mono_ns) * 1e-9, time.monotonic())
            device_ns = buffer.get_timestamp() or None
        finally:
            stream.push_buffer(buffer)
        # The exposure began at least an exposure time and one frame transfer before arrival.
        return Grab(image, arrival_s, arrival_s - self._exposure_s - self._period_s, device_ns)

    def _decode(self, buffer: "Aravis.Buffer") -> np.ndarray:
        pixel_format = buffer.get_image_pixel_format()
        try:
            name, code, channels = _CONVERSIONS[pixel_format]
        except KeyError as err:
            raise CameraError(f"{self.name}: pixel format 0x{pixel_format:08x} from {self._device_id} is not "
                              f"supported: use one of {', '.join(SUPPORTED_PIXEL_FORMATS)}") from err
        width, height = buffer.get_image_width(), buffer.get_image_height()
        data = np.frombuffer(buffer.get_data(), np.uint8)
        if data.size < width * height * channels:
            raise CameraError(f"{self.name}: {name} buffer of {data.size} bytes for {width} x {height} px")
        raw = data[:width * height * channels].reshape((height, width, channels) if channels == 3 else (height, width))
        if code is None:
            return raw.copy()
        return cv2.cvtColor(raw, code)

    def _add_totals(self, stream: "Aravis.Stream") -> None:
        for name, value in _stream_counters(stream).items():
            self._totals[name] += value

    def _backend_stats(self) -> dict[str, int]:
        """Aravis stream counters summed over every stream since open (lost frames, underruns)."""
        totals = dict(self._totals)
        stream = self._stream
        if stream is not None:
            for name, value in _stream_counters(stream).items():
                totals[name] += value
        return {"aravis_" + name.removeprefix("n_"): value for name, value in totals.items()} | {
            "incomplete_buffers": self._incomplete}
