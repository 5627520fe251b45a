"""The camera interface: frames, the capture thread, construction.

This module owns what every camera backend shares, once (a camera's typed settings,
`CameraConfig`, are in `drivers.cameras.config`):
  - `Frame`: an image (grey (H, W) or BGR (H, W, 3) uint8, OpenCV's channel order) with its
    frame counter, host monotonic timestamps and the device timestamp where there is one;
  - `Camera(Device)`: the lifecycle plus a named capture thread per camera that holds the
    latest frame (and a short history) in a latest-value slot, reports errors to a callback
    and to `health`/`last_error`, and reopens a lost camera with bounded backoff. Backends
    implement only the small hooks `_open_device`, `_close_device`, `_start_stream`,
    `_stop_stream`, `_grab` and, when they declare the capability, `_set_exposure_us`,
    `_set_gain_db` and `_lock_exposure` / `_unlock_exposure`;
  - exposure control (`ExposureMode`): auto, locked (the camera's auto exposure and gain held
    at their present values, `lock_exposure` until `unlock_exposure`: what the service does
    around a fixation with `exposure_control: lock_per_fixation`, so the images before and
    after a saccade share one exposure), or manual (`exposure_us`, `set_exposure_us`);
  - `create_camera`: config -> backend class (`drivers.backends`) -> camera.

Stereo pairs of two cameras: `drivers.cameras.stereo`.

Times: `clock.monotonic()` seconds for everything the service compares (`time_s`,
`exposure_start_s`); device clocks only in `device_time_ns`, never mixed with host time.
"""
from __future__ import annotations

import collections
import enum
import logging
import threading
import time
import traceback
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, ClassVar, TypeVar

import numpy as np

from drivers import backends
from drivers.base import Device
from drivers.clock import SYSTEM_CLOCK, Clock
from drivers.cameras.config import CameraConfig, ImageMode
from drivers.errors import (
    CameraConfigError,
    CameraError,
    CameraLostError,
    CameraTimeoutError,
    DeviceStateError,
)

log = logging.getLogger(__name__)

T = TypeVar("T")

ErrorCallback = Callable[["Camera", BaseException], None]
# Called on the capture thread with each new frame, and with None when the health changes.
Listener = Callable[["Frame | None"], None]


# --- frames ------------------------------------------------------------------------------
@dataclass(frozen=True)
class Frame:
    """One image and when it was taken.

    `time_s`: host monotonic time of the frame (its arrival for real cameras, its exposure
    for simulated ones). `exposure_start_s`: a time no later than the true start of the
    exposure (the backend's conservative estimate): what "taken after t" is judged on.
    `device_time_ns`: the camera's own clock, where it has one.
    """

    camera: str
    counter: int
    image: np.ndarray
    time_s: float
    exposure_start_s: float
    device_time_ns: int | None = None

    @property
    def is_colour(self) -> bool:
        return self.image.ndim == 3


@dataclass(frozen=True)
class Grab:
    """What a backend's `_grab` hook returns: an image and its timestamps."""

    image: np.ndarray
    time_s: float
    exposure_start_s: float
    device_time_ns: int | None = None


@dataclass(frozen=True)
class Capabilities:
    """What a camera can do, declared rather than discovered by exceptions."""

    device_timestamps: bool = False
    exposure: bool = False
    gain: bool = False
    frame_rate: bool = False
    colour: bool = True
    reconnect: bool = False
    simulated: bool = False
    exposure_lock: bool = False  # can hold its auto exposure and gain, and let them run again


class ExposureMode(enum.Enum):
    """Who sets the exposure: the camera's own loop (auto), nobody while held (locked: at the
    values the loop had reached), or the config or a caller (manual)."""

    AUTO = "auto"
    LOCKED = "locked"
    MANUAL = "manual"


class StreamHealth(enum.Enum):
    STOPPED = "stopped"
    STREAMING = "streaming"
    RECONNECTING = "reconnecting"
    FAILED = "failed"


