"""The gaze map W(x, y, d): image position -> relative motor command (paper II-A, II-D, II-E).

W is a lookup grid over (x, y, d) -- left-image pixel position and disparity d = x_r - x_l
-- whose nodes hold relative commands (dpan, dtilt, dverg) in degrees. It starts random and
learns online from fixations: a converged fixation says "the command m brought what was at
r* = (x*, y*, d*) onto both foveae", and W moves towards m around r* (eqs. 10-11) with a
Gaussian neighbourhood whose widths follow the windowed mean retinal error (eqs. 8-9).

Two profiles:
  - `paper`: the paper's rule as written, with Table I's values: nearest-node readout and
    inverse lookup, a fixed adaptation rate alpha, target m for every node in the
    neighbourhood.
  - `default`: the same grid, eqs. 8-11 and schedule, with what holds the paper's rule back
    removed (docs/method.md, "Two profiles"): W = P + R, P a cubic polynomial in (x, y, d) fitted by
    confidence-weighted recursive least squares, R the grid learning P's residual by eqs.
    10-11; a memory that shrinks when the error jumps (the head changed) and regrows; a
    Cauchy weight against confident false correspondences; trilinear readout and a sub-node
    inverse lookup; and, beyond the paper, a second fit of P that also takes the head's tilt
    and vergence when the pre-fixation images were taken (`pose=` of `command` and `adapt`;
    `calib_free.map.polynomial`). Without a pose the map answers from its pose-free P.

Indices: grid coordinates are continuous node indices (i, j, k) along (x, y, d); pixel and
disparity positions map onto them linearly, node 0 at the range's start and the last node
at its end. The image range is -0.5 .. width-0.5 (pixel centres at integers, origin at the
top-left pixel's centre), the disparity range as configured.
"""
from __future__ import annotations

import copy
import logging
import time
from collections import deque
from dataclasses import dataclass, field
from typing import Any, Sequence, TypeAlias

import numpy as np

from calib_free.map import _kernels
from calib_free.errors import OutOfRangeError
from calib_free.map.params import GazeMapParams
from calib_free.map.polynomial import PolynomialPart, PosePolynomialPart

log = logging.getLogger(__name__)

_NO_POLYNOMIAL = np.zeros((0, 0, 0, 3))

Vector: TypeAlias = Sequence[float] | np.ndarray


@dataclass
class AdaptResult:
    """What one adaptation did (or why it did not)."""

    accepted: bool
    reason: str = ""  # why a sample was refused; "" when accepted
    retinal_error: float = float("nan")  # eq. 8, a fraction of the half-ranges
    output_error: np.ndarray = field(default_factory=lambda: np.full(3, np.nan))  # |dW(r*)| per axis, deg
    mean_retinal_error: float = float("nan")  # E-bar of eq. 9
    sigma_cells: np.ndarray = field(default_factory=lambda: np.full(3, np.nan))  # eq. 9 widths, grid cells
    nodes_updated: int = 0


