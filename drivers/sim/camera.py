"""The simulated camera: one eye of the simulated head, a first-class `Camera` backend.

Its frame times come from `drivers.sim.camera_effects.frame_timing.FrameTiming` (config `timing:`): by
default (`ideal`) frames fall on a grid of the injected clock (frame n at n / fps seconds),
so the left and right cameras of a head, sharing a clock, produce frames with identical
timestamps, like hardware-triggered stereo cameras; `free_running` gives each eye its own
phase and clock drift, jittered timestamps, lost and late frames, as two USB webcams. At
each frame the capture thread takes the joint angles from a pose source ({"pan", "tilt",
"left_eye", "right_eye"} in degrees; the service wires the simulated servos to it) and
renders this eye's view with `drivers.sim.scene`.

A frame shows the world at its true exposure start, however late it is rendered (on a
loaded machine the capture thread runs milliseconds to tens of milliseconds after it): the
moving objects are placed at that time, and so are the joints when the pose source can tell
where they were then (`TimedPoseSource`, as the service's simulated world does); a plain
callable gives the joints at the render time. The frame carries the driver's timestamp
(`time_s`, jittered), a start of exposure no later than the true one (`exposure_start_s`)
and, free-running, the camera's own clock (`device_time_ns`, frame n at n / fps on it).

Pacing: with `paced_by_clock` (default) the thread sleeps on the clock until the next frame
(real time with the system clock; a `ManualClock` then advances as fast as frames render).
Without it the thread only watches the clock, and frames appear as someone else (a test,
the simulated servo loop) advances it.

The image is a real camera's (`sensor:` config, `drivers.sim.camera_effects.sensor_config`; the default
`ideal` camera shows the render as it is): `_image_at` renders the frame over its exposure
(`drivers.sim.camera_effects.shutter`: motion blur, rolling shutter) through this unit's lens
(`drivers.sim.camera_effects.lens_error`), multiplies it by the room's light over the exposure
(`Scene.light`), and passes it through the sensor (`drivers.sim.camera_effects.sensor`: vignetting, noise,
this unit's response, MJPEG) at the exposure and gain of the auto exposure
(`drivers.sim.camera_effects.auto_exposure`), which the driver can lock, unlock or set by hand. Both the
capture thread and the synchronous `render()` make their images with it.

Unplugging (`unplug()`, `replug()`): the camera behaves as a USB camera whose device node
vanished: grabs fail as lost and every reopen fails until it is plugged back, when the base
class's reopen opens it again and applies its config afresh (`opens` counts the opens).
"""
from __future__ import annotations

import collections
import math
import logging
import time
from collections.abc import Callable, Mapping
from typing import Protocol, runtime_checkable

import numpy as np

from drivers.cameras.camera import Camera, Capabilities, ErrorCallback, Grab
from drivers.cameras.config import CameraConfig
from drivers.clock import SYSTEM_CLOCK, Clock
from drivers.errors import CameraConfigError, CameraError, CameraLostError, DeviceStateError
from drivers.sim.camera_effects.auto_exposure import AutoExposure, ExposureState
from drivers.sim.camera_effects.lens_error import unit_lens
from drivers.sim.scene import HeadGeometry, Scene, shared_scene
from drivers.sim.camera_effects.sensor import SensorPipeline, exposure_scale, mjpeg_round_trip
from drivers.sim.camera_effects.shutter import ExposureRenderer, PoseAt
from drivers.sim.camera_effects.frame_timing import FrameTiming

log = logging.getLogger(__name__)

PoseSource = Callable[[], Mapping[str, float]]  # the joint angles now
DEFAULT_FPS = 30.0
RENDER_LAGS_KEPT = 1000  # the last frames' render lags (`render_lags_s`)
_PACING_STEP_S = 0.02  # longest uninterrupted sleep, so stop() is prompt
_WATCH_STEP_S = 0.0005  # how often an unpaced camera looks at the clock


@runtime_checkable
class TimedPoseSource(Protocol):
    """A pose source that also tells where the joints were at a past time of the clock."""

    def __call__(self) -> Mapping[str, float]: ...

    def at(self, time_s: float) -> Mapping[str, float]: ...


def fixed_pose(pan: float = 0.0, tilt: float = 0.0, left_eye: float = 0.0, right_eye: float = 0.0) -> PoseSource:
    """A pose source for a head that does not move (degrees)."""
    pose = {"pan": pan, "tilt": tilt, "left_eye": left_eye, "right_eye": right_eye}
    return lambda: pose


