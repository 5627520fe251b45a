"""Where did the fixated patch come from? Correspondence and confidence (paper II-B, II-C).

After a fixation, the foveal patch of the post-fixation image I^t (centre, Table I: 20 x 20)
is searched for in the pre-fixation image I^(t-1). The correspondence map (eq. 1) is

    C(x, y) = NCC(patch, I^(t-1) around (x, y)) * f1(x, y) * f2(x, y)

where f1 and f2 favour pre-fixation patches with the same mean and variance as the foveal
patch: the fish-eye periphery distorts shapes, which NCC is sensitive to, but barely changes
a patch's mean and variance (II-B).

Bounded factors (a point the paper leaves open, docs/architecture.md). Eqs. 2-3 are |difference|^-1,
which is infinite for equal statistics and makes C unbounded, while eq. 4 reads c_max as a
correlation in [-1, 1] (its threshold (1 + tau)/2). We use

    f1 = 1 / (1 + |mean_t - mean_p| / mean_scale)          (mean_scale: grey levels)
    f2 = 2 min(var_t, var_p) / (var_t + var_p)              (0 when one patch is flat)

Both equal 1 for identical statistics, fall monotonically as the difference grows (as the
paper's inverses do), and keep |C| <= 1, so eqs. 4-7 apply as written. f2 is relative: a
contrast change of a given ratio costs the same in a dark or a bright, busy or quiet patch.

Confidence (eqs. 4-7): c1 = sigmoid(c_s (c_max - c_t)) with c_s = 10 / (1 - tau), c_t =
(1 + tau) / 2; c2 = 1 / (1 + sum N), N = T(C - delta) * squared distance from the peak in
units of sigma_c = r_t * image width, delta = R * c_max; c = c1_l c2_l c1_r c2_r.

Everything runs on OpenCV (matchTemplate, box filters); no Python loop touches a pixel.
"""
from __future__ import annotations

import threading
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import cv2
import numpy as np

from calib_free.errors import CalibFreeError


class CorrespondenceError(CalibFreeError, ValueError):
    """Images that cannot be matched: wrong shapes, a patch larger than the image."""


@dataclass(frozen=True)
class CorrespondenceParams:
    """Table I's correspondence parameters and our bounded-factor scale."""

    patch_size: tuple[int, int] = (20, 20)  # Table I: s_pat (width, height), pixels
    min_correlation: float = 0.2  # Table I: tau (eq. 4)
    min_ratio_to_compete: float = 0.95  # Table I: delta, the R of delta = R * c_max (eq. 5)
    tolerance_radius: float = 0.1  # Table I: r_t, sigma_c = r_t * image width (eq. 5)
    mean_scale: float = 10.0  # grey levels at which f1 has halved (our bounded eq. 2)
    use_factors: bool = True  # False: plain NCC, as the paper's fig. 3(c)
    # Coarse-to-fine: search the whole image at 1/2**levels resolution (and count competing
    # peaks there), then refine the best peak at full resolution. None: 1 level for images
    # wider than 400 px, else 0 (an exhaustive full-resolution NCC at 640 x 480 costs ~10 ms
    # an eye on a 2-core machine; at half resolution ~2 ms).
    pyramid_levels: int | None = None
    # Consistency of the two eyes' matches (`stereo_inconsistency`): beyond the paper.
    max_vertical_disparity_px: float = 4.0
    # Relocate each match with centre-weighted NCC (Gaussian of this fraction of the patch
    # width; 0: off): see `_centre_weighted_peak`. Beyond the paper.
    refine_sigma_fraction: float = 0.25
    stereo_tolerance_px: float = 2.0

    def __post_init__(self) -> None:
        if min(self.patch_size) < 3:
            raise ValueError(f"patch_size must be at least 3 x 3 pixels, got {self.patch_size}")
        if not -1.0 < self.min_correlation < 1.0:
            raise ValueError(f"min_correlation (tau) must be in (-1, 1), got {self.min_correlation}")
        if not 0.0 < self.min_ratio_to_compete <= 1.0:
            raise ValueError(f"min_ratio_to_compete must be in (0, 1], got {self.min_ratio_to_compete}")
        if self.tolerance_radius <= 0 or self.mean_scale <= 0:
            raise ValueError("tolerance_radius and mean_scale must be positive")


