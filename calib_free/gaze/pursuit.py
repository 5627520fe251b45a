"""Smooth pursuit: a moving target's patch kept on both foveae, one frame pair at a time.

Beyond the paper, which fixates still targets. Three parts, none of which knows a driver:

- `PoseHistory`: (time, pose) samples of the head as the servos report it; the pose at a
  frame's exposure time by interpolation, so that what a frame shows is judged from where the
  head was when it was exposed, not where it is when the command goes out.
- `PatchTracker`: the target's patch found in each new pair: in the left image by normalised
  cross-correlation near where it is predicted, then along the same rows of the right image
  (its disparity). The template is taken again where the patch was found when the match
  weakens (the target turns, the lens distorts it off-centre).
- `Pursuit`: the control law. Each found patch gives the target's direction in motor space,
  q = pose at exposure + J (r - fovea), with J the map's local Jacobian at the fovea (finite
  differences of `command`; beyond `linear_radius_px` the map's own secant W(r) - W(fovea)).
  An alpha-beta filter estimates q and its velocity; the goal commanded is the filtered q
  carried forward by the velocity over the time from exposure to command plus `lead_s`
  (velocity feed-forward with the frame-to-command delay accounted for). Retinal errors are
  corrected proportionally through the filter's position gain.

Unsynchronised cameras (two USB webcams) expose the right image up to half a frame period
before or after the left: while the head or the target moves, the patch has moved in the
right image by then, and its disparity is off by the right image's velocity times that skew
(2 px at 30 deg/s and 16 ms). `step` and `start` take the pair's skew (`right_lag_s`, right
timestamp minus left) and the head's pose at the right exposure, and bring the disparity to
the left image's time: the patch's motion in motor space over the skew (the target's
filtered velocity times the skew, less the head's own motion) through the Jacobian is the
right image's shift, which the measured disparity loses (`correct_skew`).

Poses are (pan, tilt, vergence) in degrees; image positions (x, y, d) in pixels of the left
image, d = x_right - x_left; the fovea is (cx, cy, 0).
"""
from __future__ import annotations

import bisect
import dataclasses
import enum
import inspect
import logging
import threading
from typing import Any, Protocol

import cv2
import numpy as np

from calib_free.correspondence.disparity import DISPARITY_BAND_PX, as_grey_float, stereo_offset, subpixel_peak
from calib_free.errors import OutOfRangeError

log = logging.getLogger(__name__)


@dataclasses.dataclass(frozen=True)
class PursuitParams:
    """How the patch is found and how the head follows it."""

    patch_size_px: int = 24  # the square template, px
    search_radius_px: int = 24  # the patch is looked for this far around where it is predicted
    min_ncc: float = 0.6  # a best match below this: not found in this pair
    # Rows either side of the target's own its right-image match is looked for when a track
    # starts: the two cameras' vertical misalignment (docs/method.md); later pairs look a few
    # rows around where the start found it.
    row_band_px: int = 24
    refresh_ncc: float = 0.85  # found, but below this: the template is taken again where it was found
    disparity_search_px: float = 8.0  # the right image is searched this far either side of the last d
    lost_after_frames: int = 10  # pairs in a row without the patch: the track is lost
    alpha: float = 0.7  # the filter's position gain (proportional correction of the retinal error)
    beta: float = 0.25  # its velocity gain
    lead_s: float = 0.035  # the goal looks this far beyond the command (next exposure, the servos' lag)
    max_speed_deg_s: float = 150.0  # the target's estimated speed is clamped to this, per axis
    jacobian_step_px: float = 6.0  # finite-difference step of the map's Jacobian (x, y; d: half)
    linear_radius_px: float = 16.0  # retinal errors beyond this use the map's secant, not its Jacobian
    frame_timeout_s: float = 0.5  # no new pair for this long: no command; the track is lost
    correct_skew: bool = True  # a pair's right image taken later or earlier: its disparity brought to the left's time

    def __post_init__(self) -> None:
        if self.patch_size_px < 5:
            raise ValueError(f"patch_size_px must be at least 5, got {self.patch_size_px}")
        if self.search_radius_px < 1:
            raise ValueError(f"search_radius_px must be at least 1, got {self.search_radius_px}")
        if not -1.0 <= self.min_ncc <= self.refresh_ncc <= 1.0:
            raise ValueError(f"min_ncc must lie in [-1, refresh_ncc], refresh_ncc in [min_ncc, 1]; got "
                             f"{self.min_ncc}, {self.refresh_ncc}")
        if self.lost_after_frames < 1:
            raise ValueError(f"lost_after_frames must be at least 1, got {self.lost_after_frames}")
        if not (0.0 < self.alpha <= 1.0 and 0.0 <= self.beta <= 2.0):
            raise ValueError(f"alpha must lie in (0, 1] and beta in [0, 2], got {self.alpha}, {self.beta}")
        if self.jacobian_step_px <= 0 or self.linear_radius_px < 0:
            raise ValueError(f"jacobian_step_px must be positive and linear_radius_px >= 0, got "
                             f"{self.jacobian_step_px}, {self.linear_radius_px}")


