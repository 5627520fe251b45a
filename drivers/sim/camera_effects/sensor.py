"""The simulated camera's photometry: from the light a frame gathers to the bytes it delivers.

The renderer gives the grey levels a nominal camera shows at the reference exposure, 0 dB
and the room's nominal light: this module treats them as proportional to the light (the
textures stand for the scene as a well-adjusted camera renders it) and applies, in a real
sensor's order:

1. the lens's relative illumination (vignetting), falling with the field angle toward the
   rim, `1 - vignetting` at the image corners;
2. the exposure: the room's light over the exposure and the exposure time relative to the
   reference (`scale`, per row band under a rolling shutter);
3. the pixel: its full well (saturation), shot noise (Poisson, as Gaussian of variance
   equal to the electrons) and read noise, both counted in electrons;
4. gain (the auto gain's or the driver's) and this unit's own gain, offset and gamma;
5. 8-bit quantisation. The MJPEG round trip of the USB link is `mjpeg_round_trip`.

Random numbers are deterministic per (seed, eye, frame index); a unit's response is drawn
per (seed, eye) within the configured spreads. A frame's unit-normal noise is drawn as 16-bit
random numbers looked up in the normal distribution's quantiles (`_normal_quantiles`), half
the cost of drawing normals; its tails end at 4.3 sigma, which 8-bit grey levels of a few
sigma's noise never show. The ideal camera passes the image through
untouched.
"""
from __future__ import annotations

import functools
import statistics
from dataclasses import dataclass

import cv2
import numpy as np

from drivers.sim.scene import Lens
from drivers.sim.camera_effects.sensor_config import SensorParams

_UNIT_STREAM = 0x5E45  # the photometric draws' random stream
_NOISE_STREAM = 0x401E  # the per-frame noise's
_QUANTILE_LEVELS = 1 << 16


@dataclass(frozen=True)
class UnitResponse:
    """How one camera unit renders light into grey levels, beyond the nominal response."""

    gain: float = 1.0  # factor
    offset: float = 0.0  # grey levels (black level)
    gamma: float = 1.0  # output = full scale x (signal / full scale) ** gamma

    @property
    def is_nominal(self) -> bool:
        return self.gain == 1.0 and self.offset == 0.0 and self.gamma == 1.0


def draw_unit_response(params: SensorParams, seed: int, eye: int) -> UnitResponse:
    """This eye's unit: gain, offset and gamma drawn uniformly within their spreads."""
    g, o, y = np.random.default_rng((seed, eye, _UNIT_STREAM)).uniform(-1.0, 1.0, 3)
    return UnitResponse(1.0 + params.gain_spread * float(g), params.offset_spread * float(o),
                        1.0 + params.gamma_spread * float(y))


def relative_illumination(lens: Lens, nominal: Lens, vignetting: float) -> np.ndarray:
    """(H, W) float32: the light each pixel of `lens` gets relative to its optical axis.

    The cos^4 law's shape in the field angle theta, scaled so that the nominal lens's image
    corners get `1 - vignetting`: (1 + a (theta / theta_corner)^2)^-2 with
    a = (1 - vignetting)^-1/2 - 1."""
    w, h = int(lens.width), int(lens.height)
    corners = np.array([[0.0, 0.0], [w - 1.0, 0.0], [0.0, h - 1.0], [w - 1.0, h - 1.0]])
    theta_corner = float(np.arccos(np.clip(nominal.unproject(corners)[:, 2], -1.0, 1.0)).max())
    vv, uu = np.mgrid[0:h, 0:w]
    rays = lens.unproject(np.column_stack([uu.ravel(), vv.ravel()]).astype(float))
    theta = np.arccos(np.clip(rays[:, 2], -1.0, 1.0)).reshape(h, w)
    a = (1.0 - vignetting) ** -0.5 - 1.0
    return np.asarray((1.0 + a * (theta / theta_corner) ** 2) ** -2, np.float32)


def mjpeg_round_trip(image: np.ndarray, quality: int) -> np.ndarray:
    """`image` as it arrives after JPEG compression at `quality` (a UVC camera's MJPEG stream)."""
    ok, encoded = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
    if not ok:
        raise ValueError(f"JPEG encoding of a {image.shape} image failed")
    decoded = cv2.imdecode(encoded, cv2.IMREAD_UNCHANGED)
    if decoded is None:
        raise ValueError(f"JPEG decoding of a {image.shape} image failed")
    out: np.ndarray = decoded
    return out