@dataclass(frozen=True)
class EyeMatch:
    """Where one eye's foveal patch was in that eye's pre-fixation image, and how sure we are."""

    x: float  # sub-pixel position of the best match (patch centre), pre-fixation image
    y: float
    c_max: float  # C at the peak (eq. 1)
    c1: float  # eq. 4
    c2: float  # eq. 6
    competitors: float  # sum of N over the map (eq. 5): the mass of far, nearly as good peaks


@dataclass(frozen=True)
class FixationMatch:
    """The training position r* = (x*, y*, d*) of a fixation and its confidence (eq. 7)."""

    left: EyeMatch
    right: EyeMatch

    @property
    def position(self) -> np.ndarray:
        """(x*, y*, d*): the left match, and d* = x_max,r - x_max,l (II-B)."""
        return np.array([self.left.x, self.left.y, self.right.x - self.left.x])

    @property
    def confidence(self) -> float:
        """Eq. 7: c = c1_l c2_l c1_r c2_r."""
        return self.left.c1 * self.left.c2 * self.right.c1 * self.right.c2

    def factors(self) -> dict[str, float]:
        return {"c1_left": self.left.c1, "c2_left": self.left.c2, "c1_right": self.right.c1,
                "c2_right": self.right.c2, "c_max_left": self.left.c_max, "c_max_right": self.right.c_max}


def as_grey_float(image: np.ndarray) -> np.ndarray:
    """A 2-D float32 grey image from a grey or BGR uint8/float image."""
    img = np.asarray(image)
    if img.ndim == 3 and img.shape[2] == 3:
        img = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
    elif img.ndim != 2:
        raise CorrespondenceError(f"expected a grey (H, W) or colour (H, W, 3) image, got shape {img.shape}")
    return img.astype(np.float32, copy=False)


def foveal_patch(image: np.ndarray, patch_size: tuple[int, int]) -> np.ndarray:
    """The patch of `patch_size` (w, h) centred on the image centre (the fovea)."""
    h, w = image.shape[:2]
    pw, ph = patch_size
    if pw > w or ph > h:
        raise CorrespondenceError(f"patch {pw} x {ph} is larger than the image {w} x {h}")
    x0, y0 = (w - pw) // 2, (h - ph) // 2
    return image[y0:y0 + ph, x0:x0 + pw]


def correspondence_map(pre: np.ndarray, patch: np.ndarray, params: CorrespondenceParams) -> np.ndarray:
    """Eq. 1 with the bounded factors: C for every placement of `patch` in `pre`.

    C[v, u] belongs to the patch whose top-left pixel is (u, v) in `pre`.
    """
    pre = as_grey_float(pre)
    patch = as_grey_float(patch)
    ph, pw = patch.shape
    if pw > pre.shape[1] or ph > pre.shape[0]:
        raise CorrespondenceError(f"patch {pw} x {ph} is larger than the image {pre.shape[1]} x {pre.shape[0]}")
    ncc = cv2.matchTemplate(pre, patch, cv2.TM_CCOEFF_NORMED)
    if not params.use_factors:
        return ncc
    # Mean and variance of every pre-fixation patch, by box filters over the valid placements.
    mean = cv2.boxFilter(pre, cv2.CV_32F, (pw, ph), anchor=(0, 0), normalize=True,
                         borderType=cv2.BORDER_CONSTANT)[: ncc.shape[0], : ncc.shape[1]]
    mean_sq = cv2.boxFilter(pre * pre, cv2.CV_32F, (pw, ph), anchor=(0, 0), normalize=True,
                            borderType=cv2.BORDER_CONSTANT)[: ncc.shape[0], : ncc.shape[1]]
    var = np.maximum(mean_sq - mean * mean, 0.0)
    patch_mean = float(patch.mean())
    patch_var = float(patch.var())
    f1 = 1.0 / (1.0 + np.abs(mean - patch_mean) / params.mean_scale)
    f2 = 2.0 * np.minimum(var, patch_var) / (var + patch_var + 1e-6)
    # A flat region gives NCC = 0 or NaN-like noise in OpenCV; where both are flat, no evidence.
    cmap: np.ndarray = np.nan_to_num(ncc) * f1 * f2
    return cmap