class GazeMap:
    """The learned map from image position (x, y, d) to relative command (dpan, dtilt, dverg).

    `grid` holds the SOM nodes (Table I's input size). In the `paper` profile it is W itself;
    in the `default` profile W = polynomial + grid, the grid learning by eqs. 10-11 what the
    polynomial leaves (so unvisited nodes are not left random).
    """

    COARSE_REFRESH = 8  # adaptations between refreshes of the inverse lookup's coarse table
    COARSE_CANDIDATES = 3  # coarse nodes refined at full resolution

    def __init__(self, params: GazeMapParams, seed: int | None = None,
                 grid: np.ndarray | None = None) -> None:
        self.params = params
        shape = tuple(params.grid_shape)
        rng = np.random.default_rng(seed)
        command_range = np.array(params.command_range, dtype=float)
        self.polynomial = (PolynomialPart(params.global_degree, np.array(shape), command_range, rng)
                           if params.global_degree > 0 else None)
        self.pose_polynomial: PosePolynomialPart | None = None
        self.derive_pose_polynomial()
        if grid is None:
            if self.polynomial is None:
                # "In all experiments the mapping has been initialized randomly" (III).
                grid = rng.uniform(command_range[:, 0], command_range[:, 1], size=shape + (3,))
                grid = grid.transpose(3, 0, 1, 2)
            else:
                grid = np.zeros((3,) + shape)
        grid = np.ascontiguousarray(grid, dtype=np.float64)
        if grid.shape != (3,) + shape:
            raise ValueError(f"grid must have shape {(3,) + shape} (planar: one plane per axis), got {grid.shape}")
        # Planar layout (axis, x, y, d): the neighbourhood update runs twice as fast as with
        # the command axis last.
        self.grid = grid
        self._coarse: np.ndarray | None = None  # W on the coarse subgrid, refreshed periodically
        self._coarse_age = 0
        self._pending_decay = 1.0  # residual-grid forgetting not yet applied
        self.recent_errors: deque[float] = deque(maxlen=params.error_window)
        self.long_run_error = float("nan")
        self.memory = params.global_memory  # fixations the polynomial part remembers now
        self.surprised = 0.0  # surprise summed over the consecutive surprising windows
        self.residual_scale = 1.0  # running median of |m - W(r*)|, output cells (robust weighting)
        self.adaptations = 0
        # Running mean square of |m - W(r*)| (output cells) of the map read without and with
        # the pose, over the samples that carry one: a pose is used while it predicts better.
        # Infinite until the first sample with a pose: a pose-aware fit that never learned.
        self.fit_errors = np.array([0.0, np.inf])
        self._setup_geometry()

    def _setup_geometry(self) -> None:
        p = self.params
        w, h = p.image_size
        # The image spans pixel edges to pixel edges: centres are at 0 .. w-1, so -0.5 .. w-0.5.
        self._low = np.array([-0.5, -0.5, p.disparity_range[0]])
        self._high = np.array([w - 0.5, h - 0.5, p.disparity_range[1]])
        self._shape = np.array(p.grid_shape)
        self._cells_per_unit = (self._shape - 1) / (self._high - self._low)
        # eq. 8: E_max is 50 % of each input dimension's size.
        self._error_max = p.retinal_error_max_fraction * (self._high - self._low)
        # eq. 9: sigma_max is 20 % of each input dimension's size, here in grid cells.
        self._sigma_max_cells = p.sigma_max_fraction * (self._shape - 1)
        cmd = np.array(p.command_range)
        # Table I's output size: the motor-space resolution, used as the inverse lookup's metric.
        self._motor_scale = np.array(p.output_resolution) / (cmd[:, 1] - cmd[:, 0])
        self._half_span = (self._shape - 1) / 2.0
        self._coarse_stride = (4, 4, 2)

    def derive_pose_polynomial(self) -> None:
        """(Re)build the pose-aware P from the pose-free one: where a new map, or an older file's, starts it."""
        p = self.params
        if self.polynomial is None or not p.uses_pose:
            self.pose_polynomial = None
            return
        half_span = [(high - low) / 2.0 for low, high in p.command_range[1:]]  # tilt, vergence
        self.pose_polynomial = PosePolynomialPart(self.polynomial, p.pose_position_degree, p.pose_cross_degree,
                                                  p.pose_degree, half_span)

    @classmethod
    def for_image(cls, width: int, height: int, disparity_range: Sequence[float] = (-60.0, 60.0),
                  seed: int | None = None, profile: str = "default", **overrides: Any) -> "GazeMap":
        """A random map for a `width` x `height` left image and a disparity range in pixels."""
        params = GazeMapParams.profile_values(
            profile, image_size=(int(width), int(height)),
            disparity_range=(float(disparity_range[0]), float(disparity_range[1])), **overrides)
        return cls(params, seed=seed)

    # -- positions ---------------------------------------------------------------------
    def check_position(self, position: Vector) -> str:
        """'' if the map covers `position` (x, y, d), else what is wrong with it."""
        r = np.asarray(position, dtype=float)
        if r.shape != (3,) or not np.all(np.isfinite(r)):
            return f"position must be 3 finite numbers (x, y, d), got {position!r}"
        names = ("x", "y", "d")
        for axis in range(3):
            if not self._low[axis] <= r[axis] <= self._high[axis]:
                what = "disparity range" if axis == 2 else "image"
                return (f"{names[axis]}={r[axis]:g} is outside the {what}: expected "
                        f"{self._low[axis]:g} <= {names[axis]} <= {self._high[axis]:g}")
        return ""

    def to_grid(self, position: Vector) -> np.ndarray:
        """Continuous node indices (i, j, k) of an image position (x, y, d)."""
        g: np.ndarray = (np.asarray(position, dtype=float) - self._low) * self._cells_per_unit
        return g

    def to_position(self, grid: Vector) -> np.ndarray:
        """Image position (x, y, d) of continuous node indices."""
        position: np.ndarray = np.asarray(grid, dtype=float) / self._cells_per_unit + self._low
        return position

    @staticmethod
    def check_pose(pose: Vector | None) -> str:
        """'' if `pose` is None or a pose (pan, tilt, vergence) the map can take, else what is wrong."""
        q = np.zeros(3) if pose is None else np.asarray(pose, dtype=float)
        if q.shape != (3,) or not np.all(np.isfinite(q)) or np.any(np.abs(q) > 360.0):
            return f"pose must be 3 finite angles (pan, tilt, vergence) within +-360 deg, got {pose!r}"
        return ""

    @property
    def pose_trusted(self) -> bool:
        """Whether the pose-aware fit answers lookups with a pose: while it has predicted the
        recent samples at least as well as the pose-free one. Right after the head changed the
        pose-free fit (a sixth of the terms) re-learns faster and answers until the other has
        caught up."""
        return self.pose_polynomial is not None and bool(self.fit_errors[1] <= self.fit_errors[0])  # inf: never

    def _pose_for_lookup(self, pose: Vector | None) -> np.ndarray | None:
        """The pose as an array if one is given and the pose-aware fit answers, else None."""
        return None if pose is None or not self.pose_trusted else np.asarray(pose, dtype=float)

    # -- readout -----------------------------------------------------------------------
    def command(self, position: Vector, pose: Vector | None = None) -> np.ndarray:
        """The relative command (dpan, dtilt, dverg) in degrees that fixates `position`.

        `pose`: the head's (pan, tilt, vergence) in degrees when the image the position was
        taken from was exposed. With it a map whose parameters use poses answers from its
        pose-aware fit; without it (or on a map that does not use poses) from its pose-free one.
        Raises OutOfRangeError for a position outside the image or the disparity range, or a
        pose that is not 3 finite angles.
        """
        problem = self.check_position(position) or self.check_pose(pose)
        if problem:
            raise OutOfRangeError(problem)
        return self._value_at(self.to_grid(position), self._pose_for_lookup(pose))

    def uncertainty(self, position: Vector, pose: Vector | None = None) -> float:
        """How uncertain the map is at `position` (and `pose`, as in `command`): the predictive
        variance of P's command there, deg^2 summed over the motor axes (the least-squares
        covariance along the position's features times the fit's running estimate of its
        samples' noise, 1 deg^2 an axis before any sample): large where few samples came within
        the memory. Without P (`paper` profile) 1.0 everywhere. Raises as `command` does."""
        problem = self.check_position(position) or self.check_pose(pose)
        if problem:
            raise OutOfRangeError(problem)
        g, q = self.to_grid(position), self._pose_for_lookup(pose)
        if self.pose_polynomial is not None and q is not None:
            return float(np.sum(self.pose_polynomial.predictive_variance(self.pose_polynomial.features(g, q))))
        return float(np.sum(self.polynomial.predictive_variance(self.polynomial.features(g)))) \
            if self.polynomial is not None else 1.0

    def _grid_at(self, g: np.ndarray) -> np.ndarray:
        if not self.params.interpolate:
            i, j, k = np.rint(g).astype(int)
            return self.grid[:, i, j, k].copy()
        base = np.minimum(np.floor(g).astype(int), self._shape - 2)
        f = g - base
        i, j, k = base
        cube = self.grid[:, i:i + 2, j:j + 2, k:k + 2].reshape(3, 8)
        fx, fy, fd = f
        weights = np.array([(1 - fx) * (1 - fy) * (1 - fd), (1 - fx) * (1 - fy) * fd,
                            (1 - fx) * fy * (1 - fd), (1 - fx) * fy * fd,
                            fx * (1 - fy) * (1 - fd), fx * (1 - fy) * fd,
                            fx * fy * (1 - fd), fx * fy * fd])
        value: np.ndarray = cube @ weights
        return value

    def _value_at(self, g: np.ndarray, pose: np.ndarray | None = None) -> np.ndarray:
        value = self._grid_at(g)
        if pose is not None and self.pose_polynomial is not None:
            value += self.pose_polynomial.at(g, pose)
        elif self.polynomial is not None:
            value += self.polynomial.at(g)
        return value

    def _block(self, lo: np.ndarray, hi: np.ndarray, stride: Sequence[int] | np.ndarray = (1, 1, 1),
               pose: np.ndarray | None = None) -> np.ndarray:
        """W at the nodes lo..hi (exclusive) with `stride`, planar: (3, a, b, c)."""
        values = self.grid[:, lo[0]:hi[0]:stride[0], lo[1]:hi[1]:stride[1], lo[2]:hi[2]:stride[2]]
        if pose is not None and self.pose_polynomial is not None:
            values = values + self.pose_polynomial.block(lo, hi, stride, pose)
        elif self.polynomial is not None:
            values = values + self.polynomial.block(lo, hi, stride)
        return values

    def node_values(self, pose: Vector | None = None) -> np.ndarray:
        """W at every node, (nx, ny, nd, 3) degrees (at `pose`, as in `command`)."""
        problem = self.check_pose(pose)
        if problem:
            raise OutOfRangeError(problem)
        values = self._block(np.zeros(3, int), self._shape, pose=self._pose_for_lookup(pose))
        return np.array(values.transpose(1, 2, 3, 0))

    # -- inverse lookup (eq. 8) ----------------------------------------------------------
    def inverse(self, command: Vector, pose: Vector | None = None) -> np.ndarray:
        """The image position (x, y, d) the map associates with `command` (eq. 8's x_d, y_d, d_d),
        at `pose` as in `command`.

        Nearest node in motor space, the metric scaled by Table I's output resolution; found
        coarse-to-fine (a strided subgrid, then full resolution around the best few coarse
        nodes). The coarse subgrid is a table of W refreshed every `COARSE_REFRESH` adaptations,
        read without a pose (at a pose, W moves by a few nodes at most, within the boxes
        searched around each candidate): it only nominates candidates, which are then compared
        on the current map at the pose. With `interpolate`, one Gauss-Newton step refines the
        result between nodes.
        """
        m = np.asarray(command, dtype=float)
        stride = np.array(self._coarse_stride)
        q = self._pose_for_lookup(pose)
        if self._coarse is None or self._coarse_age >= self.COARSE_REFRESH:
            self._coarse = np.array(self._block(np.zeros(3, int), self._shape, stride))
            self._coarse_age = 0
        coarse = self._coarse
        tensor = self._poly_tensor() if q is None or self.pose_polynomial is None else self.pose_polynomial.tensor_at(q)
        n_best = min(self.COARSE_CANDIDATES, coarse[0].size)
        centres = _kernels.best_coarse_nodes(coarse, m, self._motor_scale, n_best)
        starts = np.maximum(centres * stride - stride, 0)
        stops = np.minimum(centres * stride + stride + 1, self._shape)
        node, _ = _kernels.nearest_node(self.grid, tensor, self._half_span, m, self._motor_scale, starts, stops)
        if not self.params.interpolate:
            return self.to_position(node)
        # One Gauss-Newton step between nodes, the slopes from the neighbouring nodes.
        value, slopes = _kernels.value_and_slopes(self.grid, tensor, self._half_span, node, self._shape)
        scaled = slopes * self._motor_scale[:, None]
        residual = (m - value) * self._motor_scale
        # Normal equations with a small ridge: stable where the map is flat along an axis.
        step = np.linalg.solve(scaled.T @ scaled + 1e-6 * np.eye(3), scaled.T @ residual)
        g = np.clip(node + np.clip(step, -1.0, 1.0), 0.0, self._shape - 1.0)
        return self.to_position(g)

    def _poly_tensor(self) -> np.ndarray:
        return self.polynomial.tensor if self.polynomial is not None else _NO_POLYNOMIAL

    def warm_up(self) -> float:
        """Compile the inner loops now, on a throwaway copy (this map is not changed); returns
        the seconds it took.

        numba compiles on first call: several seconds on the first run after an install (then
        read from the cache beside `_kernels.py`). Paid here, at startup, it is not paid inside
        the first adaptation, where it would hold up everything waiting on the map.
        """
        start_s = time.perf_counter()
        scratch = copy.deepcopy(self)
        w, h = self.params.image_size
        centre = (w / 2.0, h / 2.0, sum(self.params.disparity_range) / 2.0)
        scratch.adapt(centre, scratch.command(centre), confidence=1.0)
        scratch.adapt(centre, scratch.command(centre), confidence=1.0, pose=(0.0, 0.0, 10.0))  # and with a pose
        return time.perf_counter() - start_s

    # -- learning ----------------------------------------------------------------------
    def retinal_error(self, found: Vector, expected: Vector) -> float:
        """Eq. 8: the distance between two image positions, as a fraction of the half-ranges."""
        diff = (np.asarray(found, dtype=float) - np.asarray(expected, dtype=float)) / self._error_max
        return float(np.sqrt(np.sum(diff ** 2)))

    def _sigmoid(self, mean_error: float) -> float:
        """Eq. 9's sigmoid of the windowed mean retinal error, in (0, 1)."""
        p = self.params
        return float(1.0 / (1.0 + np.exp(-p.adaptation_slope * (mean_error - p.adaptation_threshold))))

    def sigma_cells(self, mean_error: float) -> np.ndarray:
        """Eq. 9: the neighbourhood widths (grid cells) for a windowed mean retinal error."""
        return self._sigma_max_cells * self._sigmoid(mean_error)

    def adapt(self, position: Vector, command: Vector, confidence: float = 1.0,
              pose: Vector | None = None) -> AdaptResult:
        """Learn that `command` fixated what was at `position` (x*, y*, d*), with a confidence.

        `pose`: the head's (pan, tilt, vergence) in degrees when the pre-fixation images were
        taken. With it, a map that uses poses fits its pose-aware P too, and measures the
        sample against it (retinal error, residual); the pose-free P learns from every sample.
        A position outside the map, a non-finite command, a confidence outside (0, 1] or a
        pose that is not 3 finite angles is refused (nothing learned) and the result says why.
        """
        problem = self.check_position(position) or self.check_pose(pose)
        m = np.asarray(command, dtype=float)
        if not problem and (m.shape != (3,) or not np.all(np.isfinite(m))):
            problem = f"command must be 3 finite numbers (dpan, dtilt, dverg), got {command!r}"
        if not problem and not (0.0 < confidence <= 1.0):
            problem = f"confidence must be in (0, 1], got {confidence!r}"
        if problem:
            log.debug("adaptation refused: %s", problem)
            return AdaptResult(accepted=False, reason=problem)
        c = float(confidence)
        g = self.to_grid(position)
        polynomial = self.polynomial
        pose_polynomial = self.pose_polynomial
        q = self._pose_for_lookup(pose)  # the pose, if the map reads it for this sample
        value = self._grid_at(g)
        phi_pose: np.ndarray | None = None
        if polynomial is not None:
            phi = polynomial.features(g)
            if pose_polynomial is not None and pose is not None:
                if not np.isfinite(self.fit_errors[1]):
                    # The first sample with a pose: the pose-aware fit starts from what the
                    # pose-free one has learned so far (from samples without poses).
                    self.derive_pose_polynomial()
                    pose_polynomial = self.pose_polynomial
                    assert pose_polynomial is not None
                phi_pose = pose_polynomial.features(g, np.asarray(pose, dtype=float))
                free = value + phi @ polynomial.coef
                aware = value + phi_pose @ pose_polynomial.coef
                value = aware if q is not None else free
                squares = np.array([np.sum(((m - v) * self._motor_scale) ** 2) for v in (free, aware)])
                if np.isfinite(self.fit_errors[1]):
                    self.fit_errors += (squares - self.fit_errors) / min(self.adaptations + 1,
                                                                         2 * self.params.error_window)
                else:
                    self.fit_errors = squares
            else:
                value = value + phi @ polynomial.coef
        # Output error: |dW(x*, y*, d*)| of eq. 11 at the peak of the neighbourhood (G = 1).
        output_error = np.abs(c * (value - m))
        # Eq. 8: where the map, before this adaptation, would have put the target of m.
        error = self.retinal_error(position, self.inverse(m, q))
        self.recent_errors.append(error)
        mean_error = float(np.mean(self.recent_errors))
        # For telling a changed head from a false correspondence: the median of the window
        # (one wild sample does not move it, a change of the head moves them all) against its
        # long-run level, an average over about `global_memory` fixations.
        recent_median = float(np.median(self.recent_errors))
        if self.adaptations == 0:
            self.long_run_error = recent_median
        self.long_run_error += (recent_median - self.long_run_error) / min(self.adaptations + 1,
                                                                            self.params.global_memory)
        sigma = self.sigma_cells(mean_error)
        target = m
        if polynomial is not None:
            p = self.params
            # When the windowed error jumps far above its long-run level the head has changed (lens,
            # baseline, offset) and what was learned before is wrong: the memory drops to its
            # minimum, then grows by one a fixation, so the fit weighs the samples since the
            # change about equally until it remembers `global_memory` fixations again.
            surprise = recent_median / max(self.long_run_error, 1e-3)
            residual = float(np.linalg.norm((m - value) * self._motor_scale))  # output cells
            # Only a surprise that outlasts a window counts. The errors of a right map are
            # heavy-tailed (learning from images, about one in six is over 3x the long-run
            # level), so a window's median tops the threshold for a few adaptations in a row
            # every few hundred: each such false alarm cut the fit to `global_memory_min`
            # fixations and faded the residual grid, and the landing error drifted up over a
            # long run (docs/results/online.md). A changed head keeps the windows high:
            # their surprise, in thresholds, is summed until it makes `error_window` (a window
            # 3x over the long-run level counts 1: 10 in a row; a prism's 10-15x counts 3-5).
            # The false alarms measured summed to 4.3 at most. While the memory regrows after a
            # change, the head is still being re-learned: one surprising window renews it.
            surprised_before = self.surprised
            if surprise > p.surprise_threshold:
                self.surprised += surprise / p.surprise_threshold
            else:
                self.surprised = 0.0
            if pose_polynomial is not None and self.surprised >= p.error_window > surprised_before:
                # The head changed: the pose-aware fit starts over from what it holds, its
                # covariance back to the prior (with five times the terms of the pose-free one
                # it would otherwise take many memories to unlearn the old head); the pose-free
                # fit answers until it has caught up (`pose_trusted`).
                pose_polynomial.restart()
            recovering = self.memory < p.global_memory
            if self.surprised >= p.error_window or (recovering and self.surprised > 0.0):
                self.memory = p.global_memory_min
                self.residual_scale = max(residual, 1e-3)
            else:
                self.memory = min(p.global_memory, self.memory + 1.0)
            memory = self.memory
            if p.robust_scale > 0:
                # A sample far off what the map predicts, compared with how far off samples
                # usually are, is more likely a false correspondence (repetitive texture)
                # than news: Cauchy weight. The usual distance is tracked as a running median.
                c *= 1.0 / (1.0 + (residual / (p.robust_scale * self.residual_scale)) ** 2)
                self.residual_scale *= np.exp(0.05 if residual > self.residual_scale else -0.05)
            polynomial.learn(phi, m, c, memory, self.adaptations)
            if pose_polynomial is not None and phi_pose is not None:
                pose_polynomial.learn(phi_pose, m, c, memory, self.adaptations)
            # The residual grid forgets at the same pace: residuals learned against an old
            # polynomial must not outlive it. Applied in batches (one pass over the grid).
            self._pending_decay *= 1.0 - 1.0 / memory
            if self._pending_decay < 0.95:
                self.settle()
            # The grid learns the residual (of the fit this sample was read from).
            target = m - phi @ polynomial.coef
            if pose_polynomial is not None and phi_pose is not None and q is not None:
                target = m - phi_pose @ pose_polynomial.coef
        touched = self._update(g, target, c, sigma)
        self.adaptations += 1
        return AdaptResult(accepted=True, retinal_error=error, output_error=output_error,
                           mean_retinal_error=mean_error, sigma_cells=sigma, nodes_updated=touched)

    def _update(self, g: np.ndarray, target: np.ndarray, c: float, sigma: np.ndarray) -> int:
        """Eqs. 10-11 on the grid, over the window where G is not negligible; returns nodes touched."""
        p = self.params
        reach = sigma * np.sqrt(-2.0 * np.log(p.gaussian_cutoff))
        # alpha * c * G(x, y, d): eq. 10's step times eq. 11's confidence and neighbourhood
        touched = _kernels.update_window(self.grid, g, np.asarray(target, dtype=float), p.adaptation_rate * c,
                                         sigma, reach, self._shape)
        self._coarse_age += 1
        return int(touched)

    # -- persistence -------------------------------------------------------------------
    def settle(self) -> None:
        """Apply the batched residual forgetting and drop caches, so that the map is exactly its
        saved arrays: a map and its reloaded copy then continue identically."""
        if self._pending_decay != 1.0:
            self.grid *= self._pending_decay
            self._pending_decay = 1.0
        self._coarse = None
