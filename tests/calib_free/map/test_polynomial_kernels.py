"""The polynomial part's compiled kernels against a plain numpy reference held here.

The references are the fit written the obvious numpy way (features as products of powers,
the tensor by fancy indexing, the RLS step as matrix algebra); the kernels must compute the
same numbers on random inputs, to round-off.
"""
from __future__ import annotations

import logging

import numpy as np
import pytest

from calib_free.map import _kernels
from calib_free.map.polynomial import NOISE_PRIOR, PRIOR, PolynomialPart, PosePolynomialPart

RTOL = 1e-9


# --- numpy references ---------------------------------------------------------------------
def reference_features(part: PolynomialPart | PosePolynomialPart, g: np.ndarray,
                       pose: np.ndarray | None = None) -> np.ndarray:
    u = g / part.half_span - 1.0
    if isinstance(part, PolynomialPart):
        return np.prod(u[None, :] ** part.terms, axis=1)
    assert pose is not None
    q = pose[1:] / part.pose_scale
    factors = np.prod(q[None, :] ** part.pose_terms, axis=1)
    position = np.prod(u[None, :] ** part.position_terms, axis=1)
    cross = np.prod(u[None, :] ** part.cross_terms, axis=1)
    return np.concatenate([position, (factors[:, None] * cross[None, :]).ravel()])


def reference_tensor(part: PolynomialPart | PosePolynomialPart, pose: np.ndarray | None = None) -> np.ndarray:
    n = part.degree + 1
    tensor = np.zeros((n, n, n, 3))
    if isinstance(part, PolynomialPart):
        tensor[tuple(part.terms.T)] = part.coef
        return tensor
    assert pose is not None
    n_pos, n_cross = len(part.position_terms), len(part.cross_terms)
    tensor[tuple(part.position_terms.T)] = part.coef[:n_pos]
    factors = np.prod((pose[1:] / part.pose_scale)[None, :] ** part.pose_terms, axis=1)
    pose_coef = part.coef[n_pos:].reshape(len(part.pose_terms), n_cross * 3)
    tensor[tuple(part.cross_terms.T)] += (factors @ pose_coef).reshape(n_cross, 3)
    return tensor


