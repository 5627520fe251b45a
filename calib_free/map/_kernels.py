"""Compiled inner loops of the gaze map (numba): the neighbourhood update, the node search and
the polynomial part's least-squares fit.

All run on every adaptation: the first two over a few thousand nodes, the fit over 20 and 106
terms (features, one recursive least-squares step, the coefficient tensor at a pose). Written
with numpy each costs a dozen temporary arrays and as many Python-level calls; here each is
one pass with no temporaries but its result. `cache=True` keeps the compiled code beside
this file, so only the first process pays the compile time.

Layout: the grid is planar, (3, nx, ny, nd). The polynomial part of W (default profile) is
passed as its dense coefficient tensor (n, n, n, 3) and per-axis scaling to [-1, 1]; a fit's
terms as exponent arrays (`calib_free.map.polynomial`).
"""
from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, nogil=True)
def update_window(grid: np.ndarray, centre: np.ndarray, target: np.ndarray, rate_scale: float, sigma: np.ndarray,
                  reach: np.ndarray, shape: np.ndarray) -> int:
    """grid[:, q] += rate_scale * G(q) * (target - grid[:, q]) where G(q) is not negligible.

    G is the separable Gaussian of eq. 11 centred at `centre` (continuous node indices) with
    widths `sigma` (cells); `reach` is where it falls below the cutoff. Returns nodes touched.
    """
    lo = np.empty(3, np.int64)
    hi = np.empty(3, np.int64)
    for a in range(3):
        lo[a] = max(int(np.ceil(centre[a] - reach[a])), 0)
        hi[a] = min(int(np.floor(centre[a] + reach[a])) + 1, shape[a])
        if hi[a] <= lo[a]:
            return 0
    gx = np.exp(-0.5 * ((np.arange(lo[0], hi[0]) - centre[0]) / sigma[0]) ** 2) * rate_scale
    gy = np.exp(-0.5 * ((np.arange(lo[1], hi[1]) - centre[1]) / sigma[1]) ** 2)
    gd = np.exp(-0.5 * ((np.arange(lo[2], hi[2]) - centre[2]) / sigma[2]) ** 2)
    t0, t1, t2 = target[0], target[1], target[2]
    for i in range(hi[0] - lo[0]):
        for j in range(hi[1] - lo[1]):
            wij = gx[i] * gy[j]
            x = lo[0] + i
            y = lo[1] + j
            for k in range(hi[2] - lo[2]):
                w = wij * gd[k]
                d = lo[2] + k
                grid[0, x, y, d] += w * (t0 - grid[0, x, y, d])
                grid[1, x, y, d] += w * (t1 - grid[1, x, y, d])
                grid[2, x, y, d] += w * (t2 - grid[2, x, y, d])
    touched: int = (hi[0] - lo[0]) * (hi[1] - lo[1]) * (hi[2] - lo[2])
    return touched


@njit(cache=True, nogil=True)
def _powers(value: float, degree: int) -> np.ndarray:
    out = np.empty(degree + 1)
    out[0] = 1.0
    for n in range(1, degree + 1):
        out[n] = out[n - 1] * value
    return out


@njit(cache=True, nogil=True)
def value_at_node(grid: np.ndarray, tensor: np.ndarray, half_span: np.ndarray, x: int, y: int, d: int) -> np.ndarray:
    """W at one node: the grid plus, when `tensor` is not empty, the polynomial."""
    out = np.empty(3)
    for a in range(3):
        out[a] = grid[a, x, y, d]
    n = tensor.shape[0]
    if n == 0:
        return out
    px = _powers(x / half_span[0] - 1.0, n - 1)
    py = _powers(y / half_span[1] - 1.0, n - 1)
    pd = _powers(d / half_span[2] - 1.0, n - 1)
    for i in range(n):
        for j in range(n - i):
            pij = px[i] * py[j]
            for k in range(n - i - j):
                p = pij * pd[k]
                for a in range(3):
                    out[a] += p * tensor[i, j, k, a]
    return out


