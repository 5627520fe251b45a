"""The polynomial part P of the gaze map in the default profile (W = P + R, docs/method.md).

Two fits of the same samples by confidence-weighted, exponentially forgetting recursive least
squares:

- `PolynomialPart`: P(x, y, d), a polynomial in the image position alone (the paper's
  representation, section II-A);
- `PosePolynomialPart`: P(x, y, d; tilt, vergence), which also takes the head's pose when the
  pre-fixation images were taken. The image of a point rotates with tilt and vergence (the
  pan axis is tilted in the eye's frame, the tilt axis yawed by the eye), so the command that
  fixates (x, y, d) depends on them; a fit on (x, y, d) alone cannot learn that part and
  averages it out. Its features are the monomials of (x, y, d) up to `position_degree` and,
  for every monomial of (tilt, vergence) of degree 1 to `pose_degree`, that monomial times
  the monomials of (x, y, d) up to `cross_degree`. Pan is left out: turning the head about
  its vertical axis changes nothing the command depends on.

At a given pose the pose-aware fit is again a polynomial in (x, y, d) (`tensor_at`), so the
map's kernels (node search, slopes, blocks of nodes) serve both.

Coordinates: grid indices scaled to [-1, 1] per axis; tilt and vergence in degrees divided by
the half-span of their relative command range.

Both fits build their features, take their least-squares steps and (at a pose) their tensors
with the same compiled kernels (`calib_free.map._kernels`): the pose-free fit is the pose-aware
one without pose terms.
"""
from __future__ import annotations

import abc
import itertools
import logging
from typing import Sequence

import numpy as np

from calib_free.map import _kernels

log = logging.getLogger(__name__)

PRIOR = 100.0  # P0 = 100 I: a weak prior, the first samples dominate at once
NOISE_PRIOR = 1.0  # deg^2 per motor axis: the noise variance assumed before any sample
_NO_CROSS_TERMS = np.zeros((0, 3), dtype=np.int64)  # the pose-free fit has no pose terms
_NO_POSE_TERMS = np.zeros((0, 2), dtype=np.int64)
_NO_POSE = np.zeros(2)


def monomials(variables: int, degree: int) -> np.ndarray:
    """Exponents (n, variables) of every monomial of total degree <= `degree`, in a fixed order."""
    terms = [e for e in itertools.product(range(degree + 1), repeat=variables) if sum(e) <= degree]
    ordered = sorted(terms, key=lambda e: (sum(e), tuple(-v for v in e)))
    return np.array(ordered, dtype=np.int64).reshape(-1, variables)


def _position_terms(degree: int) -> np.ndarray:
    """The (x, y, d) monomials of `PolynomialPart`, in the order its saved coefficients have (map files depend on it)."""
    return np.array([(i, j, k) for i in range(degree + 1) for j in range(degree + 1 - i)
                     for k in range(degree + 1 - i - j)], dtype=np.int64)


class _RecursiveFit(abc.ABC):
    """Coefficients (n, 3) fitted by weighted, forgetting recursive least squares, with a
    running estimate of each motor axis's noise variance (for `predictive_variance`)."""

    coef: np.ndarray
    covariance: np.ndarray
    noise_variance: np.ndarray  # (3,), deg^2; NOISE_PRIOR until samples say otherwise

    @abc.abstractmethod
    def coefficients_changed(self) -> None:
        """What a subclass derives from `coef` is out of date."""

    def learn(self, phi: np.ndarray, command: np.ndarray, confidence: float, memory: float, samples: int = 0) -> None:
        """One weighted RLS step on features `phi` (of the sample) and its command, forgetting
        with the map's `memory` (fixations); `samples` learned before it.

        The noise estimate averages over the memory (its first samples at once). Round-off
        makes P drift from symmetric and, thousands of samples on, indefinite, and then the fit
        diverges: the kernel keeps it symmetric, and a P that broke starts afresh. Forgetting
        inflates P along directions no sample excites: its trace is bounded.
        """
        forget = 1.0 - 1.0 / max(memory, 1.0)
        noise_rate = confidence / min(max(memory, 1.0), samples + 1.0)
        size = len(phi)
        healthy = _kernels.rls_step(self.coef, self.covariance, self.noise_variance, np.asarray(phi, dtype=float),
                                    np.asarray(command, dtype=float), float(confidence), forget, noise_rate,
                                    PRIOR * size)
        self.coefficients_changed()
        if not healthy:
            log.warning("gaze map: the least-squares covariance (%d terms) lost positive definiteness; reset", size)
            self.covariance = np.eye(size) * PRIOR

    def predictive_variance(self, phi: np.ndarray) -> np.ndarray:
        """Variance (3,) of the fit's value at features `phi`, deg^2 per motor axis."""
        variance: np.ndarray = _kernels.quadratic_form(self.covariance, np.asarray(phi, dtype=float)) \
            * self.noise_variance
        return variance


