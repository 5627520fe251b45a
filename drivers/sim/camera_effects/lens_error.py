"""One unit's lens as it really is: the nominal lens with this unit's focal length, principal
point and roll about the optical axis, different in each eye.

Two webcams of one model differ: their lenses' focal lengths by a few percent, their
principal points by pixels from the image centre (the lens is glued over the sensor within a
tolerance), and each camera is mounted slightly rolled about its axis. The simulated eye
renders through `ErredLens` (a `drivers.sim.scene.Lens`) while the method keeps the nominal
lens model: the gaze map must learn around the difference, as it does on a real head.

For a radially symmetric lens (the nominal lens is one) the three differences are exact in
pixel space: a point the nominal lens puts at `uv` lands at `c + offset + s R (uv - c)`,
with `c` the nominal principal point, `s` the focal scale and `R` the roll, which turns the
image clockwise as seen (x right, y down) for a positive angle.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from drivers.sim.scene import Lens
from drivers.sim.camera_effects.sensor_config import SensorParams

_LENS_STREAM = 0x1E45  # the lens draws' own random stream, apart from noise and photometry
_FIELD_TOLERANCE_RAD = 1e-4  # a ray the nominal lens sends back elsewhere is beyond its field


@dataclass(frozen=True)
class LensError:
    """How one unit's lens differs from the nominal one."""

    focal_scale: float = 1.0
    centre_offset_px: tuple[float, float] = (0.0, 0.0)
    roll_deg: float = 0.0

    @property
    def is_nominal(self) -> bool:
        return self.focal_scale == 1.0 and self.centre_offset_px == (0.0, 0.0) and self.roll_deg == 0.0


def draw_lens_error(params: SensorParams, seed: int, eye: int) -> LensError:
    """This eye's lens: each difference drawn uniformly within its configured range from
    (seed, eye), unless the config gives it. Deterministic; a given value leaves the others'
    draws unchanged."""
    rng = np.random.default_rng((seed, eye, _LENS_STREAM))
    scale, dx, dy, roll = rng.uniform(-1.0, 1.0, 4)
    focal = 1.0 + params.focal_error * float(scale) if params.focal_scale is None else params.focal_scale
    if params.centre_offset_px is None:
        offset = (params.centre_error_px * float(dx), params.centre_error_px * float(dy))
    else:
        offset = (float(params.centre_offset_px[0]), float(params.centre_offset_px[1]))
    roll_deg = params.roll_error_deg * float(roll) if params.roll_deg is None else params.roll_deg
    return LensError(focal, offset, roll_deg)


class ErredLens:
    """The nominal lens as this unit has it (a `drivers.sim.scene.Lens`): same image size,
    its rays moved by `error`."""

    def __init__(self, nominal: Lens, error: LensError) -> None:
        self.nominal, self.error = nominal, error
        centre, _ = nominal.project(np.array([[0.0, 0.0, 1.0]]))
        self.principal_point = (float(centre[0, 0]), float(centre[0, 1]))
        self._centre = np.asarray(centre[0], float)
        self._offset = np.asarray(error.centre_offset_px, float)
        a = math.radians(error.roll_deg)
        self._rotation = np.array([[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]])
        self._field_rad = _field_of(nominal)

    @property
    def width(self) -> int:
        return int(self.nominal.width)

    @property
    def height(self) -> int:
        return int(self.nominal.height)

    @property
    def optical_centre(self) -> tuple[float, float]:
        """Where this unit's optical axis meets the image, px."""
        x, y = self._centre + self._offset
        return float(x), float(y)

    def _to_nominal(self, uv: np.ndarray) -> np.ndarray:
        shifted: np.ndarray = (uv - self._centre - self._offset) / self.error.focal_scale
        out: np.ndarray = self._centre + shifted @ self._rotation  # R^T applied to row vectors
        return out

    def _from_nominal(self, uv: np.ndarray) -> np.ndarray:
        turned: np.ndarray = (uv - self._centre) @ self._rotation.T
        out: np.ndarray = self._centre + self._offset + self.error.focal_scale * turned
        return out

    def unproject(self, uv: np.ndarray) -> np.ndarray:
        """Unit rays (N, 3) in the camera frame through this unit's pixels (N, 2)."""
        return self.nominal.unproject(self._to_nominal(np.atleast_2d(np.asarray(uv, float))))

    def project(self, points_cam: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Pixels (N, 2) of points (N, 3) in the camera frame, and which of them are seen: in
        front, within the lens's field and inside this unit's image."""
        p = np.atleast_2d(np.asarray(points_cam, float))
        uv = self._from_nominal(self.nominal.project(p)[0])
        theta = np.arctan2(np.hypot(p[:, 0], p[:, 1]), p[:, 2])
        seen = ((theta < self._field_rad) & (p[:, 2] > 0)
                & (uv[:, 0] >= -0.5) & (uv[:, 0] <= self.width - 0.5)
                & (uv[:, 1] >= -0.5) & (uv[:, 1] <= self.height - 0.5))
        return uv, seen


def _field_of(lens: Lens) -> float:
    """The largest angle off the axis (rad) whose ray `lens` projects to a pixel it unprojects
    back to the same ray: its field, found once by bisection."""
    def round_trips(theta: float) -> bool:
        ray = np.array([[math.sin(theta), 0.0, math.cos(theta)]])
        back = lens.unproject(lens.project(ray)[0])
        return bool(float(back[0] @ ray[0]) > math.cos(_FIELD_TOLERANCE_RAD))

    low, high = 0.0, math.pi
    for _ in range(40):
        middle = (low + high) / 2
        low, high = (middle, high) if round_trips(middle) else (low, middle)
    return low


def unit_lens(nominal: Lens, params: SensorParams, seed: int, eye: int) -> Lens:
    """The lens this eye renders through: the nominal one unless its unit's lens differs."""
    if not params.lens_differs:
        return nominal
    error = draw_lens_error(params, seed, eye)
    return nominal if error.is_nominal else ErredLens(nominal, error)