@njit(cache=True, nogil=True)
def nearest_node(grid: np.ndarray, tensor: np.ndarray, half_span: np.ndarray, command: np.ndarray,
                 motor_scale: np.ndarray, starts: np.ndarray, stops: np.ndarray) -> tuple[np.ndarray, float]:
    """The node whose W is nearest `command` (metric scaled per motor axis) over boxes of nodes.

    `starts`/`stops` (b, 3) are the boxes' first and one-past-last node indices. Returns the
    best node's indices and its squared distance. The polynomial is summed separably (x, y
    first, then d) with no allocation per node.
    """
    n = tensor.shape[0]
    best = np.zeros(3, np.int64)
    best_dist = np.inf
    partial = np.zeros((max(n, 1), 3))
    for b in range(starts.shape[0]):
        for x in range(starts[b, 0], stops[b, 0]):
            px = _powers(x / half_span[0] - 1.0, max(n - 1, 0))
            for y in range(starts[b, 1], stops[b, 1]):
                if n > 0:
                    py = _powers(y / half_span[1] - 1.0, n - 1)
                    partial[:] = 0.0
                    for i in range(n):
                        for j in range(n - i):
                            pij = px[i] * py[j]
                            for k in range(n - i - j):
                                for a in range(3):
                                    partial[k, a] += pij * tensor[i, j, k, a]
                for d in range(starts[b, 2], stops[b, 2]):
                    u = d / half_span[2] - 1.0
                    dist = 0.0
                    for a in range(3):
                        w = grid[a, x, y, d]
                        pk = 1.0
                        for k in range(n):
                            w += partial[k, a] * pk
                            pk *= u
                        e = (w - command[a]) * motor_scale[a]
                        dist += e * e
                    if dist < best_dist:
                        best_dist = dist
                        best[0] = x
                        best[1] = y
                        best[2] = d
    return best, best_dist


