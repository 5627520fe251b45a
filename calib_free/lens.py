"""Fish-eye lenses as the Kannala-Brandt polynomial (the model of `cv2.fisheye`).

A ray at angle theta from the optical axis lands at radius
    r = f * theta_d,   theta_d = theta * (1 + k1 theta^2 + k2 theta^4 + k3 theta^6 + k4 theta^8)
from the principal point. All k = 0 is the equidistant lens. Unlike `cv2.fisheye`, points
behind the camera (z <= 0) never project here.

Camera frame: OpenCV's (x right, y down, z along the optical axis). Pixels: origin at the
top-left pixel's centre, x right, y down; the principal point (the fovea) is the image
centre ((width - 1) / 2, (height - 1) / 2).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

# The paper's lens (section I-B): 5.4 mm focal length at the centre, 90 deg horizontal and
# 150 deg diagonal angle of view on a 7.28 x 5.04 mm sensor. A least-squares fit of k1..k4
# to r(45 deg) = 3.64 mm, r(75 deg) = 4.43 mm, r(31 deg) = 2.52 mm, keeping dr/dtheta >= 0.8
# mm/rad out to 80 deg (the three figures are not exactly consistent with one smooth lens):
# 3.63 mm at 45 deg, 4.47 mm at 75 deg, 2.72 mm at 31 deg. Magnification is 1.8x lower at
# the left/right edges than at the centre and 4.9x lower in the corners: the periphery is
# compressed, the centre foveated.
PAPER_FOCAL_MM = 5.4
PAPER_SENSOR_MM = (7.28, 5.04)
FOVEATED_K = (-0.2329, 0.00582, -0.01872, 0.01258)
# Equisolid r = 2 f sin(theta / 2), as its Taylor series in Kannala-Brandt form.
EQUISOLID_K = (-1 / 24, 1 / 1920, -1 / 322560, 1 / 92897280)
LENS_KINDS = ("foveated", "equidistant", "equisolid")


@dataclass(frozen=True)
class FisheyeLens:
    """A Kannala-Brandt fish-eye camera: focal length in pixels, distortion, image size."""

    width: int
    height: int
    focal_px: float
    k: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0)
    max_theta_rad: float = np.radians(85.0)
    _table: tuple[np.ndarray, np.ndarray] = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        if self.width < 2 or self.height < 2:
            raise ValueError(f"image size must be at least 2 x 2 px, got {self.width} x {self.height}")
        if self.focal_px <= 0:
            raise ValueError(f"focal_px must be positive, got {self.focal_px}")
        theta = np.linspace(0.0, self.max_theta_rad, 4096)
        radius = self.radius_px(theta)
        if np.any(np.diff(radius) <= 0):
            raise ValueError(f"lens k={self.k} is not monotonic up to {np.degrees(self.max_theta_rad):.0f} deg")
        object.__setattr__(self, "_table", (radius, theta))

    # -- construction ------------------------------------------------------------------
    @classmethod
    def named(cls, kind: str, width: int, height: int) -> "FisheyeLens":
        """One of LENS_KINDS at the given image size, all with the paper's 90 deg horizontal view.

        Pixels are square, their pitch set by the paper's 7.28 mm sensor width over `width`.
        """
        pitch_mm = PAPER_SENSOR_MM[0] / width
        half_width_mm = PAPER_SENSOR_MM[0] / 2
        if kind == "foveated":
            return cls(width, height, PAPER_FOCAL_MM / pitch_mm, FOVEATED_K)
        if kind == "equidistant":
            # r = f theta; f chosen so that 45 deg lands on the sensor's edge.
            return cls(width, height, half_width_mm / np.radians(45) / pitch_mm)
        if kind == "equisolid":
            return cls(width, height, half_width_mm / (2 * np.sin(np.radians(22.5))) / pitch_mm, EQUISOLID_K)
        raise ValueError(f"unknown lens kind {kind!r}: expected one of {', '.join(LENS_KINDS)}")

    # -- geometry ----------------------------------------------------------------------
    @property
    def principal_point(self) -> tuple[float, float]:
        return ((self.width - 1) / 2.0, (self.height - 1) / 2.0)

    @property
    def camera_matrix(self) -> np.ndarray:
        cx, cy = self.principal_point
        return np.array([[self.focal_px, 0, cx], [0, self.focal_px, cy], [0, 0, 1]], dtype=float)

    def radius_px(self, theta: np.ndarray) -> np.ndarray:
        t2 = np.asarray(theta) ** 2
        k1, k2, k3, k4 = self.k
        return self.focal_px * theta * (1 + t2 * (k1 + t2 * (k2 + t2 * (k3 + t2 * k4))))

    def project(self, points_cam: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Pixels (N, 2) of points (N, 3) in the camera frame, and which of them are seen.

        A point is seen when it is in front of the camera, within `max_theta_rad` of the axis
        and inside the image. Pixels of unseen points are still computed where finite.
        """
        p = np.atleast_2d(np.asarray(points_cam, dtype=float))
        x, y, z = p[:, 0], p[:, 1], p[:, 2]
        rho = np.hypot(x, y)
        theta = np.arctan2(rho, z)
        r = self.radius_px(np.minimum(theta, self.max_theta_rad))
        with np.errstate(invalid="ignore", divide="ignore"):
            scale = np.where(rho > 1e-12, r / rho, self.focal_px / np.where(z > 0, z, 1.0))
        cx, cy = self.principal_point
        uv = np.stack([cx + scale * x, cy + scale * y], axis=1)
        seen = (
            (z > 0)
            & (theta < self.max_theta_rad)
            & (uv[:, 0] >= -0.5) & (uv[:, 0] <= self.width - 0.5)
            & (uv[:, 1] >= -0.5) & (uv[:, 1] <= self.height - 0.5)
        )
        return uv, seen

    def unproject(self, uv: np.ndarray) -> np.ndarray:
        """Unit rays (N, 3) in the camera frame through pixels (N, 2)."""
        q = np.atleast_2d(np.asarray(uv, dtype=float))
        cx, cy = self.principal_point
        dx, dy = q[:, 0] - cx, q[:, 1] - cy
        r = np.hypot(dx, dy)
        radius_table, theta_table = self._table
        theta = np.interp(r, radius_table, theta_table)
        # Two Newton steps on the table's linear interpolation: sub-micro-radian accuracy.
        for _ in range(2):
            t2 = theta * theta
            k1, k2, k3, k4 = self.k
            dr = self.focal_px * (1 + t2 * (3 * k1 + t2 * (5 * k2 + t2 * (7 * k3 + t2 * 9 * k4))))
            theta = theta - (self.radius_px(theta) - r) / dr
        s = np.sin(theta)
        with np.errstate(invalid="ignore", divide="ignore"):
            ux = np.where(r > 1e-12, dx / r, 0.0)
            uy = np.where(r > 1e-12, dy / r, 0.0)
        return np.stack([s * ux, s * uy, np.cos(theta)], axis=1)

    def opencv_distortion(self) -> np.ndarray:
        """The same lens as `cv2.fisheye`'s D vector (use with `camera_matrix`)."""
        return np.array(self.k, dtype=float).reshape(4, 1)