def block_values(tensor: np.ndarray, powers: Sequence[np.ndarray]) -> np.ndarray:
    """Values (3, a, b, c) of the polynomial with dense coefficient tensor (n, n, n, 3) at the
    nodes whose per-axis powers (a, n), (b, n), (c, n) are given."""
    px, py, pd = powers
    n = tensor.shape[0]
    # Contract one axis at a time with plain matmuls (einsum's path search costs more here).
    t = (px @ tensor.reshape(n, -1)).reshape(len(px), n, n * 3)  # (a, j, k*m)
    t = np.matmul(py, t).reshape(len(px), len(py), n, 3)  # (a, b, k, m)
    values: np.ndarray = np.matmul(pd, t).transpose(3, 0, 1, 2)  # (m, a, b, c)
    return values


class _Powers:
    """Per-axis powers of the scaled node indices, cached by (axis, range, stride)."""

    def __init__(self, half_span: np.ndarray, degree: int) -> None:
        self.half_span = half_span
        self.degree = degree
        self._cache: dict[tuple[int, int, int, int], np.ndarray] = {}

    def __call__(self, lo: np.ndarray, hi: np.ndarray, stride: Sequence[int] | np.ndarray) -> list[np.ndarray]:
        return [self._axis(a, int(lo[a]), int(hi[a]), int(stride[a])) for a in range(3)]

    def _axis(self, axis: int, lo: int, hi: int, stride: int) -> np.ndarray:
        key = (axis, lo, hi, stride)
        powers = self._cache.get(key)
        if powers is None:
            unit = np.arange(lo, hi, stride, dtype=float) / self.half_span[axis] - 1.0
            powers = unit[:, None] ** np.arange(self.degree + 1)[None, :]
            if len(self._cache) < 4096:
                self._cache[key] = powers
        return powers


class PolynomialPart(_RecursiveFit):
    """P(x, y, d): the smooth global part of W in the default profile.

    Fitted by exponentially weighted recursive least squares, each sample weighted by its
    confidence; the forgetting factor follows the map's memory, so the fit remembers
    `global_memory` fixations while the map is right and only `global_memory_min` right after
    the head has changed.
    """

    def __init__(self, degree: int, shape: np.ndarray, command_range: np.ndarray, rng: np.random.Generator):
        self.degree = degree
        self.terms = _position_terms(degree)
        self.half_span = (shape - 1) / 2.0
        self._powers = _Powers(self.half_span, degree)
        n = len(self.terms)
        # Random initialisation like the paper's: a random smooth map, not a learned one.
        centre = command_range.mean(axis=1)
        span = command_range[:, 1] - command_range[:, 0]
        self.coef = rng.normal(0.0, 0.1, size=(n, 3)) * span
        self.coef[0] = centre + rng.uniform(-0.25, 0.25, size=3) * span
        self.prior = PRIOR
        self.covariance = np.eye(n) * self.prior
        self.noise_variance = np.full(3, NOISE_PRIOR)
        self.coefficients_changed()

    def coefficients_changed(self) -> None:
        """Rebuild the dense (i, j, k, axis) coefficient tensor `block` contracts with."""
        self.tensor = _kernels.polynomial_tensor(self.coef, self.terms, _NO_CROSS_TERMS, _NO_POSE, _NO_POSE_TERMS,
                                                 self.degree)

    def features(self, g: np.ndarray) -> np.ndarray:
        """The monomials `terms` of the grid position `g` scaled to [-1, 1]."""
        u = np.asarray(g, dtype=float) / self.half_span - 1.0
        phi: np.ndarray = _kernels.polynomial_features(u, self.terms, _NO_CROSS_TERMS, _NO_POSE, _NO_POSE_TERMS,
                                                       self.degree)
        return phi

    def at(self, g: np.ndarray) -> np.ndarray:
        value: np.ndarray = self.features(g) @ self.coef
        return value

    def block(self, lo: np.ndarray, hi: np.ndarray, stride: Sequence[int] | np.ndarray = (1, 1, 1)) -> np.ndarray:
        """Values at the nodes lo..hi (exclusive) with `stride`: (3, a, b, c)."""
        return block_values(self.tensor, self._powers(lo, hi, stride))