class TrackOutcome(enum.StrEnum):
    """How a track ended (`None` while it runs)."""

    STOPPED = "stopped"  # a client stopped it
    LOST = "lost"  # the patch was not found for lost_after_frames pairs
    NO_FRAMES = "no frames"  # no new stereo pair for frame_timeout_s
    NOT_FOUND = "target not trackable"  # no patch to track where it was asked (border, no texture)
    PREEMPTED = "preempted"  # a look or a newer track took the head
    HEAD_FAULT = "head fault"  # the servo bus went down, a servo faulted, torque went off
    SHUTDOWN = "shutdown"


class PoseHistory:
    """The last `size` (time, pose) samples, thread-safe; `at(t)` interpolates between the two
    around t. Times must not go back (an older sample is ignored)."""

    def __init__(self, size: int = 512, max_gap_s: float = 0.1) -> None:
        self.size = size
        self.max_gap_s = max_gap_s  # extrapolating past the newest sample by more than this: None
        self._times: list[float] = []
        self._poses: list[np.ndarray] = []
        self._lock = threading.Lock()

    def add(self, time_s: float, pose: np.ndarray) -> None:
        with self._lock:
            if self._times and time_s <= self._times[-1]:
                return
            self._times.append(float(time_s))
            self._poses.append(np.asarray(pose, dtype=float).copy())
            if len(self._times) > self.size:
                del self._times[0], self._poses[0]

    def clear(self) -> None:
        with self._lock:
            self._times.clear()
            self._poses.clear()

    def newest_s(self) -> float:
        """The newest sample's time (-inf when empty)."""
        with self._lock:
            return self._times[-1] if self._times else float("-inf")

    def __len__(self) -> int:
        with self._lock:
            return len(self._times)

    def at(self, time_s: float) -> np.ndarray | None:
        """The pose at `time_s`: interpolated between samples, the nearest one when `time_s` lies
        within `max_gap_s` beyond them, None when the history does not reach it."""
        with self._lock:
            if not self._times:
                return None
            i = bisect.bisect_left(self._times, time_s)
            if i == 0:
                t0 = self._times[0]
                return self._poses[0].copy() if t0 - time_s <= self.max_gap_s else None
            if i == len(self._times):
                t1 = self._times[-1]
                return self._poses[-1].copy() if time_s - t1 <= self.max_gap_s else None
            t0, t1 = self._times[i - 1], self._times[i]
            w = (time_s - t0) / (t1 - t0)
            pose: np.ndarray = (1.0 - w) * self._poses[i - 1] + w * self._poses[i]
            return pose


@dataclasses.dataclass(frozen=True)
class PatchMatch:
    """Where the patch is in one pair: (x, y) in the left image, d, and how well each matched."""

    x: float
    y: float
    d: float
    ncc: float
    d_ncc: float  # 0 when the right image gave no match (d is then the last known one)

    @property
    def position(self) -> np.ndarray:
        return np.array([self.x, self.y, self.d])


def _peak(scores: np.ndarray) -> tuple[float, float, float]:
    """(x, y, score) of the best score, refined to sub-pixel by a parabola on each axis."""
    _, best, _, (ix, iy) = cv2.minMaxLoc(scores)
    x, y = subpixel_peak(scores, iy, ix)
    return x, y, float(best)


