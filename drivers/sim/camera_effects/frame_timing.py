"""When a simulated camera exposes its frames, what time it reports for them, which never
arrive and which arrive late: `FrameTiming`, from the camera's `timing:` section
(`drivers.cameras.config.FrameTimingConfig`; the numbers and their sources are in
docs/sim-world.md, "Frame timing").

The camera runs on its own clock: frame n starts its exposure when that clock reads n / fps.
The camera's clock counts `1 + drift_ppm * 1e-6` seconds per second of the host's clock and
read 0 at the host time `phase_s`, so frame n starts at `phase_s + n / (fps * (1 + drift))`
host seconds. The driver stamps each frame later than that by a lag drawn uniformly from
[0, `timestamp_jitter_s`] (uvcvideo stamps a buffer when it decodes the frame's first
payload, at the completion of the USB transfer carrying it). A frame is lost with
probability `drop_rate`, and with probability `late_rate` arrives up to `late_s` after it
would have (a host that came late to dequeue it; its timestamp is the one taken on arrival
of its first payload all the same).

Presets (`model`): `ideal`, the code default, is a hardware-triggered pair: phase 0, no
drift, exact timestamps, nothing lost, both eyes on the grid n / fps of the clock.
`free_running` is a pair of USB webcams: each eye's phase drawn from the camera's seed
within one frame period, and its drift within +-`FREE_RUNNING_DRIFT_PPM`, unless given.

Everything about frame n is a function of (seed, eye, n): asking again gives the same slot.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from drivers.cameras.config import FrameTimingConfig
from drivers.errors import CameraConfigError

# The free-running preset (sources: docs/sim-world.md, "Frame timing").
FREE_RUNNING_DRIFT_PPM = 30.0  # each eye's drift drawn within +-this: a crystal's tolerance and stability
FREE_RUNNING_JITTER_S = 0.002  # the stamp's lag after the exposure start, uniform within [0, this]
FREE_RUNNING_DROP_RATE = 0.002
FREE_RUNNING_LATE_RATE = 0.01
FREE_RUNNING_LATE_S = 0.010

_SEED_TAG = 0x7431  # keeps these draws apart from the camera's other uses of its seed
_INDEX_SPAN = 1 << 62  # frame indices as seed words (a seed word cannot be negative)


@dataclass(frozen=True)
class FrameSlot:
    """One frame of a camera: when it is exposed, stamped and delivered (clock seconds)."""

    index: int
    exposure_start_s: float  # true clock time the exposure starts (first row)
    timestamp_s: float  # what the driver reports (with jitter), clock seconds
    dropped: bool  # this frame never arrives
    delivery_delay_s: float  # extra delay before it arrives (late frames)

    @property
    def delivery_s(self) -> float:
        """When the frame can be handed over: its exposure start plus any late delay."""
        return self.exposure_start_s + self.delivery_delay_s


@dataclass(frozen=True)
class TimingValues:
    """The values in force for one eye: the preset's, with the keys given."""

    phase_s: float
    drift_ppm: float
    timestamp_jitter_s: float
    drop_rate: float
    late_rate: float
    late_s: float


