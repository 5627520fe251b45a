"""Disparity between the two eyes' images, measured along rows: where a left-image patch is in
the right image (`horizontal_offset`), at a point of the left image (`disparity_at`, an image
target's), and at the foveae (`foveal_disparity`, what fine vergence drives to zero). Also the image helpers the matching shares: `as_grey_float`, and
`subpixel_peak`, the parabolic refinement of a correlation peak.
"""
from __future__ import annotations

import cv2
import numpy as np

from calib_free.errors import CorrespondenceError, DisparityError

# A match this good or better gives a point's disparity; below, the patch is likely matched to
# something else (a distinctly textured patch scores 0.8-1 on the simulated head).
MIN_DISPARITY_NCC = 0.6
# Rows searched either side of the point's own: off-centre, the fish-eye's vertical disparity
# (the paper's lens: up to 3.5 px; the simulated head: 2.3 px at p90, 4.1 px at p99 of random pixels).
DISPARITY_BAND_PX = 4


def as_grey_float(image: np.ndarray) -> np.ndarray:
    """A 2-D float32 grey image from a grey or BGR uint8/float image."""
    img = np.asarray(image)
    if img.ndim == 3 and img.shape[2] == 3:
        img = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
    elif img.ndim != 2:
        raise CorrespondenceError(f"expected a grey (H, W) or colour (H, W, 3) image, got shape {img.shape}")
    return img.astype(np.float32, copy=False)


def subpixel_peak(values: np.ndarray, iy: int, ix: int) -> tuple[float, float]:
    """Parabolic refinement of a peak at (iy, ix) along each axis."""

    def offset(a: float, b: float, c: float) -> float:
        denom = a - 2 * b + c
        if denom >= 0:
            return 0.0
        shift = float(0.5 * (a - c) / denom)
        return 0.5 if shift > 0.5 else -0.5 if shift < -0.5 else shift  # (NaN stays NaN)

    dx = offset(values[iy, ix - 1], values[iy, ix], values[iy, ix + 1]) if 0 < ix < values.shape[1] - 1 else 0.0
    dy = offset(values[iy - 1, ix], values[iy, ix], values[iy + 1, ix]) if 0 < iy < values.shape[0] - 1 else 0.0
    return ix + dx, iy + dy


def horizontal_offset(left: np.ndarray, right: np.ndarray, centre: tuple[float, float],
                      patch_size: tuple[int, int], search: tuple[float, float],
                      band_px: int = 0, row_offset_px: float = 0.0) -> tuple[float, float]:
    """Where the left image's patch around `centre` is in the right image, along the same rows
    and `band_px` rows either side (a fish-eye pair's vertical disparity away from the centre).

    Returns (x_r - x_l in px, sub-pixel; its NCC) for offsets searched within `search`
    (low, high); (0, 0) when the patch reaches beyond the image. A best match on the search's
    left or right edge scores 0: the true one may lie beyond. `row_offset_px`: the rows
    searched are centred this far below the patch's (the pair's vertical misalignment).
    """
    dx, _dy, ncc = stereo_offset(left, right, centre, patch_size, search, band_px, row_offset_px)
    return dx, ncc


