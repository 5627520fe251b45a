"""The simulated camera's sensor and lens as a real camera has them: the `sensor:` section.

A camera's `sensor:` section names a preset (`model`) and overrides any of its values:
`ideal` (the code default) is the perfect camera the renderer alone gives; `uvc_webcam` is
a USB webcam with a fish-eye lens (what each value is and where it comes from:
docs/sim-world.md, "Cameras"). Each eye has its own section, so the two cameras of a head
may differ; what differs between two units of one model (their lenses, their photometric
response) is drawn per eye from the camera's seed within the ranges given here.

Plain data, read by `drivers.config.reader`; the effects themselves are in
`drivers.sim.camera_effects.sensor` (photometry, noise, compression), `drivers.sim.camera_effects.auto_exposure`,
`drivers.sim.camera_effects.lens_error` and `drivers.sim.camera_effects.shutter` (motion blur, rolling shutter).
"""
from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass
from typing import ClassVar, Literal

from drivers.config.reader import check_settings, setting
from drivers.errors import CameraConfigError

SensorModel = Literal["ideal", "uvc_webcam"]
SENSOR_MODELS: tuple[str, ...] = ("ideal", "uvc_webcam")


@dataclass(frozen=True)
class SensorParams:
    """Every effect's size; the defaults are the ideal camera's (no effect at all)."""

    # Lens: relative illumination at the image corners is 1 - vignetting (cos^4-like in the field angle).
    vignetting: float = setting(0.0, lo=0.0, hi=0.95, expected="a fraction from 0 to 0.95")
    # Unit-to-unit lens differences: the largest |focal scale - 1|, principal point offset, roll.
    focal_error: float = setting(0.0, lo=0.0, hi=0.2, expected="a fraction from 0 to 0.2")
    centre_error_px: float = setting(0.0, lo=0.0, hi=200.0, expected="from 0 to 200 px")
    roll_error_deg: float = setting(0.0, lo=0.0, hi=30.0, expected="from 0 to 30 deg")
    # This unit's lens, given rather than drawn (None: drawn from the seed within the errors above).
    focal_scale: float | None = setting(None, lo=0.5, hi=2.0, expected="a scale from 0.5 to 2")
    centre_offset_px: tuple[float, float] | None = setting(
        None, check=lambda c: all(abs(x) <= 200.0 for x in c), expected="[dx, dy] px, each within +-200")
    roll_deg: float | None = setting(None, lo=-30.0, hi=30.0, expected="from -30 to 30 deg")
    # Exposure: the rendered grey levels are what the camera gives at this exposure and 0 dB.
    reference_exposure_us: float = setting(10_000.0, above=0.0, hi=1e7, expected="a positive time, at most 1e7 us")
    auto_exposure: bool = False
    ae_target: float = setting(0.45, above=0.0, hi=1.0, expected="a fraction of full scale in (0, 1]")
    ae_speed: float = setting(0.3, above=0.0, hi=1.0, expected="a fraction in (0, 1]")
    ae_max_step_ev: float = setting(1.0, above=0.0, hi=10.0, expected="a positive number of stops, at most 10")
    min_exposure_us: float = setting(100.0, above=0.0, hi=1e7, expected="a positive time, at most 1e7 us")
    max_exposure_us: float = setting(33_000.0, above=0.0, hi=1e7, expected="a positive time, at most 1e7 us")
    max_gain_db: float = setting(0.0, lo=0.0, hi=48.0, expected="from 0 to 48 dB")
    # Unit-to-unit photometric differences: gain x (1 +- spread), offset +- grey levels, gamma 1 +- spread.
    gain_spread: float = setting(0.0, lo=0.0, hi=0.5, expected="a fraction from 0 to 0.5")
    offset_spread: float = setting(0.0, lo=0.0, hi=50.0, expected="from 0 to 50 grey levels")
    gamma_spread: float = setting(0.0, lo=0.0, hi=0.5, expected="a fraction from 0 to 0.5")
    # Noise: shot noise from the full well (None: none), read noise in electrons (needs full_well_e).
    full_well_e: float | None = setting(None, above=0.0, hi=1e7, expected="a positive number of electrons")
    read_noise_e: float = setting(0.0, lo=0.0, hi=1e4, expected="not negative, at most 10000 electrons")
    # MJPEG: the JPEG quality of every frame's round trip (None: raw frames).
    jpeg_quality: int | None = setting(None, lo=1, hi=100, expected="a quality from 1 to 100")
    # Motion during the exposure: blur from sub-exposure renders, rolling-shutter skew over the readout.
    motion_blur: bool = False
    blur_samples_max: int = setting(6, lo=2, hi=64, expected="from 2 to 64 renders")
    readout_s: float = setting(0.0, lo=0.0, hi=1.0, expected="from 0 to 1 s")
    readout_bands: int = setting(12, lo=1, hi=1024, expected="from 1 to 1024 bands of rows")

    CONFIG_ERROR: ClassVar[type[CameraConfigError]] = CameraConfigError

    def __post_init__(self) -> None:
        check_settings(self)
        if self.read_noise_e > 0 and self.full_well_e is None:
            raise CameraConfigError(key_path="read_noise_e", value=self.read_noise_e,
                                    expected="0 without full_well_e (electrons are counted against the full well)")
        if self.min_exposure_us > self.max_exposure_us:
            raise CameraConfigError(key_path="min_exposure_us", value=self.min_exposure_us,
                                    expected=f"at most max_exposure_us ({self.max_exposure_us} us)")

    @property
    def lens_differs(self) -> bool:
        """Whether this unit's lens may differ from the nominal one."""
        return (self.focal_error > 0 or self.centre_error_px > 0 or self.roll_error_deg > 0
                or self.focal_scale is not None or self.centre_offset_px is not None or self.roll_deg is not None)

    @property
    def exposure_moves(self) -> bool:
        """Whether motion during the exposure shows (blur, rolling-shutter skew)."""
        return self.motion_blur or self.readout_s > 0


# The typical values of each model (where each number comes from: docs/sim-world.md, "Cameras").
SENSOR_PRESETS: Mapping[str, SensorParams] = {
    "ideal": SensorParams(),
    "uvc_webcam": SensorParams(
        vignetting=0.45, focal_error=0.03, centre_error_px=10.0, roll_error_deg=2.0,
        reference_exposure_us=10_000.0, auto_exposure=True, ae_target=0.45, ae_speed=0.3, ae_max_step_ev=1.0,
        min_exposure_us=100.0, max_exposure_us=33_000.0, max_gain_db=18.0,
        gain_spread=0.05, offset_spread=3.0, gamma_spread=0.05,
        full_well_e=6000.0, read_noise_e=5.0, jpeg_quality=80,
        motion_blur=True, blur_samples_max=4, readout_s=0.025, readout_bands=8,
    ),
}


@dataclass(frozen=True)
class SensorConfig:
    """A simulated camera's `sensor:` section: a model's preset and overrides of its values
    (any `SensorParams` key)."""

    model: SensorModel = setting("ideal", choices=SENSOR_MODELS, expected=" or ".join(SENSOR_MODELS))
    overrides: Mapping[str, object] = setting(default_factory=dict, inline=SensorParams)

    CONFIG_ERROR: ClassVar[type[CameraConfigError]] = CameraConfigError

    def __post_init__(self) -> None:
        check_settings(self)
        self.params()  # checks across the preset's and the overrides' values

    def params(self) -> SensorParams:
        """The preset's values with the overrides applied."""
        return dataclasses.replace(SENSOR_PRESETS[self.model], **self.overrides)  # type: ignore[arg-type]