class SensorPipeline:
    """One eye's sensor: `expose` turns the rendered radiance into the frame's grey levels."""

    def __init__(self, params: SensorParams, lens: Lens, nominal: Lens, seed: int, eye: int) -> None:
        self.params, self.seed, self.eye = params, seed, eye
        self.unit = draw_unit_response(params, seed, eye)
        self.vignette = relative_illumination(lens, nominal, params.vignetting) if params.vignetting > 0 else None
        self.noisy = params.full_well_e is not None
        # Nothing to do at the nominal exposure: the renderer's image is the frame.
        self.identity = self.vignette is None and not self.noisy and self.unit.is_nominal

    def expose(self, radiance: np.ndarray, scale: float | np.ndarray, gain: float, index: int,
               measure: bool = False) -> tuple[np.ndarray, float | None]:
        """The frame (uint8, radiance's shape) and, with `measure`, its metered level (a
        fraction of full scale, what an auto exposure meters: the mean of the middle half of
        the image each way, as a webcam's centre-weighted metering).

        `radiance`: the render (grey levels at the reference exposure); `scale`: light x
        exposure over the reference, a number or (H, 1) per row; `gain`: a factor."""
        if self.identity and gain == 1.0 and np.all(np.asarray(scale) == 1.0):
            image = radiance if radiance.dtype == np.uint8 else _to_uint8(radiance)
            return image, _metered(image) if measure else None
        signal = self._levels(radiance, scale, gain, index, step=1)
        return _to_uint8(signal), _metered(signal) if measure else None

    def meter(self, radiance: np.ndarray, scale: float | np.ndarray, gain: float) -> float:
        """The mean level (fraction of full scale) `expose` would give, without noise, from
        every 4th pixel of every 4th row: what an auto exposure needs of a view, cheaply."""
        return _metered(self._levels(radiance[::4, ::4], scale, gain, None, step=4))

    def _levels(self, radiance: np.ndarray, scale: float | np.ndarray, gain: float, index: int | None,
                step: int) -> np.ndarray:
        """Grey levels as float32 before quantisation (noise for frame `index`; none if None);
        `radiance` is every `step`-th pixel of the image."""
        signal = radiance.astype(np.float32) * np.float32(1.0 / 255.0)  # fraction of the full well
        if isinstance(scale, np.ndarray):
            rows = scale[::step].astype(np.float32)
            signal *= rows if signal.ndim == 2 else rows[:, :, None]
        elif scale != 1.0:
            signal *= np.float32(scale)
        if self.vignette is not None:
            vignette = self.vignette[::step, ::step]
            signal *= vignette if signal.ndim == 2 else vignette[:, :, None]
        np.clip(signal, 0.0, 1.0, out=signal)  # the full well
        if self.noisy and index is not None:
            signal = self._noise(signal, index)
        signal *= np.float32(gain * self.unit.gain)
        np.clip(signal, 0.0, 1.0, out=signal)
        if self.unit.gamma != 1.0:
            np.power(signal, np.float32(self.unit.gamma), out=signal)
        signal *= np.float32(255.0)
        if self.unit.offset != 0.0:
            signal += np.float32(self.unit.offset)
        return signal

    def _noise(self, signal: np.ndarray, index: int) -> np.ndarray:
        """Shot and read noise, in electrons of the full well, as fractions of it again."""
        full_well = float(self.params.full_well_e or 0.0)
        electrons = signal * np.float32(full_well)
        sigma = np.sqrt(electrons + np.float32(self.params.read_noise_e ** 2))
        electrons += sigma * self._unit_normals(signal.shape, index)
        electrons *= np.float32(1.0 / full_well)
        return electrons

    def _unit_normals(self, shape: tuple[int, ...], index: int) -> np.ndarray:
        """Frame `index`'s standard normal field of `shape` (see the module docstring)."""
        rng = np.random.default_rng((self.seed, self.eye, index, _NOISE_STREAM))
        levels = np.frombuffer(rng.bytes(2 * int(np.prod(shape))), dtype=np.uint16)
        return _normal_quantiles()[levels].reshape(shape)


@functools.cache
def _normal_quantiles() -> np.ndarray:
    """The standard normal's quantiles at the middles of 2^16 equal steps of probability."""
    inverse = statistics.NormalDist().inv_cdf
    return np.array([inverse((k + 0.5) / _QUANTILE_LEVELS) for k in range(_QUANTILE_LEVELS)], np.float32)


def _metered(image: np.ndarray) -> float:
    """The mean level of the middle half of `image` each way, a fraction of full scale."""
    h, w = image.shape[:2]
    return float(np.mean(image[h // 4:h - h // 4, w // 4:w - w // 4])) / 255.0


def _to_uint8(image: np.ndarray) -> np.ndarray:
    """Rounded and clipped to 0..255 bytes."""
    out: np.ndarray = np.clip(np.rint(image), 0, 255).astype(np.uint8)
    return out


def exposure_scale(light: float | np.ndarray, exposure_us: float, reference_exposure_us: float) -> float | np.ndarray:
    """The light a frame gathers relative to the reference: the room's light over the exposure
    times the exposure over the reference."""
    ratio = exposure_us / reference_exposure_us
    if isinstance(light, np.ndarray):
        out: np.ndarray = light * ratio
        return out
    return float(light) * ratio
