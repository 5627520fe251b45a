"""Rendering one frame over its exposure: motion blur and rolling-shutter skew.

A webcam's CMOS sensor starts each row's exposure a little after the one above (a rolling
shutter): the rows are read out one after another over `readout_s`, each exposed for the
same exposure time. While the head turns, each row sees the room from where the eye was
during that row's exposure: vertical edges lean (skew), and everything smears along its
motion over the exposure (blur).

`ExposureRenderer.render` renders the image in bands of rows (`readout_bands`), each at the
pose of its own rows' exposure, and, for blur, averages a few renders at sub-times of that
exposure, as many as keep successive renders about a pixel apart (at most
`blur_samples_max`). The poses come from a function of time (a `TimedPoseSource`'s `at`).
Only when something moves during the frame: a still head (and still objects) is one render,
as the ideal camera's. The room's light is averaged over each band's exposure alike
(`light_over`), so flicker bands a rolling-shutter image.
"""
from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence

import numpy as np

from drivers.sim.room_light import Illumination
from drivers.sim.scene import EyeRenderer, HeadGeometry, Lens, Scene, joints_tuple
from drivers.sim.camera_effects.sensor_config import SensorParams

PoseAt = Callable[[float], Mapping[str, float]]  # joint angles (degrees) at a time of the clock

_STILL_DEG = 1e-6  # joints moving less than this over a frame are still
_BLUR_SPACING_PX = 1.0  # sub-exposure renders at most this far apart on the image
_BAND_SKEW_PX = 1.5  # the skew within one band at most, where the bands configured allow


