"""Compiled inner loops of the gaze map (numba): the neighbourhood update and the node search.

Both run on every adaptation over a few thousand nodes; written with numpy they cost a dozen
temporary arrays and as many Python-level calls each, which capped adaptation near 1,000
per second. Here each is one pass over the window, no temporaries. `cache=True` keeps the
compiled code beside this file, so only the first process pays the compile time.

Layout: the grid is planar, (3, nx, ny, nd). The polynomial part of W (default profile) is
passed as its dense coefficient tensor (n, n, n, 3) and per-axis scaling to [-1, 1].
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
def rls_step(coef: np.ndarray, covariance: np.ndarray, phi: np.ndarray, command: np.ndarray, confidence: float,
             forget: float) -> tuple[float, np.ndarray, float, bool]:
    """One weighted, forgetting recursive-least-squares step, in place on `coef` (n, 3) and the
    symmetric `covariance` (n, n), kept exactly symmetric.

    Returns the features' leverage phi' P phi and the a-priori residual (3,) (both before the
    step), the new covariance's trace, and whether it stayed positive on its diagonal and finite.
    """
    n = phi.shape[0]
    p_phi = np.zeros(n)
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
        acc = command[a]
        for i in range(n):
            acc -= phi[i] * coef[i, a]
        residual[a] = acc
    scale = confidence / (forget + confidence * leverage)
    gain = p_phi * scale
    for i in range(n):
        for a in range(3):
            coef[i, a] += gain[i] * residual[a]
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
    return leverage, residual, trace, healthy