class PatchTracker:
    """The target's patch, found again in each new pair (see the module docstring)."""

    def __init__(self, params: PursuitParams, disparity_range: tuple[float, float]) -> None:
        self.params = params
        self.disparity_range = disparity_range
        self.template: np.ndarray | None = None
        self.first: np.ndarray | None = None  # the template as taken at start: what drift is corrected to
        self.refreshes = 0
        self.row_offset_px = 0.0  # how far below the left patch's rows its right match lies

    def _take(self, left: np.ndarray, x: float, y: float) -> np.ndarray:
        size = self.params.patch_size_px
        return cv2.getRectSubPix(left, (size, size), (float(x), float(y)))

    def _inside(self, shape: tuple[int, ...], x: float, y: float) -> bool:
        half = self.params.patch_size_px / 2.0
        return half <= x <= shape[1] - 1 - half and half <= y <= shape[0] - 1 - half

    def _disparity(self, left: np.ndarray, right: np.ndarray, x: float, y: float,
                   d_hint: float | None) -> tuple[float, float]:
        size = self.params.patch_size_px
        if d_hint is None:
            search = self.disparity_range
        else:
            margin = self.params.disparity_search_px
            search = (max(self.disparity_range[0], d_hint - margin), min(self.disparity_range[1], d_hint + margin))
        band, rows = (self.params.row_band_px, 0.0) if d_hint is None else (DISPARITY_BAND_PX, self.row_offset_px)
        d, dy, ncc = stereo_offset(left, right, (x, y), (size, size), search, band, rows)
        if ncc >= self.params.min_ncc:
            self.row_offset_px = dy
        return d, ncc

    def start(self, left: np.ndarray, right: np.ndarray, x: float, y: float,
              d: float | None = None) -> PatchMatch | None:
        """Take the patch around (x, y) of the left image as the template; None if it does not
        fit in the image, is flat, or has no match in the right image (when `d` is not given)."""
        left, right = as_grey_float(left), as_grey_float(right)
        if not self._inside(left.shape, x, y):
            return None
        template = self._take(left, x, y)
        if float(template.std()) < 2.0:  # nothing to correlate
            return None
        d_ncc = 1.0
        if d is None:
            d, d_ncc = self._disparity(left, right, x, y, None)
            if d_ncc < self.params.min_ncc:
                return None
        self.template = self.first = template
        self.refreshes = 0
        return PatchMatch(float(x), float(y), float(d), 1.0, float(d_ncc))

    def _search(self, left: np.ndarray, template: np.ndarray, predicted: np.ndarray,
                radius: int) -> tuple[float, float, float] | None:
        """(x, y, NCC) of the best match of `template` within `radius` of `predicted` (x, y)."""
        h, w = left.shape
        size = self.params.patch_size_px
        # The window of top-left corners searched, within the image.
        x0 = int(np.floor(predicted[0] - (size - 1) / 2.0)) - radius
        y0 = int(np.floor(predicted[1] - (size - 1) / 2.0)) - radius
        x0, y0 = max(0, x0), max(0, y0)
        x1 = min(w, int(np.ceil(predicted[0] + (size - 1) / 2.0)) + radius + 1)
        y1 = min(h, int(np.ceil(predicted[1] + (size - 1) / 2.0)) + radius + 1)
        if x1 - x0 < size or y1 - y0 < size:
            return None
        scores = np.nan_to_num(cv2.matchTemplate(left[y0:y1, x0:x1], template, cv2.TM_CCOEFF_NORMED))
        u, v, ncc = _peak(scores)
        return x0 + u + (size - 1) / 2.0, y0 + v + (size - 1) / 2.0, ncc

    def find(self, left: np.ndarray, right: np.ndarray, predicted: np.ndarray,
             radius_px: float | None = None) -> PatchMatch | None:
        """The patch near `predicted` (x, y, d) in this pair, or None (not found).

        Found with the current template, then the first template is looked for within a few
        pixels of that place: while it still matches, its position wins, so that the template
        taken again and again does not drift off the point the track started on."""
        if self.template is None or self.first is None:
            raise RuntimeError("PatchTracker.find before start")
        p = self.params
        left, right = as_grey_float(left), as_grey_float(right)
        radius = int(np.ceil(radius_px if radius_px is not None else p.search_radius_px))
        found = self._search(left, self.template, predicted, radius)
        if found is None or found[2] < p.min_ncc:
            return None
        x, y, ncc = found
        if self.template is not self.first:
            anchored = self._search(left, self.first, np.array([x, y]), 3)
            if anchored is not None and anchored[2] >= p.min_ncc:
                x, y = anchored[0], anchored[1]
        if not self._inside(left.shape, x, y):
            return None
        d, d_ncc = self._disparity(left, right, x, y, float(predicted[2]))
        if d_ncc < p.min_ncc:
            d, d_ncc = float(predicted[2]), 0.0
        if ncc < p.refresh_ncc:
            self.template = self._take(left, x, y)
            self.refreshes += 1
        return PatchMatch(float(x), float(y), float(d), float(ncc), float(d_ncc))