class RowBand:
    """Rows `rows` of a lens, as a lens of their own (a `drivers.sim.scene.Lens`): what one
    band of a rolling shutter renders through."""

    def __init__(self, lens: Lens, rows: slice) -> None:
        self.lens, self.rows = lens, rows
        self._shift = np.array([0.0, float(rows.start)])

    @property
    def width(self) -> int:
        return int(self.lens.width)

    @property
    def height(self) -> int:
        return int(self.rows.stop - self.rows.start)

    def unproject(self, uv: np.ndarray) -> np.ndarray:
        return self.lens.unproject(np.atleast_2d(np.asarray(uv, float)) + self._shift)

    def project(self, points_cam: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        uv, seen = self.lens.project(points_cam)
        uv = uv - self._shift
        return uv, seen & (uv[:, 1] >= -0.5) & (uv[:, 1] <= self.height - 0.5)


def row_bands(height: int, bands: int) -> list[slice]:
    """`bands` bands of rows as even as whole rows allow (at most one a row)."""
    edges = np.round(np.linspace(0, height, min(bands, height) + 1)).astype(int)
    return [slice(int(a), int(b)) for a, b in zip(edges[:-1], edges[1:])]


def _span_deg(a: Mapping[str, float], b: Mapping[str, float]) -> float:
    return max(abs(float(a[k]) - float(b[k])) for k in a)


class ExposureRenderer:
    """One eye's frames rendered over their exposure (module docstring)."""

    def __init__(self, lens: Lens, scene: Scene, head: HeadGeometry, eye: int, params: SensorParams) -> None:
        self.lens, self.scene, self.head, self.eye, self.params = lens, scene, head, eye, params
        self.full = EyeRenderer(lens, scene)
        self.height = int(lens.height)
        self.bands = row_bands(self.height, params.readout_bands) if params.readout_s > 0 else [slice(0, self.height)]
        self.band_delays_s = self._delays(self.bands)
        # Renderers for the configured bands and for halves of that count (fewer while the
        # head moves slowly: a band's cost is mostly its own, whatever its rows).
        self._partitions: dict[int, list[tuple[slice, EyeRenderer, float]]] = {}
        count = len(self.bands)
        while count > 1:
            bands = row_bands(self.height, count)
            self._partitions[count] = [(b, EyeRenderer(RowBand(lens, b), scene), d)
                                       for b, d in zip(bands, self._delays(bands))]
            count //= 2
        axis = lens.project(np.array([[0.0, 0.0, 1.0], [math.sin(math.radians(1.0)), 0.0, math.cos(math.radians(1.0))]]))[0]
        self.px_per_deg = float(np.hypot(*(axis[1] - axis[0])))
        self.renders = 0  # renders made (a band's counts as one): what the frames cost

    def _delays(self, bands: Sequence[slice]) -> list[float]:
        """When each band's exposure starts after the first row's: its middle row's start."""
        return [self.params.readout_s * (b.start + b.stop - 1) / (2.0 * self.height) for b in bands]

    # -- the room's light -------------------------------------------------------------------
    def light_over(self, light: Illumination, start_s: float, exposure_s: float) -> float | np.ndarray:
        """The room's light over each row's exposure: a number, or (H, 1) per row band."""
        if len(self.bands) == 1:
            return float(light.mean_over(start_s, exposure_s))
        factors = [float(light.mean_over(start_s + delay, exposure_s)) for delay in self.band_delays_s]
        if all(f == factors[0] for f in factors):
            return factors[0]
        rows = np.repeat(np.asarray(factors, np.float32), [b.stop - b.start for b in self.bands])
        return rows[:, None]

    # -- the image --------------------------------------------------------------------------
    def render(self, pose_at: PoseAt, start_s: float, exposure_s: float) -> np.ndarray:
        """The frame whose first row's exposure starts at `start_s`: uint8 when one render
        made it, else float32 grey levels (an average of renders)."""
        first = pose_at(start_s)
        if not self.params.exposure_moves:
            return self._render(self.full, first, start_s)
        readout_s = self.params.readout_s
        end_s = start_s + readout_s + exposure_s
        poses = {t: pose_at(t) for t in (start_s + exposure_s, start_s + readout_s, end_s, (start_s + end_s) / 2)}
        poses[start_s] = first
        moving = max(_span_deg(first, p) for p in poses.values()) > _STILL_DEG
        objects_deg = self._objects_deg(first, start_s, end_s)
        if not moving and objects_deg == 0.0:
            return self._render(self.full, first, start_s)
        blur_deg = max(_span_deg(first, poses[start_s + exposure_s]),
                       _span_deg(poses[start_s + readout_s], poses[end_s]), objects_deg)
        samples = 1
        if self.params.motion_blur:
            samples = min(self.params.blur_samples_max, max(1, math.ceil(blur_deg * self.px_per_deg / _BLUR_SPACING_PX)))
        skew_deg = max(_span_deg(first, poses[start_s + readout_s]), objects_deg)
        parts: Sequence[tuple[slice, EyeRenderer, float]] = [(slice(0, self.height), self.full, 0.0)]
        wanted = skew_deg * self.px_per_deg / _BAND_SKEW_PX
        fitting = [n for n in self._partitions if n >= wanted]
        if self._partitions and wanted > 1.0:
            parts = self._partitions[min(fitting) if fitting else max(self._partitions)]
        if len(parts) == 1 and samples == 1:
            middle_s = start_s + exposure_s / 2
            return self._render(self.full, pose_at(middle_s), middle_s)
        out: np.ndarray | None = None
        for rows, renderer, delay_s in parts:
            total: np.ndarray | None = None
            for s in range(samples):
                t = start_s + delay_s + exposure_s * (s + 0.5) / samples
                image = self._render(renderer, pose_at(t), t).astype(np.float32)
                total = image if total is None else total + image
            assert total is not None
            if out is None:
                out = np.empty((self.height,) + total.shape[1:], np.float32)
            out[rows] = total * np.float32(1.0 / samples)
        assert out is not None
        return out

    def _render(self, renderer: EyeRenderer, joints: Mapping[str, float], time_s: float) -> np.ndarray:
        rotation, centre = self.head.eye_frames_from_joints(*joints_tuple(joints))[self.eye]
        self.renders += 1
        return renderer.render(rotation, centre, time_s)

    def _objects_deg(self, joints: Mapping[str, float], start_s: float, end_s: float) -> float:
        """The most any moving box turns as seen from the eye over the frame (0: none moves)."""
        motion = self.scene.motion
        if motion is None:
            return 0.0
        before, after = motion.box_offsets(start_s), motion.box_offsets(end_s)
        if before is None or after is None or np.array_equal(before, after):
            return 0.0
        _, eye_centre = self.head.eye_frames_from_joints(*joints_tuple(joints))[self.eye]
        centres = (np.asarray(self.scene.lo, float) + np.asarray(self.scene.hi, float)) / 2 + before
        distance = np.maximum(np.linalg.norm(centres - np.asarray(eye_centre, float), axis=1), 0.05)
        moved = np.linalg.norm(np.asarray(after, float) - np.asarray(before, float), axis=1)
        return float(np.degrees(np.max(moved / distance)))
