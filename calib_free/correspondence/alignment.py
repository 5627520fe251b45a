"""Where a patch lies, to a fraction of a pixel, near a first guess: the default profile's
last two steps of correspondence (`calib_free.correspondence.search`).

- `centre_weighted_peak`: NCC weighted towards the patch centre, searched a few pixels
  around the guess (the fish-eye compresses a patch's rim more than its centre).
- `warp_aligned`: the patch aligned by an affine or a quadratic map (the lens's local
  compression, and its change across the patch).

Both work on a window of the image around the guess, in any grey dtype (converted to float
there), and keep the guess where they have no evidence.
"""
from __future__ import annotations

import functools
import math

import cv2
import numpy as np

from calib_free.correspondence._kernels import centre_weighted_scores, centre_weighted_terms, ecc_polynomial
from calib_free.correspondence.disparity import subpixel_peak

ALIGNMENT_PAD_PX = 6  # the window the alignment works in: the patch and this much around
ALIGNMENT_MAX_SHIFT_PX = 3.0  # an alignment that moves the match farther has not converged: kept out
ALIGNMENT_TOLERANCE_PX = 0.01  # the alignment stops once an iteration moves the centre less
ALIGNMENT_WARPS = {"affine": 1, "quadratic": 2}  # the maps an alignment fits, by name: their polynomial degree