# deg per px of a 320 px wide image through the paper's lens near its centre (4.1 px/deg): what
# pursuit uses while the map's own Jacobian is implausible (a young map). Pan and tilt turn
# against x and y; vergence against d, and pan by half of it (one eye's share).
DEFAULT_JACOBIAN = np.array([[-0.24, 0.0, -0.12], [0.0, -0.24, 0.0], [0.0, 0.0, -0.24]])
PLAUSIBLE_GAIN = (-2.0, -0.02)  # deg per px on the Jacobian's diagonal, as fine vergence's


class MapReader(Protocol):
    def command(self, position: Any) -> np.ndarray: ...


@dataclasses.dataclass(frozen=True)
class PursuitStep:
    """What one pair gave: the patch (or None), the retinal error, the goal to command (None:
    command nothing), misses in a row, and whether the track is lost."""

    exposure_s: float
    match: PatchMatch | None
    retinal_error_px: float | None  # |(x, y) - fovea|
    goal: np.ndarray | None
    misses: int
    lost: bool
    target_pose: np.ndarray | None = None  # the filtered target direction in motor space
    velocity_deg_s: np.ndarray | None = None


class Pursuit:
    """The control law over a map and a patch tracker; one `step` a pair."""

    def __init__(self, gaze_map: MapReader, image_size: tuple[int, int], disparity_range: tuple[float, float],
                 params: PursuitParams | None = None) -> None:
        self.map = gaze_map
        self.params = params or PursuitParams()
        self.width, self.height = image_size
        self.fovea = np.array([(self.width - 1) / 2.0, (self.height - 1) / 2.0, 0.0])
        self.tracker = PatchTracker(self.params, disparity_range)
        self.jacobian = DEFAULT_JACOBIAN.copy()  # the map's at start, when plausible
        self._map_takes_pose = "pose" in inspect.signature(gaze_map.command).parameters
        self.map_plausible = False  # whether the map's Jacobian was, at start (else its secant is not used either)
        self._q: np.ndarray | None = None  # the target's direction (motor space) at _t
        self._v = np.zeros(3)
        self._t = 0.0
        self._updates = 0
        self.misses = 0
        self.last: PatchMatch | None = None

    # -- the map ----------------------------------------------------------------------------
    def _command(self, position: np.ndarray, pose: np.ndarray) -> np.ndarray:
        if self._map_takes_pose:
            return np.asarray(self.map.command(position, pose=pose), dtype=float)  # type: ignore[call-arg]
        return np.asarray(self.map.command(position), dtype=float)

    def local_jacobian(self, pose: np.ndarray) -> np.ndarray:
        """d(command)/d(x, y, d) at the fovea: central differences of the map (deg per px)."""
        h = self.params.jacobian_step_px
        steps = np.array([h, h, h / 2.0])
        columns = []
        for axis in range(3):
            delta = np.zeros(3)
            delta[axis] = steps[axis]
            columns.append((self._command(self.fovea + delta, pose) - self._command(self.fovea - delta, pose))
                           / (2 * steps[axis]))
        return np.column_stack(columns)

    def _motor_offset(self, position: np.ndarray, pose: np.ndarray) -> np.ndarray:
        """The relative command that would put `position` on the foveae, from `pose`."""
        error = position - self.fovea
        if not self.map_plausible or float(np.hypot(error[0], error[1])) <= self.params.linear_radius_px:
            offset: np.ndarray = self.jacobian @ error
            return offset
        try:
            offset = self._command(position, pose) - self._command(self.fovea, pose)
        except OutOfRangeError:
            offset = self.jacobian @ error
        return offset

    def _predicted_position(self, exposure_s: float, pose: np.ndarray) -> np.ndarray:
        """Where the patch should be in a pair exposed at `exposure_s` from `pose`."""
        assert self._q is not None
        q = self._q + self._v * (exposure_s - self._t)
        try:
            error = np.linalg.solve(self.jacobian, q - pose)
        except np.linalg.LinAlgError:
            error = np.zeros(3)
        predicted = self.fovea + error
        if self.last is not None and not np.all(np.isfinite(predicted)):
            predicted = self.last.position
        return predicted

    def right_shift_px(self, right_lag_s: float, pose: np.ndarray, right_pose: np.ndarray | None) -> float:
        """How far (x, px) the patch moves in the right image from the left exposure (at `pose`)
        to the right one, `right_lag_s` later (at `right_pose`; None: the head's motion unknown,
        taken as none): the target's motion over the skew less the head's, through the Jacobian."""
        if not self.params.correct_skew or right_lag_s == 0.0:
            return 0.0
        head_motion = np.zeros(3) if right_pose is None else np.asarray(right_pose, dtype=float) - pose
        motion = self._v * right_lag_s - head_motion
        try:
            dx, _, dd = np.linalg.solve(self.jacobian, motion)
        except np.linalg.LinAlgError:
            return 0.0
        shift = float(dx + dd)  # x_right = x + d
        return shift if np.isfinite(shift) else 0.0

    # -- the track --------------------------------------------------------------------------
    def start(self, left: np.ndarray, right: np.ndarray, exposure_s: float, pose: np.ndarray,
              x: float, y: float, d: float | None = None, *, right_lag_s: float = 0.0,
              right_pose: np.ndarray | None = None) -> PursuitStep | None:
        """Take the patch at (x, y) in this pair (exposed at `exposure_s`, from `pose`; the right
        image `right_lag_s` later, from `right_pose`) and aim at it; None when there is no patch
        to track there."""
        match = self.tracker.start(left, right, x, y, d)
        if match is None:
            return None
        try:
            jacobian = self.local_jacobian(pose)
        except OutOfRangeError:
            jacobian = np.full((3, 3), np.nan)
        diagonal = np.diag(jacobian)
        self.map_plausible = bool(np.all(np.isfinite(jacobian)) and np.all(
            (PLAUSIBLE_GAIN[0] <= diagonal) & (diagonal <= PLAUSIBLE_GAIN[1])))
        if self.map_plausible:
            self.jacobian = jacobian
        else:
            self.jacobian = DEFAULT_JACOBIAN.copy()
            log.warning("the map's Jacobian at the fovea is implausible (diagonal %s deg/px; a young map?): "
                        "pursuit uses the default one", np.round(diagonal, 3))
        self._q, self._v, self._t, self._updates = None, np.zeros(3), exposure_s, 0
        self.misses = 0
        if d is None:  # measured in this pair: at the left image's time (the target's velocity not yet known)
            match = dataclasses.replace(match, d=match.d - self.right_shift_px(right_lag_s, pose, right_pose))
        return self._update(match, exposure_s, pose, exposure_s)

    def step(self, left: np.ndarray, right: np.ndarray, exposure_s: float, pose: np.ndarray,
             now_s: float, *, right_lag_s: float = 0.0, right_pose: np.ndarray | None = None) -> PursuitStep:
        """Find the patch in this pair (the left image exposed at `exposure_s` from `pose`, the
        right `right_lag_s` later from `right_pose`) and say what to command at `now_s`."""
        if self._q is None:
            raise RuntimeError("Pursuit.step before start")
        # The disparity is searched where the right image shows the patch, and brought back
        # to the left image's time once found.
        shift = np.array([0.0, 0.0, self.right_shift_px(right_lag_s, pose, right_pose)])
        predicted = self._predicted_position(exposure_s, pose)
        match = self.tracker.find(left, right, predicted + shift)
        if match is None and self.last is not None:  # a miss: look again, wider, around the last place
            wider = self.params.search_radius_px * (2 + self.misses)
            match = self.tracker.find(left, right, self.last.position + shift, radius_px=wider)
        if match is not None:
            match = dataclasses.replace(match, d=match.d - float(shift[2]))
        if match is None:
            self.misses += 1
            lost = self.misses >= self.params.lost_after_frames
            return PursuitStep(exposure_s, None, None, None, self.misses, lost, self._q, self._v.copy())
        self.misses = 0
        return self._update(match, exposure_s, pose, now_s)

    def _update(self, match: PatchMatch, exposure_s: float, pose: np.ndarray, now_s: float) -> PursuitStep:
        p = self.params
        self.last = match
        measured = pose + self._motor_offset(match.position, pose)
        if self._q is None:
            self._q = measured
        else:
            dt = max(exposure_s - self._t, 1e-3)
            predicted = self._q + self._v * dt
            residual = measured - predicted
            self._q = predicted + p.alpha * residual
            # The second measurement sets the velocity outright; later ones correct it.
            beta = 1.0 if self._updates == 1 else p.beta
            self._v = np.clip(self._v + beta * residual / dt, -p.max_speed_deg_s, p.max_speed_deg_s)
        self._t = exposure_s
        self._updates += 1
        goal = self._q + self._v * (now_s - exposure_s + p.lead_s)
        error = float(np.hypot(match.x - self.fovea[0], match.y - self.fovea[1]))
        return PursuitStep(exposure_s, match, error, goal, 0, False, self._q.copy(), self._v.copy())