def _subpixel_peak(values: np.ndarray, iy: int, ix: int) -> tuple[float, float]:
    """Parabolic refinement of a peak at (iy, ix) along each axis."""

    def offset(a: float, b: float, c: float) -> float:
        denom = a - 2 * b + c
        return 0.0 if denom >= 0 else float(np.clip(0.5 * (a - c) / denom, -0.5, 0.5))

    dx = offset(values[iy, ix - 1], values[iy, ix], values[iy, ix + 1]) if 0 < ix < values.shape[1] - 1 else 0.0
    dy = offset(values[iy - 1, ix], values[iy, ix], values[iy + 1, ix]) if 0 < iy < values.shape[0] - 1 else 0.0
    return ix + dx, iy + dy


def match_eye(pre: np.ndarray, post: np.ndarray, params: CorrespondenceParams) -> EyeMatch:
    """Find one eye's post-fixation foveal patch in its pre-fixation image, with eqs. 4-6."""
    pre = as_grey_float(pre)
    post = as_grey_float(post)
    if pre.shape != post.shape:
        raise CorrespondenceError(f"pre-fixation image {pre.shape} and post-fixation image {post.shape} differ")
    levels = params.pyramid_levels
    if levels is None:
        levels = 1 if pre.shape[1] > 400 else 0
    scale = 2 ** levels
    pw, ph = params.patch_size
    if levels:
        size = (pre.shape[1] // scale, pre.shape[0] // scale)
        coarse_pre = cv2.resize(pre, size, interpolation=cv2.INTER_AREA)
        coarse_post = cv2.resize(post, size, interpolation=cv2.INTER_AREA)
        coarse_patch = foveal_patch(coarse_post, (max(3, pw // scale), max(3, ph // scale)))
    else:
        coarse_pre, coarse_patch = pre, foveal_patch(post, params.patch_size)
    cmap = correspondence_map(coarse_pre, coarse_patch, params)
    _, coarse_max, _, (ix, iy) = cv2.minMaxLoc(cmap)
    competitors = _competing_mass(cmap, coarse_max, ix, iy, params.tolerance_radius * coarse_pre.shape[1], params)
    patch = foveal_patch(post, params.patch_size)
    if levels:
        # Refine at full resolution within a coarse pixel or two of the coarse peak.
        cpw, cph = coarse_patch.shape[1], coarse_patch.shape[0]
        centre_x = (ix + (cpw - 1) / 2.0 + 0.5) * scale - 0.5
        centre_y = (iy + (cph - 1) / 2.0 + 0.5) * scale - 0.5
        margin = 2 * scale
        u0 = int(np.clip(round(centre_x - (pw - 1) / 2.0) - margin, 0, pre.shape[1] - pw))
        v0 = int(np.clip(round(centre_y - (ph - 1) / 2.0) - margin, 0, pre.shape[0] - ph))
        u1 = min(pre.shape[1], u0 + pw + 2 * margin)
        v1 = min(pre.shape[0], v0 + ph + 2 * margin)
        fine = correspondence_map(pre[v0:v1, u0:u1], patch, params)
    else:
        u0 = v0 = 0
        fine = cmap
    _, c_max, _, (fx, fy) = cv2.minMaxLoc(fine)
    u, v = _subpixel_peak(fine, fy, fx)
    # A placement's top-left (u, v) holds a patch centred at (u + (pw-1)/2, v + (ph-1)/2).
    x, y = u0 + u + (pw - 1) / 2.0, v0 + v + (ph - 1) / 2.0
    if params.refine_sigma_fraction > 0:
        x, y = _centre_weighted_peak(pre, patch, x, y, params.refine_sigma_fraction * pw)
    tau = params.min_correlation
    c_s, c_t = 10.0 / (1.0 - tau), (1.0 + tau) / 2.0  # eq. 4's slope and threshold from tau
    c1 = 1.0 / (1.0 + np.exp(-c_s * (c_max - c_t)))  # eq. 4
    c2 = 1.0 / (1.0 + competitors)  # eq. 6
    return EyeMatch(x=float(x), y=float(y), c_max=float(c_max), c1=float(c1), c2=float(c2),
                    competitors=competitors)


def _centre_weighted_peak(pre: np.ndarray, patch: np.ndarray, x: float, y: float, sigma_px: float,
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
    if a0 < 0 or b0 < 0 or a0 + pw + 2 * radius_px > pre.shape[1] or b0 + ph + 2 * radius_px > pre.shape[0]:
        return x, y  # too near the border to search around: keep the plain peak
    weight = cv2.getGaussianKernel(ph, sigma_px, cv2.CV_32F) @ cv2.getGaussianKernel(pw, sigma_px, cv2.CV_32F).T
    window = pre[b0:b0 + ph + 2 * radius_px, a0:a0 + pw + 2 * radius_px]
    scores = cv2.matchTemplate(window, patch, cv2.TM_CCOEFF_NORMED, mask=weight)
    # A flat window makes the masked normalisation 0/0 or x/0: no evidence there.
    scores = np.nan_to_num(scores, nan=0.0, posinf=0.0, neginf=0.0)
    _, _, _, (lx, ly) = cv2.minMaxLoc(scores)
    u, v = _subpixel_peak(scores, ly, lx)
    return a0 + u + (pw - 1) / 2.0, b0 + v + (ph - 1) / 2.0


def _competing_mass(cmap: np.ndarray, c_max: float, ix: int, iy: int, sigma_c: float,
                    params: CorrespondenceParams) -> float:
    """Eq. 5 summed over the map: T(C - delta) times the squared distance from the peak / sigma_c."""
    if c_max <= 0:
        return 0.0
    delta = params.min_ratio_to_compete * c_max  # eq. 5's threshold, delta = R * c_max
    above = np.argwhere(cmap >= delta)
    excess = cmap[above[:, 0], above[:, 1]] - delta  # T(C - delta)
    dist2 = ((above[:, 1] - ix) / sigma_c) ** 2 + ((above[:, 0] - iy) / sigma_c) ** 2
    return float(np.sum(excess * dist2))


def match_fixation(pre_left: np.ndarray, pre_right: np.ndarray, post_left: np.ndarray, post_right: np.ndarray,
                   params: CorrespondenceParams | None = None) -> FixationMatch:
    """r* = (x*, y*, d*) of a fixation and its confidence, from the pre- and post-fixation pairs."""
    params = params or CorrespondenceParams()
    # The two eyes are independent and OpenCV releases the GIL: the right eye is matched on a
    # second thread while this one does the left (at 640 x 480 on this 2-core machine, over
    # repeated runs: 5.2-6.4 ms a pair sequentially, 3.5-4.9 ms this way).
    right = _eye_pool().submit(match_eye, pre_right, post_right, params)
    left = match_eye(pre_left, post_left, params)
    return FixationMatch(left, right.result())


_POOL: ThreadPoolExecutor | None = None
_POOL_LOCK = threading.Lock()


def _eye_pool() -> ThreadPoolExecutor:
    """One worker thread, made on first use and kept for the process: matching the right eye."""
    global _POOL
    with _POOL_LOCK:
        if _POOL is None:
            _POOL = ThreadPoolExecutor(max_workers=1, thread_name_prefix="correspondence-right-eye")
        return _POOL


def horizontal_offset(left: np.ndarray, right: np.ndarray, centre: tuple[float, float],
                      patch_size: tuple[int, int], search: tuple[float, float]) -> tuple[float, float]:
    """Where the left image's patch around `centre` is in the right image, along the same rows.

    Returns (x_r - x_l in px, sub-pixel; its NCC) for offsets searched within `search`
    (low, high). A best match on the search's edge scores 0: the true one may lie beyond.
    """
    h, w = left.shape
    pw, ph = patch_size
    x0 = int(round(centre[0] - (pw - 1) / 2.0))
    y0 = int(round(centre[1] - (ph - 1) / 2.0))
    if x0 < 0 or y0 < 0 or x0 + pw > w or y0 + ph > h:
        return 0.0, 0.0
    patch = left[y0:y0 + ph, x0:x0 + pw]
    lo = max(0, x0 + int(np.floor(search[0])))
    hi = min(w, x0 + pw + int(np.ceil(search[1])))
    if hi - lo < pw + 2:
        return 0.0, 0.0
    scores = np.nan_to_num(cv2.matchTemplate(right[y0:y0 + ph, lo:hi], patch, cv2.TM_CCOEFF_NORMED))
    ix = int(np.argmax(scores[0]))
    if ix in (0, scores.shape[1] - 1):
        return float(lo + ix - x0), 0.0
    u, _ = _subpixel_peak(scores, 0, ix)
    return float(lo + u - x0), float(scores[0, ix])


def foveal_disparity(left: np.ndarray, right: np.ndarray, patch_size: tuple[int, int] = (32, 20),
                     search_px: int | None = None) -> tuple[float, float]:
    """Horizontal offset (px, sub-pixel) of the left fovea's content in the right image, and its NCC.

    Positive when the right eye sees the fixated content to the right of its centre: the same
    sign as d = x_r - x_l, so fine vergence drives it to zero. The search is a strip of
    +-`search_px` (default: a third of the width) around the right image's centre; a best
    match on the strip's edge scores 0 (the true one may lie beyond).
    """
    left = as_grey_float(left)
    right = as_grey_float(right)
    if left.shape != right.shape:
        raise CorrespondenceError(f"left image {left.shape} and right image {right.shape} differ")
    h, w = left.shape
    search_px = w // 3 if search_px is None else search_px
    pw, ph = patch_size
    centre = ((w - pw) // 2 + (pw - 1) / 2.0, (h - ph) // 2 + (ph - 1) / 2.0)
    return horizontal_offset(left, right, centre, patch_size, (-search_px, search_px))


def stereo_inconsistency(match: FixationMatch, pre_left: np.ndarray, pre_right: np.ndarray,
                         params: CorrespondenceParams) -> str:
    """Why the left and right matches of a fixation cannot both be right ('' if they agree).

    Each eye's patch is found on its own (II-B), so on repetitive texture each can land on a
    different repeat. Two checks the geometry allows without calibration: the rows agree
    within `max_vertical_disparity_px` (the paper's lens: 3.5 px at most, II-A footnote), and
    the pre-fixation pair's own disparity at (x*, y*) equals d* within `stereo_tolerance_px`.
    """
    left, right = match.left, match.right
    vertical = abs(left.y - right.y)
    if vertical > params.max_vertical_disparity_px:
        return f"left and right rows differ by {vertical:.1f} px > {params.max_vertical_disparity_px} px"
    d_star = right.x - left.x
    margin = 3 * params.stereo_tolerance_px + 2
    d_pre, score = horizontal_offset(as_grey_float(pre_left), as_grey_float(pre_right), (left.x, left.y),
                                     params.patch_size, (d_star - margin, d_star + margin))
    if score < params.min_correlation or abs(d_pre - d_star) > params.stereo_tolerance_px:
        return (f"the pre-fixation pair's disparity at (x*, y*) is {d_pre:.1f} px (NCC {score:.2f}), "
                f"d* = {d_star:.1f} px")
    return ""
