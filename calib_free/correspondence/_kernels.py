"""Compiled inner loops of correspondence (numba): the alignment (ECC, affine or quadratic), the
centre-weighted NCC's terms and scores, the correspondence map's factors, its best other
peak and competing mass, and the pyramid's block means.

`match_fixation` matches the two eyes on two threads. Written with numpy, these steps are
dozens of calls on small arrays, each holding the interpreter lock, so the two eyes wait for
each other and the second core gains little (measured at 640 x 480: 1.08 times faster than
one thread, against 1.5 with these kernels); compiled with `nogil=True` each is one call
that releases the lock, like the OpenCV calls around it. `cache=True` keeps the compiled code
beside this file, so only the first process pays the compile time (about 10 s).
"""
from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, nogil=True)
def _inverse(a: np.ndarray) -> np.ndarray:
    """The inverse of a square matrix by Gauss-Jordan elimination with partial pivoting; all
    NaN when a pivot is below 1e-12 of the largest entry (singular)."""
    n = a.shape[0]
    m = np.zeros((n, 2 * n))
    m[:, :n] = a
    for i in range(n):
        m[i, n + i] = 1.0
    scale = np.max(np.abs(a))
    for col in range(n):
        pivot = col
        for r in range(col + 1, n):
            if abs(m[r, col]) > abs(m[pivot, col]):
                pivot = r
        if not abs(m[pivot, col]) > 1e-12 * scale:
            return np.full((n, n), np.nan)
        if pivot != col:
            for c in range(2 * n):
                m[col, c], m[pivot, c] = m[pivot, c], m[col, c]
        d = m[col, col]
        for c in range(2 * n):
            m[col, c] /= d
        for r in range(n):
            if r != col and m[r, col] != 0.0:
                f = m[r, col]
                for c in range(2 * n):
                    m[r, c] -= f * m[col, c]
    return m[:, n:].copy()


@njit(cache=True, nogil=True)
def _warp(window: np.ndarray, coefficients: np.ndarray, monomials: np.ndarray, out: np.ndarray) -> None:
    """`out[k]` := `window` at (x, y) = `coefficients` @ `monomials[:, k]` for each template
    pixel k, bilinear; 0 beyond the window (OpenCV's constant border)."""
    h, wd = window.shape
    terms = monomials.shape[0]
    for k in range(monomials.shape[1]):
        x = 0.0
        y = 0.0
        for j in range(terms):
            x += coefficients[0, j] * monomials[j, k]
            y += coefficients[1, j] * monomials[j, k]
        x0 = int(np.floor(x))
        y0 = int(np.floor(y))
        fx = x - x0
        fy = y - y0
        if 0 <= x0 and x0 + 1 < wd and 0 <= y0 and y0 + 1 < h:
            v00, v01 = window[y0, x0], window[y0, x0 + 1]
            v10, v11 = window[y0 + 1, x0], window[y0 + 1, x0 + 1]
        else:
            v00 = window[y0, x0] if 0 <= y0 < h and 0 <= x0 < wd else 0.0
            v01 = window[y0, x0 + 1] if 0 <= y0 < h and 0 <= x0 + 1 < wd else 0.0
            v10 = window[y0 + 1, x0] if 0 <= y0 + 1 < h and 0 <= x0 < wd else 0.0
            v11 = window[y0 + 1, x0 + 1] if 0 <= y0 + 1 < h and 0 <= x0 + 1 < wd else 0.0
        out[k] = (v00 * (1.0 - fx) + v01 * fx) * (1.0 - fy) + (v10 * (1.0 - fx) + v11 * fx) * fy