def stereo_offset(left: np.ndarray, right: np.ndarray, centre: tuple[float, float],
                  patch_size: tuple[int, int], search: tuple[float, float],
                  band_px: int = 0, row_offset_px: float = 0.0) -> tuple[float, float, float]:
    """`horizontal_offset` with the rows too: (x_r - x_l, y_r - y_l, NCC), both sub-pixel."""
    h, w = left.shape
    pw, ph = patch_size
    x0 = int(round(centre[0] - (pw - 1) / 2.0))
    y0 = int(round(centre[1] - (ph - 1) / 2.0))
    if x0 < 0 or y0 < 0 or x0 + pw > w or y0 + ph > h:
        return 0.0, 0.0, 0.0
    patch = left[y0:y0 + ph, x0:x0 + pw]
    lo = max(0, x0 + int(np.floor(search[0])))
    hi = min(w, x0 + pw + int(np.ceil(search[1])))
    shift = int(round(row_offset_px))
    top, bottom = max(0, y0 + shift - band_px), min(h, y0 + shift + ph + band_px)
    if hi - lo < pw + 2 or bottom - top < ph:
        return 0.0, 0.0, 0.0
    scores = np.nan_to_num(cv2.matchTemplate(right[top:bottom, lo:hi], patch, cv2.TM_CCOEFF_NORMED))
    iy, ix = np.unravel_index(int(np.argmax(scores)), scores.shape)
    if ix in (0, scores.shape[1] - 1):
        return float(lo + ix - x0), float(top + iy - y0), 0.0
    u, v = subpixel_peak(scores, int(iy), int(ix))
    return float(lo + u - x0), float(top + v - y0), float(scores[iy, ix])


def disparity_at(left: np.ndarray, right: np.ndarray, x: float, y: float, patch_size: tuple[int, int],
                 disparity_range: tuple[float, float], band_px: int = DISPARITY_BAND_PX,
                 row_offset_px: float = 0.0) -> tuple[float, float]:
    """The disparity (px) at (x, y) of the left image of a pair, and its NCC: where the patch of
    `patch_size` around it lies in the right image, within `disparity_range` along the same
    rows and `band_px` rows either side; those rows centred `row_offset_px` lower (the pair's
    vertical misalignment as fine vergence found it at the fovea: two real cameras' optical
    centres differ by some rows). DisparityError, saying why it could not be measured, when it
    matches below MIN_DISPARITY_NCC."""
    d, ncc = horizontal_offset(as_grey_float(left), as_grey_float(right), (x, y), patch_size, disparity_range,
                               band_px, row_offset_px)
    if ncc < MIN_DISPARITY_NCC:
        raise DisparityError(
            f"the disparity at ({x:g}, {y:g}) could not be measured (the best match in the right image "
            f"scores NCC {ncc:.2f} < {MIN_DISPARITY_NCC}: too near the border, no texture there, or "
            "seen by one eye only)")
    return d, ncc


def foveal_disparity(left: np.ndarray, right: np.ndarray, patch_size: tuple[int, int] = (32, 20),
                     search_px: int | None = None, band_px: int = 0) -> tuple[float, float]:
    """Horizontal offset (px, sub-pixel) of the left fovea's content in the right image, and its
    NCC; `foveal_offset` without the rows."""
    dx, _dy, ncc = foveal_offset(left, right, patch_size, search_px, band_px)
    return dx, ncc


def foveal_offset(left: np.ndarray, right: np.ndarray, patch_size: tuple[int, int] = (32, 20),
                  search_px: int | None = None, band_px: int = 0,
                  row_offset_px: float = 0.0) -> tuple[float, float, float]:
    """Offset (dx, dy in px, sub-pixel) of the left fovea's content in the right image, and its NCC.

    Positive when the right eye sees the fixated content to the right of its centre: the same
    sign as d = x_r - x_l, so fine vergence drives it to zero. The search is a strip of
    +-`search_px` (default: a third of the width) around the right image's centre and
    `band_px` rows either side: two real cameras' optical centres differ by some rows, which
    the eyes, turning about vertical axes, cannot take away; the band is centred
    `row_offset_px` below the fovea's row. A best match on the strip's left or right edge
    scores 0 (the true one may lie beyond).
    """
    left = as_grey_float(left)
    right = as_grey_float(right)
    if left.shape != right.shape:
        raise CorrespondenceError(f"left image {left.shape} and right image {right.shape} differ")
    h, w = left.shape
    search_px = w // 3 if search_px is None else search_px
    pw, ph = patch_size
    centre = ((w - pw) // 2 + (pw - 1) / 2.0, (h - ph) // 2 + (ph - 1) / 2.0)
    return stereo_offset(left, right, centre, patch_size, (-search_px, search_px), band_px, row_offset_px)