@functools.lru_cache(maxsize=32)
def _gaussian_bands(length: int, window: int, sigma_px: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The Gaussian g of `length` taps (`cv2.getGaussianKernel`'s, float64) and the band
    matrices B (placements x `window`) with B[k, k:k + length] = g, and the same of g^2."""
    g = cv2.getGaussianKernel(length, sigma_px, cv2.CV_32F)[:, 0].astype(np.float64)
    placements = window - length + 1
    band, band_sq = np.zeros((placements, window)), np.zeros((placements, window))
    for k in range(placements):
        band[k, k:k + length] = g
        band_sq[k, k:k + length] = g * g
    return g, band, band_sq


@functools.lru_cache(maxsize=32)
def _centre_weights(template_shape: tuple[int, int], window_shape: tuple[int, int],
                    sigma_px: float) -> tuple[np.ndarray, np.ndarray, float, tuple[np.ndarray, ...]]:
    """M / sum M, M^2 and sum M^2 of the template's Gaussian mask M, and the band matrices of
    `_gaussian_bands` along y and x; read-only, shared by every call."""
    g_y, band_y, band_sq_y = _gaussian_bands(template_shape[0], window_shape[0], sigma_px)
    g_x, band_x, band_sq_x = _gaussian_bands(template_shape[1], window_shape[1], sigma_px)
    mask = np.outer(g_y, g_x)
    arrays = (mask / mask.sum(), mask * mask, band_y / mask.sum(), band_x, band_sq_y, band_sq_x)
    for a in arrays:
        a.flags.writeable = False
    return arrays[0], arrays[1], float(arrays[1].sum()), arrays[2:]


def centre_weighted_ncc(window: np.ndarray, template: np.ndarray, sigma_px: float) -> np.ndarray:
    """`cv2.matchTemplate(window, template, cv2.TM_CCOEFF_NORMED, mask=M)` (float32) for the
    Gaussian mask M = g g^T of `sigma_px` (g: `cv2.getGaussianKernel`), with 0 where a window
    or the template is flat (OpenCV: NaN or infinite there).

    OpenCV weights the template and each window by M after subtracting their M-weighted
    means: score = sum M^2 (T - m_T)(I - m_I) / sqrt(sum M^2 (T - m_T)^2 sum M^2 (I - m_I)^2).
    M is separable, so the window terms m_I, sum M^2 I and sum M^2 I^2 are band-matrix
    products, and only sum M^2 (T - m_T) I needs a correlation with the template: a fraction
    of the time of OpenCV's general masked path, and closer to the exact figure (float64
    sums; OpenCV's differ from them by up to ~1e-2 on small templates)."""
    mask_mean, mask_sq, mask_sq_sum, (band_mean_y, band_x, band_sq_y, band_sq_x) = _centre_weights(
        template.shape, window.shape, sigma_px)
    image, image32, kernel, kernel_sum, template_energy, template_scale = centre_weighted_terms(
        np.ascontiguousarray(window, np.float32), np.ascontiguousarray(template, np.float32), mask_mean, mask_sq)
    correlation = cv2.matchTemplate(image32, kernel, cv2.TM_CCORR)  # sum M^2 (T - m_T) I
    scores: np.ndarray = centre_weighted_scores(image, correlation, band_mean_y, band_x, band_sq_y, band_sq_x,
                                                kernel_sum, template_energy, template_scale, mask_sq_sum)
    return scores


def centre_weighted_peak(image: np.ndarray, patch: np.ndarray, x: float, y: float, sigma_px: float,
                         radius_px: int = 4) -> tuple[float, float]:
    """Relocate a match with NCC weighted towards the patch centre, within `radius_px`.

    Away from the fovea the lens compresses the view more at the patch's outer edge than at
    its inner one, so the rim of the foveal patch fits worse than its centre and pulls the
    plain peak by a pixel or so; a Gaussian weight on the template removes most of that
    (on rendered rich texture: 93.5 % -> 98 % of matches within 1 px).
    """
    ph, pw = patch.shape
    a0 = int(round(x - (pw - 1) / 2.0)) - radius_px
    b0 = int(round(y - (ph - 1) / 2.0)) - radius_px
    if a0 < 0 or b0 < 0 or a0 + pw + 2 * radius_px > image.shape[1] or b0 + ph + 2 * radius_px > image.shape[0]:
        return x, y  # too near the border to search around: keep the plain peak
    window = image[b0:b0 + ph + 2 * radius_px, a0:a0 + pw + 2 * radius_px]
    scores = centre_weighted_ncc(window, patch, sigma_px)  # a flat window scores 0: no evidence
    _, _, _, (lx, ly) = cv2.minMaxLoc(scores)
    u, v = subpixel_peak(scores, ly, lx)
    return a0 + u + (pw - 1) / 2.0, b0 + v + (ph - 1) / 2.0


def warp_aligned(image: np.ndarray, patch: np.ndarray, x: float, y: float, iterations: int,
                 warp: str = "quadratic") -> tuple[float, float]:
    """Where the centre of `patch` lies in `image` once the patch is aligned by an affine or a
    quadratic map (`warp`), starting at the translation to (x, y): at most `iterations` steps
    of ECC (the enhanced correlation coefficient, Evangelidis and Psarakis 2008, the criterion
    of `cv2.findTransformECC`), stopping once a step moves the centre less than 0.01 px.

    Away from the fovea the fish-eye compresses the view, more radially than tangentially and
    more at the patch's outer edge than at its inner one. A translation-only match (NCC)
    leaves a bias of a pixel or so there; an affine map removes most of it (on the photo room
    at 640 x 480: 96-98 % -> 98.6-99.2 % of matches within 1 px) but not the change of
    compression across the patch, whose best affine fit puts the centre a tenth of a pixel or
    more towards the image centre (growing with the patch's area: -0.12 px at 30-60 px of
    eccentricity with a 40 x 40 patch at 320 x 240, -0.27 px with 60 x 60). The quadratic map
    follows that change: its centre is unbiased (measured +0.00 to +0.03 px), and the match
    error's median falls from 0.13 to 0.07-0.09 px (docs/results/correspondence.md). No alignment (the window
    leaves the image, the patch is flat, ECC diverges or moves the match more than 3 px): (x, y).

    ECC in its inverse-compositional form (`_correspondence_kernels.ecc_polynomial`): the
    linearisation is the patch's (its gradients, the Jacobian and its Gram matrix are
    computed once), so a step costs one warp of the window and one projection; OpenCV's
    forward-additive form re-derives them from the warped window at every step. Both maximise
    the same criterion: on the photo room at 640 x 480 the affine alignments land within
    0.05 px of each other in 95 % of matches (the figure by which OpenCV's own result moves
    between 3 and 5 iterations).
    """
    if warp not in ALIGNMENT_WARPS:
        raise ValueError(f"warp must be one of {', '.join(ALIGNMENT_WARPS)}, got {warp!r}")
    ph, pw = patch.shape
    cx, cy = (pw - 1) / 2.0, (ph - 1) / 2.0
    pad = ALIGNMENT_PAD_PX
    a0, b0 = int(round(x - cx)) - pad, int(round(y - cy)) - pad
    if a0 < 0 or b0 < 0 or a0 + pw + 2 * pad > image.shape[1] or b0 + ph + 2 * pad > image.shape[0]:
        return x, y
    window = np.ascontiguousarray(image[b0:b0 + ph + 2 * pad, a0:a0 + pw + 2 * pad], np.float32)
    ax, ay, aligned = ecc_polynomial(window, np.ascontiguousarray(patch, np.float32), x - cx - a0, y - cy - b0,
                                     ALIGNMENT_WARPS[warp], iterations, ALIGNMENT_TOLERANCE_PX)
    ax, ay = a0 + ax, b0 + ay
    if not aligned or not math.isfinite(ax + ay) or math.hypot(ax - x, ay - y) > ALIGNMENT_MAX_SHIFT_PX:
        return x, y
    return float(ax), float(ay)