def timing_values(config: FrameTimingConfig, fps: float, seed: int, eye_index: int) -> TimingValues:
    """The values `config` gives one eye of frame rate `fps`: each key given, else its preset's
    (the free-running phase and drift drawn from (seed, eye))."""
    period_s = 1.0 / fps
    if config.model == "ideal":
        preset = TimingValues(0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    else:
        rng = np.random.default_rng((_SEED_TAG, seed, eye_index))
        phase_s, drift_ppm = float(rng.uniform(0.0, period_s)), float(rng.uniform(-1.0, 1.0) * FREE_RUNNING_DRIFT_PPM)
        preset = TimingValues(phase_s, drift_ppm, FREE_RUNNING_JITTER_S, FREE_RUNNING_DROP_RATE,
                              FREE_RUNNING_LATE_RATE, FREE_RUNNING_LATE_S)

    def given(value: float | None, default: float) -> float:
        return default if value is None else float(value)

    values = TimingValues(given(config.phase_s, preset.phase_s), given(config.drift_ppm, preset.drift_ppm),
                          given(config.timestamp_jitter_s, preset.timestamp_jitter_s),
                          given(config.drop_rate, preset.drop_rate), given(config.late_rate, preset.late_rate),
                          given(config.late_s, preset.late_s))
    if values.timestamp_jitter_s >= period_s / 2:
        raise CameraConfigError(key_path="timing.timestamp_jitter_s", value=values.timestamp_jitter_s,
                                expected=f"less than half a frame period ({period_s / 2:.6f} s at {fps:g} fps): "
                                         "timestamps keep their order")
    return values


class FrameTiming:
    """The frame times of one camera (see the module docstring)."""

    def __init__(self, config: FrameTimingConfig, fps: float, *, seed: int = 0, eye_index: int = 0) -> None:
        if not fps > 0:
            raise CameraConfigError(key_path="fps", value=fps, expected="a positive frame rate")
        self.config = config
        self.fps = float(fps)
        self.seed = seed
        self.eye_index = eye_index
        self.values = timing_values(config, self.fps, seed, eye_index)
        # Frames per host second: the camera's clock runs fast by its drift.
        self.rate_hz = self.fps * (1.0 + self.values.drift_ppm * 1e-6)
        self.ideal = self.values == TimingValues(0.0, 0.0, 0.0, 0.0, 0.0, 0.0)

    @property
    def period_s(self) -> float:
        """Host seconds between two frames' exposures."""
        return 1.0 / self.rate_hz

    @property
    def max_stamp_lag_s(self) -> float:
        """The most a timestamp lags its exposure's start: `timestamp_s - max_stamp_lag_s` is
        never later than the true start."""
        return self.values.timestamp_jitter_s

    def exposure_start_s(self, index: int) -> float:
        """When frame `index` starts its exposure (host clock seconds)."""
        return self.values.phase_s + index / self.rate_hz

    def index_at(self, now_s: float) -> int:
        """The last frame whose exposure began by `now_s`."""
        index = math.floor((now_s - self.values.phase_s) * self.rate_hz)
        # The division above may land a frame either side of `now_s` by a rounding error.
        if self.exposure_start_s(index + 1) <= now_s:
            index += 1
        elif self.exposure_start_s(index) > now_s:
            index -= 1
        return index

    def device_time_ns(self, index: int) -> int | None:
        """The camera's own clock at frame `index`'s exposure start, n / fps on it; None when
        ideal (the frames are on the host clock's grid: no clock of the camera's own)."""
        return None if self.ideal else round(index * 1e9 / self.fps)

    def slot(self, index: int) -> FrameSlot:
        """Frame `index`: its exposure start, reported timestamp, whether it is lost, its delay."""
        start_s = self.exposure_start_s(index)
        if self.ideal:
            return FrameSlot(index, start_s, start_s, False, 0.0)
        v = self.values
        rng = np.random.default_rng((_SEED_TAG, self.seed, self.eye_index, index % _INDEX_SPAN))
        lag_s, drop, late, delay = rng.random(4)
        delay_s = float(delay) * v.late_s if late < v.late_rate else 0.0
        return FrameSlot(index, start_s, start_s + float(lag_s) * v.timestamp_jitter_s, bool(drop < v.drop_rate),
                         delay_s)

    def due(self, last_index: int | None, now_s: float) -> tuple[FrameSlot | None, float]:
        """The newest frame after `last_index` (None: any) that has arrived by `now_s`, and
        when the next one arrives (for a capture thread to sleep until then).

        Frames arrive in the order of their exposures, less the lost ones; a late frame
        overtaken by the next one's arrival is not handed over after it."""
        newest = self.index_at(now_s)
        lookback = 2 + math.ceil(self.values.late_s * self.rate_hz)
        lowest = newest - lookback if last_index is None else max(last_index + 1, newest - lookback)
        wake_s = math.inf
        for index in range(newest, lowest - 1, -1):
            slot = self.slot(index)
            if slot.dropped:
                continue
            if slot.delivery_s <= now_s:
                return slot, now_s
            wake_s = min(wake_s, slot.delivery_s)
        for index in range(newest + 1, newest + 65):  # the next frame exposed that is not lost
            slot = self.slot(index)
            if not slot.dropped:
                wake_s = min(wake_s, slot.delivery_s)
                break
        return None, wake_s

    def describe(self) -> str:
        v = self.values
        return (f"{self.config.model} timing: phase {v.phase_s * 1e3:.3f} ms, drift {v.drift_ppm:+.1f} ppm, "
                f"timestamp jitter up to {v.timestamp_jitter_s * 1e3:.2f} ms, {v.drop_rate:.2%} dropped, "
                f"{v.late_rate:.2%} late by up to {v.late_s * 1e3:.1f} ms")