class SimulatedCamera(Camera):
    """One eye of a simulated head (config `eye: left|right`), rendered from the pose source."""

    backend_name = "sim"
    capabilities = Capabilities(frame_rate=True, colour=True, reconnect=True, simulated=True,
                                exposure=True, gain=True, exposure_lock=True)
    CONFIG_KEYS = frozenset({"eye", "width", "height", "fps", "seed", "lens", "noise_std", "sensor",
                             "exposure_us", "gain_db", "reconnect_backoff_max_s", "reconnect_give_up_s",
                             "timing"})

    def __init__(self, config: CameraConfig, *, name: str | None = None, clock: Clock = SYSTEM_CLOCK,
                 on_error: ErrorCallback | None = None, head: HeadGeometry | None = None,
                 pose_source: PoseSource | None = None, scene: Scene | None = None,
                 paced_by_clock: bool = True) -> None:
        super().__init__(config, name=name, clock=clock, on_error=on_error)
        if head is None or pose_source is None:
            # Not config: the service passes its head model (calib_free.sim.head_model.HeadModel) and
            # the simulated servo bus's joint angles; drivers cannot build them.
            raise CameraConfigError(f"{self.name}: a simulated camera needs head= (a head model) and "
                                    "pose_source= (joint angles) from its creator, e.g. create_camera(config, "
                                    "head=HeadModel.default(...), pose_source=fixed_pose())")
        if config.eye is None:
            raise CameraConfigError(f"{self.name}: a simulated camera needs eye: left or right")
        self.eye_index = 0 if config.eye == "left" else 1
        lens = head.lens_left if self.eye_index == 0 else head.lens_right
        for key, wanted, actual in (("width", config.width, lens.width), ("height", config.height, lens.height)):
            if wanted is not None and wanted != actual:
                raise CameraConfigError(f"{self.name}: {key} {wanted} differs from the head model's lens ({actual} px)")
        if scene is not None and scene.colour != (config.image == "colour"):
            raise CameraConfigError(f"{self.name}: the scene given is {'colour' if scene.colour else 'grey'} "
                                    f"but image is {config.image!r}")
        self.head = head
        self.lens = lens  # the nominal lens: the method's model
        self.sensor = config.sensor.params()
        self.unit_lens = unit_lens(lens, self.sensor, config.seed, self.eye_index)  # the lens it renders through
        self.pose_source = pose_source
        self.fps = config.fps or DEFAULT_FPS
        self.timing = FrameTiming(config.timing, self.fps, seed=config.seed, eye_index=self.eye_index)
        self.paced_by_clock = paced_by_clock
        self._scene = scene
        self._shutter: ExposureRenderer | None = None
        self._pipeline: SensorPipeline | None = None
        self._exposure = AutoExposure(self.sensor, self.fps)
        self._last_index: int | None = None
        # (frame time, render start, image ready) of the last frames, clock seconds.
        self._render_times: collections.deque[tuple[float, float, float]] = collections.deque(
            maxlen=RENDER_LAGS_KEPT)
        self._unplugged = False
        self.opens = 0  # times the device was opened (and its config applied)

    # -- the unplug fault ---------------------------------------------------------------------
    @property
    def unplugged(self) -> bool:
        return self._unplugged

    def unplug(self) -> None:
        """The device node vanishes: grabs fail as lost, reopens fail, until `replug()`."""
        self._unplugged = True
        log.warning("%s: simulated camera unplugged", self.name)

    def replug(self) -> None:
        """The device node is back: the next reopen attempt opens it and applies its config."""
        self._unplugged = False
        log.warning("%s: simulated camera plugged back", self.name)

    def _pose_at(self) -> PoseAt:
        """The joints at a time of the clock from the pose source (a plain one: as they are now)."""
        source = self.pose_source

        def failed(err: Exception) -> CameraError:
            return CameraError(f"{self.name}: the pose source failed: {err!r}")

        if not isinstance(source, TimedPoseSource):
            try:
                joints = source()
            except Exception as err:
                raise failed(err) from err
            return lambda time_s: joints

        def pose_at(time_s: float) -> Mapping[str, float]:
            try:
                return source.at(time_s)
            except Exception as err:
                raise failed(err) from err
        return pose_at

    def _device_gone(self, what: str) -> CameraLostError:
        return CameraLostError(f"{self.name}: {what}: the simulated {self.config.eye} eye's device node is gone "
                               "(unplugged)")

    def render_lags_s(self) -> list[tuple[float, float, float]]:
        """The last frames' (timestamp, lag of the render's start, lag of the image ready),
        seconds after the timestamp: how late the capture thread rendered (what the frame
        shows does not depend on it)."""
        return [(t, start - t, ready - t) for t, start, ready in list(self._render_times)]

    @property
    def exposure_state(self) -> ExposureState:
        """The exposure time, gain and mode of the next frame's exposure."""
        return self._exposure.state

    # -- synchronous use ----------------------------------------------------------------------
    def render(self, joints: Mapping[str, float], time_s: float | None = None) -> np.ndarray:
        """This eye's image at the given joint angles (degrees), its exposure starting at
        `time_s` (None: now; the moving objects where they are then), without the thread.

        A frame of the camera's frame index at that time: its auto exposure runs as if it had
        streamed since the last one. While the head moves (a `TimedPoseSource` tells how), the
        exposure sees it move from `joints` on as the pose source does (blur, skew)."""
        self.require_open()
        start_s = self.clock.monotonic() if time_s is None else time_s
        source = self.pose_source
        pose_at: PoseAt = lambda t: joints  # noqa: E731
        if self.sensor.exposure_moves and isinstance(source, TimedPoseSource):
            then = source.at(start_s)
            pose_at = lambda t: {k: float(joints[k]) + float(v) - float(then[k])  # noqa: E731
                                 for k, v in source.at(t).items()}
        return self._image_at(math.floor(start_s * self.fps), start_s, pose_at, legacy_noise=False)

    def _image_at(self, index: int, exposure_start_s: float, pose_at: PoseAt, legacy_noise: bool = True) -> np.ndarray:
        """Frame `index`, its first row exposed from `exposure_start_s`, the joints at each time
        `pose_at` gives: rendered over the exposure, lit by the room, through the sensor.
        `legacy_noise`: `noise_std` added (the synchronous renders' user adds its own)."""
        shutter, pipeline = self._shutter, self._pipeline
        if shutter is None or pipeline is None:
            raise DeviceStateError(f"{self.name}: rendering on a closed camera")
        settings, skipped = self._exposure.settings_for(index)
        radiance = shutter.render(pose_at, exposure_start_s, settings.exposure_us * 1e-6)

        def scale() -> float | np.ndarray:  # the room's light over this exposure, relative to the reference
            light = shutter.light_over(shutter.scene.light, exposure_start_s, settings.exposure_us * 1e-6)
            return exposure_scale(light, settings.exposure_us, self.sensor.reference_exposure_us)

        if skipped and self.sensor.auto_exposure:  # frames not rendered: their auto exposure saw this view
            settings = self._exposure.catch_up(pipeline.meter(radiance, scale(), settings.gain), skipped)
        image, level = pipeline.expose(radiance, scale(), settings.gain, index, measure=self.sensor.auto_exposure)
        if level is not None:
            self._exposure.observe(index, level)
        if legacy_noise and self.config.noise_std > 0:
            # Sensor noise, deterministic per (seed, eye, frame).
            rng = np.random.default_rng((self.config.seed, self.eye_index, index))
            noisy = image.astype(np.float32) + rng.normal(0.0, self.config.noise_std, image.shape)
            image = np.clip(noisy, 0, 255).astype(np.uint8)
        if self.sensor.jpeg_quality is not None:
            image = mjpeg_round_trip(image, self.sensor.jpeg_quality)
        return image

    # -- hooks --------------------------------------------------------------------------------
    def _open_device(self) -> None:
        if self._unplugged:
            raise self._device_gone("cannot open")
        self.opens += 1
        scene = self._scene or shared_scene(self.config.seed, self.config.image == "colour")
        self._shutter = ExposureRenderer(self.unit_lens, scene, self.head, self.eye_index, self.sensor)
        self._pipeline = SensorPipeline(self.sensor, self.unit_lens, self.lens, self.config.seed, self.eye_index)
        self._exposure = AutoExposure(self.sensor, self.fps)  # a camera opened afresh starts its auto exposure again
        log.info("%s: simulated %s eye, %d x %d px at %.1f fps, seed %d, %s", self.name, self.config.eye,
                 self.lens.width, self.lens.height, self.fps, self.config.seed, self.timing.describe())

    def _close_device(self) -> None:
        self._shutter = self._pipeline = None

    def _lock_exposure(self) -> None:
        self._exposure.lock()

    def _unlock_exposure(self) -> None:
        self._exposure.unlock()

    def _set_exposure_us(self, exposure_us: float) -> None:
        self._exposure.set_exposure_us(exposure_us)

    def _set_gain_db(self, gain_db: float) -> None:
        self._exposure.set_gain_db(gain_db)

    def _start_stream(self) -> None:
        self._last_index = None

    def _grab(self, timeout_s: float) -> Grab | None:
        if self._unplugged:
            raise self._device_gone("no frame")
        if self._shutter is None:  # closed by a reopen that failed: the base class reopens it
            raise CameraLostError(f"{self.name}: not open (its last reopen failed)")
        deadline_s = time.monotonic() + timeout_s
        while True:
            now_s = self.clock.monotonic()
            # The newest frame arrived by now (`FrameTiming`): its exposure began no later
            # than the clock, so where the world was then is known when it renders.
            slot, wake_s = self.timing.due(self._last_index, now_s)
            if slot is not None:
                break
            if time.monotonic() >= deadline_s:
                return None
            if self.paced_by_clock:
                self.clock.sleep(min(wake_s - now_s + 1e-9, _PACING_STEP_S))
                if self.wait_stop(0.0):
                    return None
            elif self.wait_stop(_WATCH_STEP_S):
                return None
        index = self._last_index = slot.index
        frame_time_s = slot.exposure_start_s  # what the frame shows: the world at its true exposure
        started_s = self.clock.monotonic()
        image = self._image_at(index, frame_time_s, self._pose_at())
        self._render_times.append((frame_time_s, started_s, self.clock.monotonic()))
        # The driver's (jittered) timestamp, a start of exposure no later than the true one,
        # and the camera's own clock at that start.
        return Grab(image, slot.timestamp_s, slot.timestamp_s - self.timing.max_stamp_lag_s,
                    self.timing.device_time_ns(index))