class PosePolynomialPart(_RecursiveFit):
    """P(x, y, d; tilt, vergence), fitted on the samples that carry the head's pose.

    It starts as the pose-free part `base` is (its coefficients, and its covariance over them;
    the prior on every other term), so a map that learned without poses keeps what it learned
    and adds the pose's part as samples with poses come.
    """

    def __init__(self, base: PolynomialPart, position_degree: int, cross_degree: int, pose_degree: int,
                 pose_scale: Sequence[float]) -> None:
        self.half_span = base.half_span
        self.position_terms = _position_terms(max(position_degree, base.degree))
        self.cross_terms = _position_terms(cross_degree)
        self.pose_terms = monomials(2, pose_degree)[1:]  # (tilt, vergence) exponents, degree 1..
        self.degree = max(position_degree, base.degree, cross_degree)
        self.pose_scale = np.asarray(pose_scale, dtype=float)  # (tilt, vergence) deg per unit
        self._powers = _Powers(self.half_span, self.degree)
        n_pos, n_cross = len(self.position_terms), len(self.cross_terms)
        self.size = n_pos + len(self.pose_terms) * n_cross
        position_of = {tuple(t): n for n, t in enumerate(self.position_terms)}
        self._base_rows = np.array([position_of[tuple(t)] for t in base.terms], dtype=int)
        self.coef = np.zeros((self.size, 3))
        self.coef[self._base_rows] = base.coef
        self.covariance = np.eye(self.size) * PRIOR
        self.covariance[np.ix_(self._base_rows, self._base_rows)] = base.covariance
        self.noise_variance = np.array(base.noise_variance, dtype=float)
        self._tensor_pose: tuple[float, float] | None = None
        self._tensor = np.zeros((self.degree + 1,) * 3 + (3,))
        self.coefficients_changed()

    def coefficients_changed(self) -> None:
        self._tensor_pose = None

    def unit_pose(self, pose: np.ndarray) -> np.ndarray:
        """(tilt, vergence) of a pose (pan, tilt, vergence), scaled by `pose_scale`."""
        q: np.ndarray = np.asarray(pose, dtype=float)[1:] / self.pose_scale
        return q

    def features(self, g: np.ndarray, pose: np.ndarray) -> np.ndarray:
        """The monomials `position_terms` of the grid position `g` scaled to [-1, 1], then each
        (tilt, vergence) monomial of `pose_terms` times each of `cross_terms`."""
        u = np.asarray(g, dtype=float) / self.half_span - 1.0
        phi: np.ndarray = _kernels.polynomial_features(u, self.position_terms, self.cross_terms, self.unit_pose(pose),
                                                       self.pose_terms, self.degree)
        return phi

    def at(self, g: np.ndarray, pose: np.ndarray) -> np.ndarray:
        value: np.ndarray = self.features(g, pose) @ self.coef
        return value

    def tensor_at(self, pose: np.ndarray) -> np.ndarray:
        """The dense (i, j, k, axis) coefficient tensor of P(x, y, d) at this pose."""
        key = (float(pose[1]), float(pose[2]))
        if self._tensor_pose != key:
            self._tensor = _kernels.polynomial_tensor(self.coef, self.position_terms, self.cross_terms,
                                                      self.unit_pose(pose), self.pose_terms, self.degree)
            self._tensor_pose = key
        return self._tensor

    def block(self, lo: np.ndarray, hi: np.ndarray, stride: Sequence[int] | np.ndarray,
              pose: np.ndarray) -> np.ndarray:
        """Values at the nodes lo..hi (exclusive) with `stride` at this pose: (3, a, b, c)."""
        return block_values(self.tensor_at(pose), self._powers(lo, hi, stride))

    def restart(self) -> None:
        """Keep the coefficients but trust them no more than the prior: the next samples
        determine the fit as the first ones of a new map do."""
        self.covariance = np.eye(self.size) * PRIOR