@njit(cache=True, nogil=True)
def ecc_polynomial(window: np.ndarray, template: np.ndarray, s0: float, w0: float, degree: int, iterations: int,
                   tolerance: float) -> tuple[float, float, bool]:
    """ECC alignment of `template` in `window` by a polynomial warp of `degree` 1 (affine) or
    2 (quadratic), inverse-compositional, from the translation putting the template's top-left
    at (s0, w0): where the template's centre lies in `window` (x, y), and whether the alignment
    held (False: a flat template, a singular system, or a step that would minimise the
    correlation).

    The warp takes the template pixel u = (u, v) to window (x, y) = C m(u), m the monomials
    1, u', v' (and u'^2, u'v', v'^2) of u' = (u - centre) / half its width: the constant
    column of C is the template centre's place. The template's Jacobian rows (the gradients
    times each monomial, x rows then y rows) and the template itself, each zero-mean, give the
    Gram matrix once; each step warps the window (bilinear), projects it on those rows and
    solves for the step D (a displacement D m(u) of the template). Composing the warp with the
    step's inverse, W(u - D m(u)), is taken to first order, C -= A D with A the warp's linear
    part: quadratic warps are not closed under composition, and the first-order composition
    changes only the path to the maximum, where D = 0, not the maximum. The steps stop after
    `iterations` or once one moves the centre less than `tolerance` px.
    """
    ph, pw = template.shape
    n = ph * pw
    terms = 3 if degree == 1 else 6
    params = 2 * terms
    cx, cy = (pw - 1) / 2.0, (ph - 1) / 2.0
    half = max(cx, cy, 1.0)
    monomials = np.empty((terms, n))
    rows = np.empty((params + 1, n))
    k = 0
    for v in range(ph):
        for u in range(pw):
            a, b = (u - cx) / half, (v - cy) / half
            monomials[0, k], monomials[1, k], monomials[2, k] = 1.0, a, b
            if terms == 6:
                monomials[3, k], monomials[4, k], monomials[5, k] = a * a, a * b, b * b
            # Central differences; 0 on the border (OpenCV's Sobel of aperture 1, reflected border).
            gx = 0.5 * (template[v, u + 1] - template[v, u - 1]) if 0 < u < pw - 1 else 0.0
            gy = 0.5 * (template[v + 1, u] - template[v - 1, u]) if 0 < v < ph - 1 else 0.0
            for j in range(terms):
                rows[j, k] = gx * monomials[j, k]
                rows[terms + j, k] = gy * monomials[j, k]
            rows[params, k] = template[v, u]
            k += 1
    for i in range(params + 1):
        rows[i] -= rows[i].mean()
    gram = rows @ rows.T
    if not gram[params, params] > 1e-6 * n:
        return cx + s0, cy + w0, False  # a flat template: nothing to align
    hessian_inv = _inverse(gram[:params, :params].copy())
    if np.isnan(hessian_inv[0, 0]):
        return cx + s0, cy + w0, False
    template_projection = gram[:params, params].copy()
    template_hessian = hessian_inv @ template_projection
    lambda_numerator = gram[params, params] - np.dot(template_projection, template_hessian)
    coefficients = np.zeros((2, terms))
    coefficients[0, 0], coefficients[1, 0] = cx + s0, cy + w0
    coefficients[0, 1], coefficients[1, 2] = half, half  # the identity: x = u, y = v
    warped = np.empty(n)
    for _ in range(iterations):
        _warp(window, coefficients, monomials, warped)
        projection = rows @ warped  # the rows are zero-mean: the warped window's mean drops out
        image_projection = projection[:params].copy()
        lambda_denominator = projection[params] - np.dot(image_projection, template_hessian)
        if not lambda_denominator > 0.0:
            return cx + s0, cy + w0, False  # the correlation would be minimised
        step = hessian_inv @ ((lambda_numerator / lambda_denominator) * image_projection - template_projection)
        # A, the warp's derivative in template pixels, times the step's coefficients.
        a00, a01 = coefficients[0, 1] / half, coefficients[0, 2] / half
        a10, a11 = coefficients[1, 1] / half, coefficients[1, 2] / half
        for j in range(terms):
            dx, dy = step[j], step[terms + j]
            coefficients[0, j] -= a00 * dx + a01 * dy
            coefficients[1, j] -= a10 * dx + a11 * dy
        moved_x = a00 * step[0] + a01 * step[terms]
        moved_y = a10 * step[0] + a11 * step[terms]
        if moved_x * moved_x + moved_y * moved_y < tolerance * tolerance:
            break
    return coefficients[0, 0], coefficients[1, 0], True