@njit(cache=True, nogil=True)
def value_and_slopes(grid: np.ndarray, tensor: np.ndarray, half_span: np.ndarray, node: np.ndarray,
                     shape: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """W at a node and its central-difference slopes dW/d(node index), (3,) and (3 axes of W, 3)."""
    centre = value_at_node(grid, tensor, half_span, node[0], node[1], node[2])
    slopes = np.zeros((3, 3))
    for axis in range(3):
        up = node.copy()
        down = node.copy()
        up[axis] = min(node[axis] + 1, shape[axis] - 1)
        down[axis] = max(node[axis] - 1, 0)
        span = up[axis] - down[axis]
        if span == 0:
            continue
        w_up = value_at_node(grid, tensor, half_span, up[0], up[1], up[2])
        w_down = value_at_node(grid, tensor, half_span, down[0], down[1], down[2])
        for a in range(3):
            slopes[a, axis] = (w_up[a] - w_down[a]) / span
    return centre, slopes


@njit(cache=True, nogil=True)
def best_coarse_nodes(coarse: np.ndarray, command: np.ndarray, motor_scale: np.ndarray, count: int) -> np.ndarray:
    """Indices (count, 3) into the coarse table (3, a, b, c) of the `count` nodes nearest `command`."""
    keep_dist = np.full(count, np.inf)
    keep = np.zeros((count, 3), np.int64)
    for x in range(coarse.shape[1]):
        for y in range(coarse.shape[2]):
            for d in range(coarse.shape[3]):
                dist = 0.0
                for a in range(3):
                    e = (coarse[a, x, y, d] - command[a]) * motor_scale[a]
                    dist += e * e
                if dist < keep_dist[count - 1]:
                    slot = count - 1
                    while slot > 0 and keep_dist[slot - 1] > dist:
                        keep_dist[slot] = keep_dist[slot - 1]
                        keep[slot] = keep[slot - 1]
                        slot -= 1
                    keep_dist[slot] = dist
                    keep[slot, 0] = x
                    keep[slot, 1] = y
                    keep[slot, 2] = d
    return keep


@njit(cache=True, nogil=True)
def _monomial_values(values: np.ndarray, exponents: np.ndarray, degree: int) -> np.ndarray:
    """prod over a of values[a] ** exponents[t, a], for every row t (exponents at most `degree`)."""
    table = np.empty((values.shape[0], degree + 1))
    for a in range(values.shape[0]):
        table[a] = _powers(values[a], degree)
    out = np.empty(exponents.shape[0])
    for t in range(exponents.shape[0]):
        product = 1.0
        for a in range(exponents.shape[1]):
            product *= table[a, exponents[t, a]]
        out[t] = product
    return out


@njit(cache=True, nogil=True)
def polynomial_features(unit_position: np.ndarray, position_terms: np.ndarray, cross_terms: np.ndarray,
                        unit_pose: np.ndarray, pose_terms: np.ndarray, degree: int) -> np.ndarray:
    """The features of a fit of P: the monomials `position_terms` (t, 3) of the scaled position
    (x, y, d), then, for every monomial `pose_terms` (p, 2) of the scaled pose (tilt, vergence)
    in turn, it times each of the monomials `cross_terms` (c, 3) of the position.

    `degree` bounds every position exponent. With no pose terms, the position monomials alone.
    """
    n_pos, n_cross = position_terms.shape[0], cross_terms.shape[0]
    table = np.empty((3, degree + 1))
    for a in range(3):
        table[a] = _powers(unit_position[a], degree)
    factors = _monomial_values(unit_pose, pose_terms, pose_terms.max() if pose_terms.size else 0)
    phi = np.empty(n_pos + factors.shape[0] * n_cross)
    for t in range(n_pos):
        phi[t] = table[0, position_terms[t, 0]] * table[1, position_terms[t, 1]] * table[2, position_terms[t, 2]]
    for c in range(n_cross):
        cross = table[0, cross_terms[c, 0]] * table[1, cross_terms[c, 1]] * table[2, cross_terms[c, 2]]
        for p in range(factors.shape[0]):
            phi[n_pos + p * n_cross + c] = factors[p] * cross
    return phi


@njit(cache=True, nogil=True)
def polynomial_tensor(coef: np.ndarray, position_terms: np.ndarray, cross_terms: np.ndarray,
                      unit_pose: np.ndarray, pose_terms: np.ndarray, degree: int) -> np.ndarray:
    """The dense coefficient tensor (n, n, n, 3), n = degree + 1, of P(x, y, d) at a pose: the
    fit's coefficients `coef` over the features of `polynomial_features`, the pose's
    monomials summed into the cross terms."""
    n = degree + 1
    n_pos, n_cross = position_terms.shape[0], cross_terms.shape[0]
    tensor = np.zeros((n, n, n, 3))
    for t in range(n_pos):
        for a in range(3):
            tensor[position_terms[t, 0], position_terms[t, 1], position_terms[t, 2], a] = coef[t, a]
    factors = _monomial_values(unit_pose, pose_terms, pose_terms.max() if pose_terms.size else 0)
    for c in range(n_cross):
        for a in range(3):
            acc = 0.0
            for p in range(factors.shape[0]):
                acc += factors[p] * coef[n_pos + p * n_cross + c, a]
            tensor[cross_terms[c, 0], cross_terms[c, 1], cross_terms[c, 2], a] += acc
    return tensor


@njit(cache=True, nogil=True)
def quadratic_form(matrix: np.ndarray, vector: np.ndarray) -> float:
    """vector' matrix vector."""
    total = 0.0
    for i in range(vector.shape[0]):
        acc = 0.0
        for j in range(vector.shape[0]):
            acc += matrix[i, j] * vector[j]
        total += vector[i] * acc
    return total


@njit(cache=True, nogil=True)
def rls_step(coef: np.ndarray, covariance: np.ndarray, noise_variance: np.ndarray, phi: np.ndarray,
             command: np.ndarray, confidence: float, forget: float, noise_rate: float, trace_limit: float) -> bool:
    """One weighted, forgetting recursive-least-squares step, in place on `coef` (n, 3), the
    symmetric `covariance` (n, n) and `noise_variance` (3,).

    The gain is P phi c / (forget + c phi' P phi), the covariance (P - gain (P phi)') / forget,
    kept exactly symmetric (the mean of it and its transpose) and scaled down to a trace of
    `trace_limit` when above it. The a-priori residual's variance is noise * (1 + phi' P phi):
    `noise_variance` moves towards residual^2 / (1 + phi' P phi) by `noise_rate`. Returns
    whether the covariance stayed finite and positive on its diagonal; when not, it is left
    as computed (not scaled) for the caller to reset.
    """
    n = phi.shape[0]
    p_phi = np.empty(n)
    for i in range(n):
        acc = 0.0
        for j in range(n):
            acc += covariance[i, j] * phi[j]
        p_phi[i] = acc
    leverage = 0.0
    for i in range(n):
        leverage += phi[i] * p_phi[i]
    residual = np.empty(3)
    for a in range(3):
        acc = 0.0
        for i in range(n):
            acc += phi[i] * coef[i, a]
        residual[a] = command[a] - acc
    denominator = forget + confidence * leverage
    gain = np.empty(n)
    for i in range(n):
        gain[i] = p_phi[i] * confidence / denominator
        for a in range(3):
            coef[i, a] += gain[i] * residual[a]
    for a in range(3):
        estimate = residual[a] ** 2 / (1.0 + leverage)
        noise_variance[a] = noise_variance[a] + noise_rate * (estimate - noise_variance[a])
    trace = 0.0
    healthy = True
    for i in range(n):
        for j in range(i, n):
            upper = (covariance[i, j] - gain[i] * p_phi[j]) / forget
            lower = (covariance[j, i] - gain[j] * p_phi[i]) / forget
            value = 0.5 * (upper + lower)
            if not np.isfinite(value):
                healthy = False
            covariance[i, j] = value
            covariance[j, i] = value
        if covariance[i, i] <= 0.0:
            healthy = False
        trace += covariance[i, i]
    if healthy and trace > trace_limit:
        scale = trace_limit / trace
        for i in range(n):
            for j in range(n):
                covariance[i, j] *= scale
    return healthy