def to_mode(image: np.ndarray, mode: ImageMode, camera: str) -> np.ndarray:
    """`image` (grey or BGR uint8) as the requested mode; conversions through OpenCV."""
    import cv2  # OpenCV is a core dependency; imported here to keep this module light

    if mode == "grey":
        return image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
    if image.ndim == 3:
        return image
    if mode == "colour":
        return cv2.cvtColor(image, cv2.COLOR_GRAY2BGR)
    raise CameraConfigError(f"{camera}: unknown image mode {mode!r}: expected 'grey' or 'colour'")


# --- the capture thread ------------------------------------------------------------------
def wait_for(cond: threading.Condition, find: Callable[[], T | None], check: Callable[[], None],
             timeout_s: float, timeout_message: Callable[[], str]) -> T:
    """Wait on `cond` (held by the caller) until `find()` gives something; `check()` raises
    when waiting is pointless (a failed stream); `CameraTimeoutError` after `timeout_s`."""
    deadline = time.monotonic() + timeout_s
    while True:
        found = find()
        if found is not None:
            return found
        check()
        remaining = deadline - time.monotonic()
        if remaining <= 0:
            raise CameraTimeoutError(timeout_message())
        cond.wait(remaining)


class CaptureThread(threading.Thread):
    """The named thread that owns a camera's streaming: grabs until its stop event is set."""

    def __init__(self, camera: "Camera") -> None:
        super().__init__(name=f"camera-{camera.name}", daemon=True)
        self.camera = camera
        self.stop_event = threading.Event()

    def run(self) -> None:
        self.camera._capture_loop(self.stop_event)

    def stop(self, timeout_s: float = 5.0) -> None:
        self.stop_event.set()
        if self.is_alive() and threading.current_thread() is not self:
            self.join(timeout_s)
            if self.is_alive():
                raise CameraTimeoutError(f"{self.camera.name}: capture thread did not stop within {timeout_s} s")


