"""The simulated camera's auto exposure and auto gain, with the lag a real one has.

A webcam's auto exposure meters each frame's level (the mean of its middle, centre-weighted
as UVC webcams meter by default: `drivers.sim.camera_effects.sensor`) and moves its exposure time and
gain toward a target for the frames that follow: a fraction of the remaining error each
frame (`ae_speed`), at most `ae_max_step_ev` stops at a time, so a change in the view's
brightness takes a few frames to settle. Exposure first (up to `max_exposure_us`, at most
the frame period), then gain (up to `max_gain_db`); back down in the reverse order.

The driver can hold the values (`lock`: `ExposureMode.LOCKED`), set them by hand
(`set_exposure_us`, `set_gain_db`: `ExposureMode.MANUAL`) and let the controller run again
(`unlock`). Without `auto_exposure` (the ideal camera) it never moves: the exposure stays
at `reference_exposure_us`, where the rendered grey levels are shown as they are.

Frames are numbered by the camera's frame index: the settings of frame n come from frame
n - 1's metering. Frames the simulation did not render (between the synchronous renders of
the online experiments; dropped frames) ran the controller all the same: `catch_up` steps
it for them as if they had seen the view of the frame being taken. Thread-safe: the capture thread steps it
while the driver locks and unlocks.
"""
from __future__ import annotations

import logging
import math
import threading
from dataclasses import dataclass

from drivers.cameras.camera import ExposureMode
from drivers.sim.camera_effects.sensor_config import SensorParams

log = logging.getLogger(__name__)

MAX_GAIN_DB = 48.0  # the most a manual gain is taken (the config's bound on max_gain_db)
_MAX_STEPS = 500  # frames stepped at once at most: the controller has settled long before
_DARKEST = 1e-4  # the mean level taken for a black frame (its error is then the largest step)


@dataclass(frozen=True)
class ExposureState:
    """The exposure a frame is taken with."""

    exposure_us: float
    gain_db: float
    mode: ExposureMode

    @property
    def gain(self) -> float:
        """The gain as a factor."""
        return float(10.0 ** (self.gain_db / 20.0))


class AutoExposure:
    """Exposure time and gain of one simulated camera, frame by frame."""

    def __init__(self, params: SensorParams, fps: float) -> None:
        self.params = params
        self.frame_period_us = 1e6 / fps
        self.max_exposure_us = min(params.max_exposure_us, self.frame_period_us)
        self.min_exposure_us = min(params.min_exposure_us, self.max_exposure_us)
        self.max_gain = 10.0 ** (params.max_gain_db / 20.0)
        self._lock = threading.Lock()
        self._mode = ExposureMode.AUTO
        start_us = params.reference_exposure_us
        if params.auto_exposure:
            start_us = min(max(start_us, self.min_exposure_us), self.max_exposure_us)
        self._exposure_us = start_us
        self._gain = 1.0
        self._index: int | None = None  # the frame the settings are for
        self._measured: tuple[int, float, float] | None = None  # (frame, mean level, exposure x gain)

    # -- what the driver asks -----------------------------------------------------------
    @property
    def state(self) -> ExposureState:
        with self._lock:
            return self._state()

    def lock(self) -> None:
        with self._lock:
            if self._mode is ExposureMode.AUTO:
                self._mode = ExposureMode.LOCKED
                log.debug("exposure locked at %.0f us, %.1f dB", self._exposure_us, self._gain_db())

    def unlock(self) -> None:
        with self._lock:
            self._mode = ExposureMode.AUTO

    def set_exposure_us(self, exposure_us: float) -> None:
        """A manual exposure, at most the frame period (as a camera clamps it)."""
        with self._lock:
            self._mode = ExposureMode.MANUAL
            self._exposure_us = min(float(exposure_us), self.frame_period_us)

    def set_gain_db(self, gain_db: float) -> None:
        with self._lock:
            self._mode = ExposureMode.MANUAL
            self._gain = 10.0 ** (min(max(float(gain_db), 0.0), MAX_GAIN_DB) / 20.0)

    # -- frame by frame -----------------------------------------------------------------
    def settings_for(self, index: int) -> tuple[ExposureState, int]:
        """The exposure of frame `index`, and how many frames before it were not taken here
        (0 while streaming). The controller steps once from the last frame's metering; the
        frames skipped are `catch_up`'s."""
        with self._lock:
            if self._index is None:
                self._index = index
                return self._state(), 0
            frames = min(max(index - self._index, 0), _MAX_STEPS)
            self._index = max(index, self._index)
            if frames > 0 and self._running() and self._measured is not None:
                self._step()
            return self._state(), max(frames - 1, 0)

    def catch_up(self, mean_level: float, frames: int) -> ExposureState:
        """The `frames` skipped saw the view of the frame being taken, whose mean level at
        the settings now is `mean_level`: the controller steps once for each of them."""
        with self._lock:
            if self._running() and frames > 0:
                self._measured = (self._index or 0, max(float(mean_level), _DARKEST), self._exposure_us * self._gain)
                for _ in range(frames):
                    self._step()
            return self._state()

    def observe(self, index: int, mean_level: float) -> None:
        """Frame `index`, taken with the settings given for it, had this mean level (a
        fraction of full scale)."""
        with self._lock:
            if self._measured is None or index >= self._measured[0]:
                self._measured = (index, max(float(mean_level), _DARKEST), self._exposure_us * self._gain)

    # -- inside -------------------------------------------------------------------------
    def _running(self) -> bool:
        return self._mode is ExposureMode.AUTO and self.params.auto_exposure

    def _gain_db(self) -> float:
        return 20.0 * math.log10(self._gain)

    def _state(self) -> ExposureState:
        return ExposureState(self._exposure_us, self._gain_db(), self._mode)

    def _step(self) -> None:
        assert self._measured is not None
        _, level, product = self._measured
        total = self._exposure_us * self._gain
        predicted = level * total / product  # the same view at the settings now
        error = math.log(self.params.ae_target / predicted)
        most = self.params.ae_max_step_ev * math.log(2.0)
        total *= math.exp(min(max(self.params.ae_speed * error, -most), most))
        total = min(max(total, self.min_exposure_us), self.max_exposure_us * self.max_gain)
        self._exposure_us = min(max(total, self.min_exposure_us), self.max_exposure_us)
        self._gain = min(max(total / self._exposure_us, 1.0), self.max_gain)