@njit(cache=True, nogil=True)
def centre_weighted_terms(window: np.ndarray, template: np.ndarray, mask_mean: np.ndarray,
                          mask_sq: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, float, float, float]:
    """The window and template terms of the centre-weighted NCC (`patch_alignment`): the
    window less its mean (float64, and float32 for OpenCV's correlation, which it keeps
    precise), the kernel M^2 (T - m_T) (float32), the kernel's sum, the template's weighted
    energy sum M^2 (T - m_T)^2, and sum M^2 (T - m_T) T (its scale, for telling a flat
    template)."""
    image = window.astype(np.float64)
    image -= image.mean()
    th, tw = template.shape
    t_mean = 0.0
    for v in range(th):
        for u in range(tw):
            t_mean += mask_mean[v, u] * template[v, u]
    kernel = np.empty((th, tw), np.float32)
    kernel_sum = 0.0
    energy = 0.0
    scale = 0.0
    for v in range(th):
        for u in range(tw):
            zero = template[v, u] - t_mean
            k = mask_sq[v, u] * zero
            kernel[v, u] = k
            kernel_sum += k
            energy += k * zero
            scale += k * template[v, u]
    return image, image.astype(np.float32), kernel, kernel_sum, energy, scale


@njit(cache=True, nogil=True)
def centre_weighted_scores(image: np.ndarray, correlation: np.ndarray, band_mean_y: np.ndarray,
                           band_x: np.ndarray, band_sq_y: np.ndarray, band_sq_x: np.ndarray, kernel_sum: float,
                           template_energy: float, template_scale: float, mask_sq_sum: float) -> np.ndarray:
    """The centre-weighted NCC of every placement from `centre_weighted_terms` and the
    correlation of the window with the kernel; 0 where the window or the template is flat (a
    weighted variance below 1e-12 grey levels^2, or below 1e-10 of its energy: rounding)."""
    weighted_mean = band_mean_y @ image @ band_x.T  # m_I of every placement
    weighted_sq = band_sq_y @ image @ band_sq_x.T  # sum M^2 I
    weighted_sq_sq = band_sq_y @ (image * image) @ band_sq_x.T  # sum M^2 I^2
    rows, cols = correlation.shape
    scores = np.zeros((rows, cols), np.float32)
    if template_energy <= 1e-12 * mask_sq_sum + 1e-10 * template_scale:
        return scores
    for v in range(rows):
        for u in range(cols):
            m = weighted_mean[v, u]
            energy = weighted_sq_sq[v, u] - (2.0 * weighted_sq[v, u] - m * mask_sq_sum) * m
            if energy > 1e-12 * mask_sq_sum + 1e-10 * weighted_sq_sq[v, u]:
                scores[v, u] = (correlation[v, u] - m * kernel_sum) / np.sqrt(energy * template_energy)
    return scores


@njit(cache=True, nogil=True)
def correspondence_factors(ncc: np.ndarray, mean: np.ndarray, mean_sq: np.ndarray, patch_mean: float,
                           patch_var: float, mean_scale: float) -> np.ndarray:
    """Eq. 1 with the bounded factors, C = NCC f1 f2, from the NCC of every placement and the
    mean and mean square of its window (arrays at least as large as `ncc`, aligned at the
    top-left): f1 = 1 / (1 + |mean - patch_mean| / mean_scale), f2 = 2 min(var, patch_var) /
    (var + patch_var), var = max(mean_sq - mean^2, 0)."""
    rows, cols = ncc.shape
    out = np.empty((rows, cols), np.float32)
    for v in range(rows):
        for u in range(cols):
            m = mean[v, u]
            var = max(mean_sq[v, u] - m * m, 0.0)
            f1 = 1.0 / (1.0 + abs(m - patch_mean) / mean_scale)
            f2 = 2.0 * min(var, patch_var) / (var + patch_var + 1e-6)
            out[v, u] = ncc[v, u] * f1 * f2
    return out