def reference_rls_step(coef: np.ndarray, covariance: np.ndarray, noise_variance: np.ndarray, phi: np.ndarray,
                       command: np.ndarray, confidence: float, memory: float,
                       samples: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The new (coef, covariance, noise_variance) after one weighted, forgetting RLS step."""
    forget = 1.0 - 1.0 / max(memory, 1.0)
    p_phi = covariance @ phi
    leverage = float(phi @ p_phi)
    residual = command - phi @ coef
    gain = p_phi * confidence / (forget + confidence * leverage)
    coef = coef + gain[:, None] * residual[None, :]
    rate = confidence / min(max(memory, 1.0), samples + 1.0)
    noise_variance = noise_variance + rate * (residual ** 2 / (1.0 + leverage) - noise_variance)
    covariance = (covariance - gain[:, None] * p_phi[None, :]) / forget
    covariance = 0.5 * (covariance + covariance.T)
    if np.min(np.diag(covariance)) <= 0.0 or not np.all(np.isfinite(covariance)):
        covariance = np.eye(len(phi)) * PRIOR
    limit = PRIOR * len(phi)
    if np.trace(covariance) > limit:
        covariance = covariance * (limit / np.trace(covariance))
    return coef, covariance, noise_variance


# --- fixtures ------------------------------------------------------------------------------
SHAPE = np.array([100, 75, 21])
COMMAND_RANGE = np.array([[-50.0, 50.0], [-35.0, 35.0], [-17.0, 17.0]])


def parts(seed: int, position_degree: int = 5, cross_degree: int = 2,
          pose_degree: int = 2) -> tuple[PolynomialPart, PosePolynomialPart]:
    """A pose-free part with random coefficients and covariance, and the pose-aware one built on
    it, its own coefficients and covariance random too."""
    rng = np.random.default_rng(seed)
    base = PolynomialPart(3, SHAPE, COMMAND_RANGE, rng)
    base.covariance = random_covariance(rng, len(base.terms))
    part = PosePolynomialPart(base, position_degree, cross_degree, pose_degree, (35.0, 17.0))
    part.coef = rng.normal(0.0, 5.0, size=part.coef.shape)
    part.covariance = random_covariance(rng, part.size)
    part.noise_variance = rng.uniform(0.1, 2.0, size=3)
    part.coefficients_changed()
    return base, part


def random_covariance(rng: np.random.Generator, n: int) -> np.ndarray:
    a = rng.normal(size=(n, n))
    return np.ascontiguousarray(a @ a.T / n + 0.1 * np.eye(n))


def random_input(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """A grid position (continuous node indices) and a pose (pan, tilt, vergence) in degrees."""
    return rng.uniform(0.0, SHAPE - 1.0), rng.uniform([-40.0, -25.0, 3.0], [40.0, 25.0, 20.0])


# --- tests ---------------------------------------------------------------------------------
@pytest.mark.parametrize("degrees", [(5, 2, 2), (3, 1, 1), (6, 3, 4), (3, 0, 1)])
def test_features_are_the_products_of_powers(degrees):
    rng = np.random.default_rng(1)
    base, part = parts(1, *degrees)
    for _ in range(50):
        g, pose = random_input(rng)
        np.testing.assert_allclose(base.features(g), reference_features(base, g), rtol=RTOL, atol=0)
        phi = part.features(g, pose)
        assert phi.shape == (part.size,)
        np.testing.assert_allclose(phi, reference_features(part, g, pose), rtol=RTOL, atol=0)


def test_features_at_the_grid_corners_and_centre():
    """Scaled positions -1, 0 and +1 exactly (0 ** 0 is 1)."""
    base, part = parts(2)
    for g in (np.zeros(3), SHAPE - 1.0, (SHAPE - 1.0) / 2.0):
        for pose in (np.zeros(3), np.array([10.0, 35.0, -17.0])):
            np.testing.assert_allclose(part.features(g, pose), reference_features(part, g, pose), rtol=RTOL, atol=0)
        np.testing.assert_allclose(base.features(g), reference_features(base, g), rtol=RTOL, atol=0)


@pytest.mark.parametrize("degrees", [(5, 2, 2), (6, 3, 4)])
def test_the_tensor_at_a_pose_is_the_reference_tensor_and_evaluates_to_the_features_value(degrees):
    rng = np.random.default_rng(3)
    base, part = parts(3, *degrees)
    np.testing.assert_allclose(base.tensor, reference_tensor(base), rtol=RTOL, atol=0)
    for _ in range(20):
        g, pose = random_input(rng)
        tensor = part.tensor_at(pose)
        expected = reference_tensor(part, pose)
        np.testing.assert_allclose(tensor, expected, rtol=RTOL, atol=RTOL * np.abs(expected).max())
        # The tensor at a pose and the features with that pose give the same value at g.
        node = np.rint(g).astype(int)
        value = _kernels.value_at_node(np.zeros((3, *SHAPE)), tensor, part.half_span, *node)
        np.testing.assert_allclose(value, part.at(node.astype(float), pose), rtol=1e-9, atol=1e-9)


def test_the_tensor_at_a_pose_is_rebuilt_when_the_coefficients_change():
    rng = np.random.default_rng(4)
    _, part = parts(4)
    _, pose = random_input(rng)
    before = part.tensor_at(pose).copy()
    part.learn(part.features(np.array([10.0, 20.0, 5.0]), pose), np.array([3.0, -2.0, 1.0]), 1.0, 100.0, 10)
    after = part.tensor_at(pose)
    assert not np.allclose(before, after)
    np.testing.assert_allclose(after, reference_tensor(part, pose), rtol=RTOL, atol=RTOL * np.abs(after).max())


def test_predictive_variance_is_the_quadratic_form_times_the_noise():
    rng = np.random.default_rng(5)
    base, part = parts(5)
    for _ in range(20):
        g, pose = random_input(rng)
        phi = part.features(g, pose)
        np.testing.assert_allclose(part.predictive_variance(phi), (phi @ part.covariance @ phi) * part.noise_variance,
                                   rtol=RTOL, atol=0)
        phi = base.features(g)
        np.testing.assert_allclose(base.predictive_variance(phi), (phi @ base.covariance @ phi) * base.noise_variance,
                                   rtol=RTOL, atol=0)


@pytest.mark.parametrize("pose_aware", [False, True])
def test_a_recursive_least_squares_step_is_the_reference_step(pose_aware):
    """One step from random states: coefficients, covariance and noise estimate as the
    matrix algebra computes them; the covariance exactly symmetric."""
    rng = np.random.default_rng(6)
    for trial in range(20):
        base, part = parts(100 + trial)
        fit = part if pose_aware else base
        g, pose = random_input(rng)
        phi = part.features(g, pose) if pose_aware else base.features(g)
        command = rng.normal(0.0, 10.0, size=3)
        confidence, memory, samples = rng.uniform(0.05, 1.0), rng.uniform(1.0, 400.0), int(rng.integers(0, 50))
        expected = reference_rls_step(fit.coef, fit.covariance, fit.noise_variance, phi, command, confidence,
                                      memory, samples)
        fit.learn(phi, command, confidence, memory, samples)
        for got, want in zip((fit.coef, fit.covariance, fit.noise_variance), expected):
            np.testing.assert_allclose(got, want, rtol=RTOL, atol=RTOL * np.abs(want).max())
        np.testing.assert_array_equal(fit.covariance, fit.covariance.T)


def test_a_learning_run_follows_the_reference_run():
    """300 steps on one state, the reference run alongside: the differences stay at round-off."""
    rng = np.random.default_rng(7)
    _, part = parts(7)
    coef, covariance, noise = part.coef.copy(), part.covariance.copy(), part.noise_variance.copy()
    for n in range(300):
        g, pose = random_input(rng)
        phi = part.features(g, pose)
        command = np.array([np.sin(g[0] / 20.0) * 30.0, pose[1] * 0.3 + g[1] * 0.1, g[2] * 0.5]) \
            + rng.normal(0.0, 0.1, size=3)
        memory = 30.0 + n
        coef, covariance, noise = reference_rls_step(coef, covariance, noise, phi, command, 0.8, memory, n)
        part.learn(phi, command, 0.8, memory, n)
    np.testing.assert_allclose(part.coef, coef, rtol=1e-8, atol=1e-8 * np.abs(coef).max())
    np.testing.assert_allclose(part.covariance, covariance, rtol=1e-8, atol=1e-8 * np.abs(covariance).max())
    np.testing.assert_allclose(part.noise_variance, noise, rtol=1e-8, atol=0)


def test_a_covariance_above_its_trace_limit_is_scaled_down_to_it():
    rng = np.random.default_rng(8)
    _, part = parts(8)
    part.covariance *= 50.0 * PRIOR * part.size / np.trace(part.covariance)
    g, pose = random_input(rng)
    phi = part.features(g, pose)
    command = np.array([1.0, 2.0, 3.0])
    expected = reference_rls_step(part.coef, part.covariance, part.noise_variance, phi, command, 1.0, 400.0, 10)
    part.learn(phi, command, 1.0, 400.0, 10)
    assert np.trace(part.covariance) == pytest.approx(PRIOR * part.size, rel=1e-12)
    np.testing.assert_allclose(part.covariance, expected[1], rtol=RTOL, atol=RTOL * np.abs(expected[1]).max())


@pytest.mark.parametrize("broken", ["negative diagonal", "not finite"])
def test_a_covariance_that_broke_starts_afresh_from_the_prior(broken, caplog):
    rng = np.random.default_rng(9)
    base, _ = parts(9)
    base.noise_variance = np.full(3, NOISE_PRIOR)
    if broken == "negative diagonal":
        base.covariance = -np.eye(len(base.terms))
    else:
        base.covariance[3, 4] = base.covariance[4, 3] = np.inf
    g, _ = random_input(rng)
    phi = base.features(g)
    with caplog.at_level(logging.WARNING, logger="calib_free.map.polynomial"):
        base.learn(phi, np.array([1.0, 2.0, 3.0]), 1.0, 100.0, 5)
    np.testing.assert_array_equal(base.covariance, np.eye(len(base.terms)) * PRIOR)
    assert "lost positive definiteness" in caplog.text and "20 terms" in caplog.text