# --- the interface -----------------------------------------------------------------------
class Camera(Device):
    """A camera with a capture thread holding the latest frame.

    open() opens the device and applies the config; enable() starts streaming and the
    capture thread; latest()/wait_frame() read the latest-value slot; close() stops all.
    """

    backend_name: ClassVar[str] = ""
    capabilities: Capabilities = Capabilities()
    # Config keys this backend uses beyond the common ones; others set in a config are refused.
    CONFIG_KEYS: ClassVar[frozenset[str]] = frozenset()

    def __init__(self, config: CameraConfig, *, name: str | None = None, clock: Clock = SYSTEM_CLOCK,
                 on_error: ErrorCallback | None = None) -> None:
        identity = next((v for v in (config.eye, config.device, config.id, config.serial) if v is not None),
                        config.backend)
        super().__init__(name or str(identity))
        self.config = config
        self.clock = clock
        self.on_error = on_error
        self._cond = threading.Condition()
        self._latest: Frame | None = None
        self._history: collections.deque[Frame] = collections.deque(maxlen=config.history)
        self._counter = 0
        self._health = StreamHealth.STOPPED
        self._last_error: BaseException | None = None
        self._error_count = 0
        self._reconnect_count = 0
        self._listeners: list[Listener] = []
        self._thread: CaptureThread | None = None
        self._stop_event: threading.Event | None = None  # the running capture thread's
        self._last_message = ""
        self._repeats = 0
        self._exposure_mode = ExposureMode.AUTO
        # Lock, unlock, manual settings and a reopen's fresh config, one at a time (the
        # fixation thread locks while the capture thread may be reopening the device).
        self._exposure_guard = threading.Lock()

    # -- state seen from outside ---------------------------------------------------------
    @property
    def health(self) -> StreamHealth:
        return self._health

    @property
    def last_error(self) -> BaseException | None:
        return self._last_error

    @property
    def frame_count(self) -> int:
        return self._counter

    def stats(self) -> dict[str, int]:
        """Counters: frames delivered, errors, reconnections, plus the backend's own."""
        return {"frames": self._counter, "errors": self._error_count,
                "reconnects": self._reconnect_count, **self._backend_stats()}

    def latest(self) -> Frame | None:
        """The newest frame, or None before the first one."""
        with self._cond:
            return self._latest

    def history(self) -> list[Frame]:
        """The last `config.history` frames, oldest first."""
        with self._cond:
            return list(self._history)

    def wait_frame(self, after_s: float | None = None, timeout_s: float = 2.0) -> Frame:
        """The newest frame whose exposure began at or after `after_s` (monotonic seconds).

        With `after_s` None: the first frame newer than the one held at the call. Raises
        `CameraTimeoutError` after `timeout_s` (real seconds), or the stream's error at once
        when it has failed.
        """
        with self._cond:
            baseline = self._counter

            def find() -> Frame | None:
                frame = self._latest
                if frame is None:
                    return None
                newer = frame.exposure_start_s >= after_s if after_s is not None else frame.counter > baseline
                return frame if newer else None

            def timeout_message() -> str:
                what = f"frame exposed after t={after_s:.6f} s" if after_s is not None else "new frame"
                return (f"{self.name}: no {what} within {timeout_s} s (health {self._health.value}, "
                        f"{self._counter} frames so far)")

            return wait_for(self._cond, find, self.raise_if_failed, timeout_s, timeout_message)

    def add_listener(self, listener: Listener) -> None:
        """Call `listener(frame)` on the capture thread after each frame (None when the health
        changes, so waiters re-check); keep it short."""
        with self._cond:
            self._listeners.append(listener)

    def remove_listener(self, listener: Listener) -> None:
        with self._cond:
            if listener in self._listeners:
                self._listeners.remove(listener)

    # -- settings (template methods over the hooks) --------------------------------------
    @property
    def exposure_mode(self) -> ExposureMode:
        return self._exposure_mode

    def lock_exposure(self) -> None:
        """Hold the auto exposure and gain at their present values until `unlock_exposure`.

        Nothing to do when the exposure is manual (fixed already) or locked already. A camera
        without the capability refuses (`CameraConfigError` naming it)."""
        self.require_open()
        if not self.capabilities.exposure_lock:
            raise CameraConfigError(f"{self.name}: the {self.backend_name} backend cannot hold its exposure "
                                    "(no exposure lock)")
        with self._exposure_guard:
            if self._exposure_mode is ExposureMode.AUTO:
                self._lock_exposure()
                self._exposure_mode = ExposureMode.LOCKED

    def unlock_exposure(self) -> None:
        """Let the auto exposure and gain run again after `lock_exposure`; nothing to do when
        they are not locked (manual, or the device reopened since, which applies the config)."""
        self.require_open()
        with self._exposure_guard:
            if self._exposure_mode is ExposureMode.LOCKED:
                self._unlock_exposure()  # on failure it stays locked, and the next unlock tries again
                self._exposure_mode = ExposureMode.AUTO

    def set_exposure_us(self, exposure_us: float) -> None:
        self.require_open()
        with self._exposure_guard:
            self._apply_exposure_us(exposure_us)

    def set_gain_db(self, gain_db: float) -> None:
        self.require_open()
        self._apply_gain_db(gain_db)

    def _apply_exposure_us(self, exposure_us: float) -> None:
        if not self.capabilities.exposure:
            raise CameraConfigError(f"{self.name}: the {self.backend_name} backend has no exposure control")
        if not exposure_us > 0:
            raise CameraConfigError(f"{self.name}: exposure {exposure_us} us, expected a positive time")
        self._set_exposure_us(float(exposure_us))
        self._exposure_mode = ExposureMode.MANUAL

    def _apply_gain_db(self, gain_db: float) -> None:
        if not self.capabilities.gain:
            raise CameraConfigError(f"{self.name}: the {self.backend_name} backend has no gain control")
        self._set_gain_db(float(gain_db))

    # -- lifecycle -------------------------------------------------------------------------
    def _open(self) -> None:
        self._open_device()  # may declare what this very device can do (`capabilities`)
        config = self.config
        if config.exposure_control == "lock_per_fixation" and not self.capabilities.exposure_lock:
            raise CameraConfigError(
                f"{self.name}: exposure_control: lock_per_fixation, but this {self.backend_name} camera cannot hold "
                "its exposure (no auto exposure or gain to switch off): use auto, or manual with exposure_us")
        with self._exposure_guard:
            self._exposure_mode = ExposureMode.AUTO
            if config.exposure_control == "lock_per_fixation":
                # V4L2 and GenICam devices keep their controls while powered: one left held
                # by a process that died mid-fixation runs its auto exposure again here.
                self._unlock_exposure()
            if config.exposure_us is not None:
                self._apply_exposure_us(config.exposure_us)
            if config.gain_db is not None:
                self._apply_gain_db(config.gain_db)

    def _enable(self) -> None:
        self._start_stream()
        self._health = StreamHealth.STREAMING
        self._last_error = None
        self._thread = CaptureThread(self)
        self._thread.start()

    def _disable(self) -> None:
        thread, self._thread = self._thread, None
        try:
            if thread is not None:
                thread.stop()
        finally:
            self._health = StreamHealth.STOPPED
            self._stop_stream()

    def _close(self) -> None:
        try:
            if self._thread is not None:
                self._disable()
        finally:
            self._close_device()

    # -- the capture loop (runs on the CaptureThread) -------------------------------------
    def _capture_loop(self, stop: threading.Event) -> None:
        self._stop_event = stop
        # A grab that fails at once (a backend erring on every call) is paced: failed grabs
        # start at least a frame period apart (5 ms without a rate), so the loop never spins.
        spacing_s = 1.0 / self.config.fps if self.config.fps else 0.005
        while not stop.is_set():
            started_s = time.monotonic()
            try:
                grab = self._grab(self.config.grab_timeout_s)
            except CameraLostError as err:
                self._report(err)
                if not self._recover(stop):
                    return
                continue
            except CameraError as err:  # one bad frame: reported, counted, streaming goes on
                self._report(err)
                stop.wait(max(0.0, started_s + spacing_s - time.monotonic()))
                continue
            except Exception as err:  # a bug or an unknown failure: stop rather than spin
                self._report(CameraError(f"{self.name}: capture failed: {err!r}"), cause=err)
                self._health = StreamHealth.FAILED
                self._notify()
                return
            if grab is not None:
                self._publish(grab)

    def _publish(self, grab: Grab) -> None:
        image = to_mode(grab.image, self.config.image, self.name)
        with self._cond:
            self._counter += 1
            frame = Frame(self.name, self._counter, image, grab.time_s, grab.exposure_start_s, grab.device_time_ns)
            self._latest = frame
            self._history.append(frame)
            listeners = list(self._listeners)
            self._cond.notify_all()
        for listener in listeners:
            try:
                listener(frame)
            except Exception:  # a listener's bug must not stop the camera
                log.exception("%s: frame listener %r failed", self.name, listener)

    def _recover(self, stop: threading.Event) -> bool:
        """Reopen a lost camera with exponential backoff, until `reconnect_give_up_s`."""
        self._health = StreamHealth.RECONNECTING
        self._notify()
        if not self.capabilities.reconnect:
            self._health = StreamHealth.FAILED
            self._notify()
            return False
        delay_s = 0.05
        deadline = time.monotonic() + self.config.reconnect_give_up_s
        attempt = 0
        while not stop.is_set():
            attempt += 1
            try:
                self._reopen()
            except CameraError as err:
                log.info("%s: reopen attempt %d failed: %s", self.name, attempt, err)
                if time.monotonic() + delay_s > deadline:
                    self._report(CameraLostError(
                        f"{self.name}: gave up reopening after {attempt} attempts "
                        f"({self.config.reconnect_give_up_s} s)"), cause=err)
                    self._health = StreamHealth.FAILED
                    self._notify()
                    return False
                stop.wait(delay_s)
                delay_s = min(delay_s * 2, self.config.reconnect_backoff_max_s)
                continue
            self._reconnect_count += 1
            self._health = StreamHealth.STREAMING
            log.info("%s: streaming again after %d attempt(s)", self.name, attempt)
            self._notify()
            return True
        return False

    def _report(self, err: BaseException, cause: BaseException | None = None) -> None:
        if cause is not None:
            err.__cause__ = cause
        # The error is kept (last_error, the callback's owner): drop its frames' locals so it
        # does not keep a lost device's objects alive. Releasing those belongs on this thread
        # (Aravis's finalizer talks to the vanished camera until a timeout), not on whichever
        # thread a later garbage collection happens to run.
        for chained in (err, err.__cause__, err.__context__):
            if chained is not None and chained.__traceback__ is not None:
                traceback.clear_frames(chained.__traceback__)
        self._error_count += 1
        self._last_error = err
        # A fault that repeats every frame would flood the log: the first of a run is logged,
        # then every 100th (the callback and the counters still see each one).
        message = str(err)
        self._repeats = self._repeats + 1 if message == self._last_message else 0
        self._last_message = message
        named = message if message.startswith(f"{self.name}:") else f"{self.name}: {message}"
        if self._repeats == 0:
            log.warning("%s", named)
        elif self._repeats % 100 == 0:
            log.warning("%s (repeated %d times)", named, self._repeats)
        if self.on_error is not None:
            try:
                self.on_error(self, err)
            except Exception:
                log.exception("%s: error callback failed", self.name)

    def _notify(self) -> None:
        with self._cond:
            self._cond.notify_all()
            listeners = list(self._listeners)
        for listener in listeners:
            try:
                listener(None)
            except Exception:
                log.exception("%s: frame listener %r failed", self.name, listener)

    def raise_if_failed(self) -> None:
        if self._health is StreamHealth.FAILED:
            raise CameraError(f"{self.name}: the stream has failed: {self._last_error}") from self._last_error
        if self._health is StreamHealth.STOPPED:
            raise DeviceStateError(f"{self.name}: not streaming (state {self.state.value}); enable() it first")

    def wait_stop(self, seconds: float) -> bool:
        """For backends on the capture thread: wait up to `seconds`; True when asked to stop."""
        stop = self._stop_event
        if stop is None:
            time.sleep(seconds)
            return False
        return stop.wait(seconds)

    # -- hooks for backends ----------------------------------------------------------------
    def _open_device(self) -> None:
        """Find and open the device, apply pixel format, size and rate."""

    def _close_device(self) -> None:
        """Release the device. Must tolerate a partial open and being called twice."""

    def _start_stream(self) -> None:
        """Start acquisition."""

    def _stop_stream(self) -> None:
        """Stop acquisition; tolerate a device already gone."""

    def _grab(self, timeout_s: float) -> Grab | None:
        """One frame with its timestamps, or None when none came within `timeout_s`.

        Raise `CameraLostError` when the device is gone (the base class reopens it).
        """
        raise CameraError(f"{self.name}: the {type(self).__name__} backend does not grab frames")

    def _reopen(self) -> None:
        """Reopen a lost device and stream again (by default: close, open and configure, start)."""
        try:
            self._stop_stream()
        finally:
            self._close_device()
        self._open()  # opens and applies exposure and gain again
        self._start_stream()

    def _set_exposure_us(self, exposure_us: float) -> None:
        raise CameraConfigError(f"{self.name}: no exposure control")

    def _set_gain_db(self, gain_db: float) -> None:
        raise CameraConfigError(f"{self.name}: no gain control")

    def _lock_exposure(self) -> None:
        """Switch the auto exposure (and auto gain) off, keeping the values they had reached."""
        raise CameraConfigError(f"{self.name}: the {self.backend_name} backend cannot hold its exposure")

    def _unlock_exposure(self) -> None:
        """Switch the auto exposure (and auto gain) on again."""
        raise CameraConfigError(f"{self.name}: the {self.backend_name} backend cannot hold its exposure")

    def _backend_stats(self) -> dict[str, int]:
        return {}


# --- construction ------------------------------------------------------------------------
def create_camera(config: CameraConfig, *, name: str | None = None, clock: Clock = SYSTEM_CLOCK,
                  on_error: ErrorCallback | None = None, key_path: str = "camera", **resources: Any) -> Camera:
    """The camera `config` describes, not yet opened.

    `resources` are what a backend needs beyond its config and cannot read from YAML (the
    simulated camera's head model and pose source); a backend not taking them refuses them.
    """
    cls = backends.backend_class("camera", config.backend, config)
    if not (isinstance(cls, type) and issubclass(cls, Camera)):
        raise CameraConfigError(f"{key_path}.backend: {config.backend!r} is {cls!r}, not a Camera class")
    backends.check_camera_config(config, cls, key_path)
    return cls(config, name=name, clock=clock, on_error=on_error, **resources)