@njit(cache=True, nogil=True)
def second_peak(cmap: np.ndarray, dilated: np.ndarray, ix: int, iy: int, radius: int) -> float:
    """The best local maximum of `cmap` (where it equals `dilated`, its grey dilation by a
    square of 2 `radius` + 1) outside the square of that size around (ix, iy); -1 when there
    is none (|C| <= 1)."""
    rows, cols = cmap.shape
    best = -1.0
    for v in range(rows):
        for u in range(cols):
            c = cmap[v, u]
            if c > best and c >= dilated[v, u] and (abs(u - ix) > radius or abs(v - iy) > radius):
                best = c
    return best


@njit(cache=True, nogil=True)
def competing_mass(cmap: np.ndarray, ix: int, iy: int, delta: float, sigma_c: float) -> float:
    """Eq. 5 summed over the map: (C - delta) times the squared distance from (ix, iy) in
    units of `sigma_c`, where C >= delta."""
    rows, cols = cmap.shape
    mass = 0.0
    for v in range(rows):
        for u in range(cols):
            c = cmap[v, u]
            if c >= delta:
                mass += (c - delta) * ((u - ix) ** 2 + (v - iy) ** 2)
    return mass / sigma_c ** 2


@njit(cache=True, nogil=True)
def block_means(image: np.ndarray, scale: int) -> np.ndarray:
    """The mean of each `scale` x `scale` block of a uint8 image (float32; the rows and columns
    beyond the last whole block are left out): exact, since the sums are integers and
    1/scale^2 a power of 2 when `scale` is. Each band of `scale` rows is summed down the
    columns first (one contiguous pass a row), then across each block."""
    rows, cols = image.shape[0] // scale, image.shape[1] // scale
    width = cols * scale
    out = np.empty((rows, cols), np.float32)
    column_sums = np.empty(width, np.int32)
    inverse = 1.0 / (scale * scale)
    for by in range(rows):
        column_sums[:] = 0
        for y in range(by * scale, (by + 1) * scale):
            for x in range(width):
                column_sums[x] += image[y, x]
        for bx in range(cols):
            total = 0
            for x in range(bx * scale, (bx + 1) * scale):
                total += column_sums[x]
            out[by, bx] = total * inverse
    return out


@njit(cache=True, nogil=True)
def _quantile(ordered: np.ndarray, percent: float) -> float:
    """The `percent` quantile of sorted values, linearly interpolated (numpy's default)."""
    position = percent / 100.0 * (ordered.size - 1)
    below = int(np.floor(position))
    above = min(below + 1, ordered.size - 1)
    return float(ordered[below] + (position - below) * (ordered[above] - ordered[below]))


@njit(cache=True, nogil=True)
def quantile_line(sa: np.ndarray, sb: np.ndarray, percents: np.ndarray, low: float, high: float,
                  min_span: float) -> tuple[float, float, float, float, float, bool]:
    """The least-squares line b = gain a + offset through the pairs of `percents` quantiles of
    a and of b, given as their sorted values `sa` and `sb` (1-D; numpy sorts faster than
    numba), leaving out the pairs where either quantile lies outside the open range (low,
    high): (gain, offset, the mean, the least and the greatest of the a quantiles used, True);
    (1, 0, 0, 0, 0, False) when fewer than 3 pairs remain or either side's quantiles span less
    than `min_span`."""
    xs = np.empty(percents.size)
    ys = np.empty(percents.size)
    n = 0
    for p in percents:
        x, y = _quantile(sa, p), _quantile(sb, p)
        if low < x < high and low < y < high:
            xs[n], ys[n] = x, y
            n += 1
    if n < 3 or xs[n - 1] - xs[0] < min_span or ys[n - 1] - ys[0] < min_span:
        return 1.0, 0.0, 0.0, 0.0, 0.0, False  # (quantiles rise with the percent: the first and last span them)
    mx, my = xs[:n].mean(), ys[:n].mean()
    sxx = 0.0
    sxy = 0.0
    for k in range(n):
        sxx += (xs[k] - mx) ** 2
        sxy += (xs[k] - mx) * (ys[k] - my)
    gain = sxy / sxx
    return gain, my - gain * mx, mx, xs[0], xs[n - 1], True
