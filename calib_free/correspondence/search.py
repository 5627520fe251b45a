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

Two profiles (`CorrespondenceParams.profile`). `paper`: eqs. 1-7 as written, the per-eye
confidence c1 c2. `default` keeps eq. 1 (with its bounded factors) but searches and decides
otherwise where real images break eqs. 4-6 (repeated structure at every scale, a fish-eye
periphery):

- context: the search runs one pyramid level coarser with the foveal patch's size there,
  so the patch searched covers twice the field of the foveal patch; a repeat of the fovea's
  content rarely repeats its surroundings too (and where the context peak is not distinct,
  the search is repeated one level coarser: a wider context). The best context peak is refined at full
  resolution (eq. 1) with the fovea's patch of `refine_patch_factor` times the size (more
  structure, a sharper peak; 40 x 40 at 320 x 240, 60 x 60 at 640 x 480), relocated with
  centre-weighted NCC, then aligned by a quadratic map (ECC), which follows the lens's local
  compression and its change across the patch (both in `calib_free.correspondence.alignment`);
- distinctiveness: the best other peak of the context map, wherever it is (eq. 5 weighs a
  competitor by its squared distance, which hides the near repeats): the margin between
  them, d = 1 - exp(-(margin / distinct_margin)^2);
- forward-backward: the pre-fixation patch at the match (the foveal patch's size times
  `backward_patch_factor`), searched in the post-fixation image within
  +-backward_radius_px of the fovea, must land on the fovea:
  b = 1 / (1 + (distance / backward_tolerance_px)^4);
- the per-eye confidence c1(context) d b, c1 being eq. 4 on the context peak with its own
  tau (`context_min_correlation`).

The fixation's confidence is the product over both eyes in either profile (eq. 7).

Everything runs on OpenCV (matchTemplate, box filters, dilation) and compiled kernels that
release the interpreter lock (`_correspondence_kernels`, numba), so the two eyes' threads
run side by side; no Python loop touches a pixel.
"""
from __future__ import annotations

import threading
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np

from calib_free.correspondence._kernels import block_means, competing_mass, correspondence_factors, second_peak
from calib_free.correspondence.disparity import as_grey_float, subpixel_peak
from calib_free.errors import CorrespondenceError
from calib_free.correspondence.alignment import ALIGNMENT_WARPS, centre_weighted_peak, warp_aligned
from calib_free.correspondence.photometric import (NO_CHANGE, BrightnessChange, brightness_change, clipped,
                                                   registration_level)


PROFILES = ("default", "paper")


@dataclass(frozen=True)
class CorrespondenceParams:
    """Table I's correspondence parameters, our bounded-factor scale, and the default
    profile's search and confidence (module doc)."""

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
    # width; 0: off): see `patch_alignment.centre_weighted_peak`. Beyond the paper: default profile only.
    refine_sigma_fraction: float = 0.25
    stereo_tolerance_px: float = 2.0
    # A repeat of the left patch along the same rows of the right pre-fixation image scoring
    # within this much NCC of the match at d* makes the fixation's d* ambiguous.
    stereo_rival_margin: float = 0.1
    # "paper": eqs. 1-7 as written (no context, no relocation, confidence c1 c2); "default":
    # the module doc's search and confidence.
    profile: str = "default"
    # Default profile: the context search runs this many levels coarser than the search of
    # `pyramid_levels`, with a patch of `patch_size` there (0: no context).
    context_levels: int = 1
    # Default profile: while the context peak is not distinct (margin < distinct_margin), the
    # search is repeated up to this many levels coarser (a wider context); the most distinct
    # peak is kept (0: never).
    wider_context_levels: int = 1
    # Default profile: the context peak is refined and relocated at full resolution with the
    # fovea's patch of this many times `patch_size` (more structure: a sharper peak). None:
    # 2 for images up to 400 px wide, 3 above (measured on the photo room; a larger patch
    # also holds more of the lens's distortion).
    refine_patch_factor: float | None = None
    # Default profile: at most this many Gauss-Newton iterations of an alignment of that patch
    # at the match by the map `alignment_warp` names (ECC, `patch_alignment.warp_aligned`:
    # fewer once a step moves the match less than 0.01 px), which follows the lens's local
    # compression (0: off). "affine" leaves the match biased towards the image centre by the
    # compression's change across the patch; "quadratic" follows that change too.
    alignment_iterations: int = 5
    alignment_warp: str = "quadratic"
    # Default profile: eq. 4's tau for the context peak (its c1): c1 = 1/2 at a correlation
    # of (1 + tau) / 2, 0.3 at -0.4. Lower than Table I's: the periphery's distortion and the
    # parallax at a depth edge (the context moves otherwise than the fovea's own patch) lower
    # the context's correlation of a right match to 0.4-0.5, and a wrong match is told by
    # distinctiveness and the backward check rather than by a low peak. On the 965 matched
    # fixations of one online run in the generated room (the teaching explorer's structured
    # corners, often at an object's edge), 0 refused 105 of the 901 right matches and -0.4
    # refused 56, accepting no more wrong ones (2, both within 3 px).
    context_min_correlation: float = -0.4
    distinct_margin: float = 0.1  # context-peak margin at which d = 1 - 1/e
    backward_radius_px: int = 24  # how far around the fovea the backward search looks
    backward_tolerance_px: float = 2.0  # backward landing distance at which b = 1/2
    # Default profile: the backward search's patch is `patch_size` times this. A larger patch
    # holds more than one period of a periodic texture (a checkerboard), whose repeats a
    # 20 x 20 patch lands on: on rendered saccades of the generated room at 320 x 240, 1.5
    # accepts 94.9 % of the right matches against 91.5 % with 1, and 1 of the 28 wrong by
    # more than 3 px (0.2 % of the accepted) against none; 2: 97.2 %, 5 of 28. In the online
    # experiment (5 seeds, 1,000 fixations) 1.5 taught no more fixations than 1 within the
    # seeds' spread, and landed no better: 1 is kept.
    backward_patch_factor: float = 1.0
    # Default profile: eq. 1's factors read the foveal patch's mean and variance through the
    # change of brightness estimated between the two images (`photometric`: an exposure or
    # gain that followed the view), clamped to a gain within [1/max_gain, max_gain] and an
    # offset within +-max_offset grey levels. max_gain 2: one photographic stop either way.
    compensate_brightness: bool = True
    max_gain: float = 2.0
    max_offset: float = 32.0

    @classmethod
    def profile_values(cls, profile: str, **overrides: Any) -> "CorrespondenceParams":
        """The parameters of a profile; `overrides` win."""
        if profile not in PROFILES:
            raise ValueError(f"profile must be one of {', '.join(PROFILES)}, got {profile!r}")
        return cls(**{"profile": profile, **overrides})

    @property
    def paper(self) -> bool:
        return self.profile == "paper"

    def __post_init__(self) -> None:
        if self.profile not in PROFILES:
            raise ValueError(f"profile must be one of {', '.join(PROFILES)}, got {self.profile!r}")
        if not 0 <= self.context_levels <= 4:
            raise ValueError(f"context_levels must be 0 to 4, got {self.context_levels}")
        if not -1.0 < self.context_min_correlation < 1.0:
            raise ValueError(f"context_min_correlation must be in (-1, 1), got {self.context_min_correlation}")
        if not 0 <= self.wider_context_levels <= 4:
            raise ValueError(f"wider_context_levels must be 0 to 4, got {self.wider_context_levels}")
        if not 0 <= self.alignment_iterations <= 100:
            raise ValueError(f"alignment_iterations must be 0 to 100, got {self.alignment_iterations}")
        if self.alignment_warp not in ALIGNMENT_WARPS:
            raise ValueError(f"alignment_warp must be one of {', '.join(ALIGNMENT_WARPS)}, got {self.alignment_warp!r}")
        if self.refine_patch_factor is not None and not 1.0 <= self.refine_patch_factor <= 8.0:
            raise ValueError(f"refine_patch_factor must be 1 to 8, got {self.refine_patch_factor}")
        if self.distinct_margin <= 0 or self.backward_tolerance_px <= 0:
            raise ValueError("distinct_margin and backward_tolerance_px must be positive")
        if not 1.0 <= self.backward_patch_factor <= 8.0:
            raise ValueError(f"backward_patch_factor must be 1 to 8, got {self.backward_patch_factor}")
        if not 0 <= self.backward_radius_px <= 1024:
            raise ValueError(f"backward_radius_px must be 0 to 1024, got {self.backward_radius_px}")
        if min(self.patch_size) < 3:
            raise ValueError(f"patch_size must be at least 3 x 3 pixels, got {self.patch_size}")
        if not -1.0 < self.min_correlation < 1.0:
            raise ValueError(f"min_correlation (tau) must be in (-1, 1), got {self.min_correlation}")
        if not 0.0 < self.min_ratio_to_compete <= 1.0:
            raise ValueError(f"min_ratio_to_compete must be in (0, 1], got {self.min_ratio_to_compete}")
        if not 1.0 <= self.max_gain <= 16.0 or not 0.0 <= self.max_offset <= 255.0:
            raise ValueError(f"max_gain must be 1 to 16 and max_offset 0 to 255, got {self.max_gain}, {self.max_offset}")
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
    # The one per-eye figure acceptance rests on: c1 c2 in the paper's profile (also when not
    # given), c1(context) d b in the default profile (module doc).
    confidence: float = float("nan")
    # Default profile only (NaN in `paper`): the context peak, the best other context peak,
    # and how far from the fovea the backward search landed (px).
    context_c_max: float = float("nan")
    second_peak: float = float("nan")
    backward_px: float = float("nan")
    brightness: BrightnessChange = NO_CHANGE  # the change the factors read the fovea through

    def __post_init__(self) -> None:
        if np.isnan(self.confidence):
            object.__setattr__(self, "confidence", self.c1 * self.c2)


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
        """Eq. 7, the product over both eyes: c1_l c2_l c1_r c2_r in the paper's profile."""
        return self.left.confidence * self.right.confidence

    def factors(self) -> dict[str, float]:
        out = {"c1_left": self.left.c1, "c2_left": self.left.c2, "c1_right": self.right.c1,
               "c2_right": self.right.c2, "c_max_left": self.left.c_max, "c_max_right": self.right.c_max,
               "confidence_left": self.left.confidence, "confidence_right": self.right.confidence}
        for side, m in (("left", self.left), ("right", self.right)):
            if not np.isnan(m.context_c_max):
                out.update({f"context_c_max_{side}": m.context_c_max, f"second_peak_{side}": m.second_peak,
                            f"backward_px_{side}": m.backward_px, f"gain_{side}": m.brightness.gain,
                            f"offset_{side}": m.brightness.offset})
        return out


def foveal_patch(image: np.ndarray, patch_size: tuple[int, int]) -> np.ndarray:
    """The patch of `patch_size` (w, h) centred on the image centre (the fovea)."""
    h, w = image.shape[:2]
    pw, ph = patch_size
    if pw > w or ph > h:
        raise CorrespondenceError(f"patch {pw} x {ph} is larger than the image {w} x {h}")
    x0, y0 = (w - pw) // 2, (h - ph) // 2
    return image[y0:y0 + ph, x0:x0 + pw]


def correspondence_map(pre: np.ndarray, patch: np.ndarray, params: CorrespondenceParams,
                       brightness: BrightnessChange = NO_CHANGE) -> np.ndarray:
    """Eq. 1 with the bounded factors: C for every placement of `patch` in `pre`, the patch's
    mean and variance read in `pre`'s grey levels through `brightness`.

    C[v, u] belongs to the patch whose top-left pixel is (u, v) in `pre`.
    """
    pre = as_grey_float(pre)
    patch = as_grey_float(patch)
    ph, pw = patch.shape
    if pw > pre.shape[1] or ph > pre.shape[0]:
        raise CorrespondenceError(f"patch {pw} x {ph} is larger than the image {pre.shape[1]} x {pre.shape[0]}")
    ncc = cv2.matchTemplate(pre, patch, cv2.TM_CCOEFF_NORMED)
    cv2.patchNaNs(ncc, 0.0)  # OpenCV scores a flat window 0; NaN would be no evidence too
    if not params.use_factors or (params.compensate_brightness and not params.paper and clipped(patch)):
        return ncc  # (a clipped patch's mean and variance are not its surface's: `photometric`)
    # Mean and mean square of every pre-fixation patch, by box filters (valid placements:
    # their top-left part), then f1 and f2 in one compiled pass.
    mean = cv2.boxFilter(pre, cv2.CV_32F, (pw, ph), anchor=(0, 0), normalize=True, borderType=cv2.BORDER_CONSTANT)
    mean_sq = cv2.sqrBoxFilter(pre, cv2.CV_32F, (pw, ph), anchor=(0, 0), normalize=True,
                               borderType=cv2.BORDER_CONSTANT)
    patch_mean, patch_std = (float(v[0, 0]) for v in cv2.meanStdDev(patch))
    patch_mean, patch_var = brightness.to_pre(patch_mean, patch_std * patch_std)
    cmap: np.ndarray = correspondence_factors(ncc, mean, mean_sq, patch_mean, patch_var, params.mean_scale)
    return cmap


def match_eye(pre: np.ndarray, post: np.ndarray, params: CorrespondenceParams) -> EyeMatch:
    """Find one eye's post-fixation foveal patch in its pre-fixation image, and how sure we are:
    eqs. 1-6 in the paper's profile, the context search and its confidence in the default
    (module doc)."""
    pre = _grey(pre)
    post = _grey(post)
    if pre.shape != post.shape:
        raise CorrespondenceError(f"pre-fixation image {pre.shape} and post-fixation image {post.shape} differ")
    levels = params.pyramid_levels
    if levels is None:
        levels = 1 if pre.shape[1] > 400 else 0
    if params.paper or params.context_levels == 0:
        return _match_plain(pre, post, params, levels)
    return _match_in_context(pre, post, params, levels + params.context_levels)


def _grey(image: np.ndarray) -> np.ndarray:
    """The 2-D grey image of `image`: a uint8 one as it is (the matching converts the windows
    it reads to float, and `_Pyramid` averages the rest exactly), any other `as_grey_float`."""
    img = np.asarray(image)
    if img.dtype == np.uint8 and img.ndim == 3 and img.shape[2] == 3:
        return cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
    if img.dtype == np.uint8 and img.ndim == 2:
        return img
    return as_grey_float(img)


def _pyramid(image: np.ndarray, levels: int) -> np.ndarray:
    """The grey float image at 1/2**levels of each side (INTER_AREA)."""
    scale = 2 ** levels
    image = as_grey_float(image)
    return cv2.resize(image, (image.shape[1] // scale, image.shape[0] // scale), interpolation=cv2.INTER_AREA)


class _Pyramid:
    """An image (`_grey`'s) and its levels `_pyramid(image, n)`, each made once. Where the
    image's sides are whole multiples of 2**n, INTER_AREA averages whole blocks, so a level is
    made from the finest one already made, or a uint8 image's by its exact block means (no
    float copy of the image): a fraction of the work for the same pixels (a float image's to
    float32 rounding)."""

    def __init__(self, image: np.ndarray) -> None:
        self._levels = {0: image}

    def level(self, levels: int) -> np.ndarray:
        if levels not in self._levels:
            image = self._levels[0]
            scale = 2 ** levels
            whole = image.shape[0] % scale == 0 and image.shape[1] % scale == 0
            finer = max(k for k in self._levels if k < levels) if whole else 0
            if whole and finer == 0 and image.dtype == np.uint8:
                self._levels[levels] = block_means(np.ascontiguousarray(image), scale)
            else:
                self._levels[levels] = _pyramid(self._levels[finer], levels - finer)
        return self._levels[levels]


def _coarse_fovea(post: np.ndarray, levels: int, size: tuple[int, int]) -> np.ndarray:
    """`foveal_patch(_pyramid(post, levels), size)`, made from the fovea's blocks alone where
    the image's sides are whole multiples of 2**levels (the same pixels: INTER_AREA averages
    whole blocks)."""
    scale = 2 ** levels
    h, w = post.shape
    pw, ph = size
    if w % scale or h % scale or pw > w // scale or ph > h // scale:
        return foveal_patch(_pyramid(post, levels), size)
    x0, y0 = (w // scale - pw) // 2 * scale, (h // scale - ph) // 2 * scale
    return _pyramid(post[y0:y0 + ph * scale, x0:x0 + pw * scale], levels)


def _eqs_4_6(c_max: float, competitors: float, params: CorrespondenceParams,
             tau: float | None = None) -> tuple[float, float]:
    """(c1, c2): eq. 4 of a peak's C (with Table I's tau unless given), eq. 6 of the competing mass."""
    tau = params.min_correlation if tau is None else tau
    c_s, c_t = 10.0 / (1.0 - tau), (1.0 + tau) / 2.0  # eq. 4's slope and threshold from tau
    return float(1.0 / (1.0 + np.exp(-c_s * (c_max - c_t)))), float(1.0 / (1.0 + competitors))


def _refine(pre: np.ndarray, patch: np.ndarray, centre: tuple[float, float], margin: int,
            params: CorrespondenceParams, brightness: BrightnessChange = NO_CHANGE) -> tuple[float, float, float]:
    """Eq. 1 at full resolution within `margin` px of a coarse peak's `centre`: (x, y, c_max)."""
    ph, pw = patch.shape
    u0 = min(max(int(round(centre[0] - (pw - 1) / 2.0)) - margin, 0), pre.shape[1] - pw)
    v0 = min(max(int(round(centre[1] - (ph - 1) / 2.0)) - margin, 0), pre.shape[0] - ph)
    u1 = min(pre.shape[1], u0 + pw + 2 * margin)
    v1 = min(pre.shape[0], v0 + ph + 2 * margin)
    fine = correspondence_map(pre[v0:v1, u0:u1], patch, params, brightness)
    _, c_max, _, (fx, fy) = cv2.minMaxLoc(fine)
    u, v = subpixel_peak(fine, fy, fx)
    # A placement's top-left (u, v) holds a patch centred at (u + (pw-1)/2, v + (ph-1)/2).
    return u0 + u + (pw - 1) / 2.0, v0 + v + (ph - 1) / 2.0, float(c_max)


def _coarse_centre(ix: int, iy: int, coarse_patch: tuple[int, int], scale: int) -> tuple[float, float]:
    """Full-resolution centre of the coarse placement whose top-left is (ix, iy)."""
    cpw, cph = coarse_patch
    return (ix + (cpw - 1) / 2.0 + 0.5) * scale - 0.5, (iy + (cph - 1) / 2.0 + 0.5) * scale - 0.5


def _brightness(pre: _Pyramid, post: np.ndarray, params: CorrespondenceParams) -> BrightnessChange:
    """The change of brightness eq. 1's factors read the fovea through: estimated in the
    default profile (`compensate_brightness`), none in the paper's."""
    if params.paper or not params.compensate_brightness or not params.use_factors:
        return NO_CHANGE
    image = pre.level(0)
    return brightness_change(image, post, params.max_gain, params.max_offset,
                             pre.level(registration_level(image.shape[1])))


def _match_plain(pre: np.ndarray, post: np.ndarray, params: CorrespondenceParams, levels: int) -> EyeMatch:
    """Eqs. 1-6: the best C over the image (searched at 1/2**levels, refined at full
    resolution), c1 of its peak, c2 of the competing mass."""
    scale = 2 ** levels
    pw, ph = params.patch_size
    patch = as_grey_float(foveal_patch(post, params.patch_size))
    pyramid = _Pyramid(pre)
    brightness = _brightness(pyramid, post, params)
    if levels:
        coarse_pre = pyramid.level(levels)
        coarse_patch = _coarse_fovea(post, levels, (max(3, pw // scale), max(3, ph // scale)))
    else:
        coarse_pre, coarse_patch = pre, patch
    cmap = correspondence_map(coarse_pre, coarse_patch, params, brightness)
    _, coarse_max, _, (ix, iy) = cv2.minMaxLoc(cmap)
    competitors = _competing_mass(cmap, coarse_max, ix, iy, params.tolerance_radius * coarse_pre.shape[1], params)
    if levels:
        centre = _coarse_centre(ix, iy, (coarse_patch.shape[1], coarse_patch.shape[0]), scale)
        x, y, c_max = _refine(pre, patch, centre, 2 * scale, params, brightness)
    else:
        u, v = subpixel_peak(cmap, iy, ix)
        x, y, c_max = u + (pw - 1) / 2.0, v + (ph - 1) / 2.0, float(coarse_max)
    if not params.paper and params.refine_sigma_fraction > 0:
        x, y = centre_weighted_peak(pre, patch, x, y, params.refine_sigma_fraction * pw)
    c1, c2 = _eqs_4_6(c_max, competitors, params)
    return EyeMatch(x=float(x), y=float(y), c_max=c_max, c1=c1, c2=c2, competitors=competitors,
                    brightness=brightness)


@dataclass(frozen=True)
class _ContextPeak:
    """The best placement of the context patch at one pyramid level, and its best rival."""

    levels: int
    size: tuple[int, int]  # the context patch at that level (w, h)
    ix: int  # its top-left at that level
    iy: int
    c_max: float
    second: float  # the best other local maximum, however far
    competitors: float  # eq. 5's mass over the context map

    @property
    def margin(self) -> float:
        return self.c_max - self.second


def _context_peak(pre: _Pyramid, post: np.ndarray, params: CorrespondenceParams, levels: int,
                  brightness: BrightnessChange) -> _ContextPeak | None:
    """Eq. 1 with the fovea's context at 1/2**levels (a patch of `patch_size` there); None when
    the image is too small at that level."""
    pw, ph = params.patch_size
    scale = 2 ** levels
    size = (min(pw, post.shape[1] // scale - 2), min(ph, post.shape[0] // scale - 2))
    if min(size) < 3:
        return None
    coarse_pre = pre.level(levels)
    cmap = correspondence_map(coarse_pre, _coarse_fovea(post, levels, size), params, brightness)
    _, c_max, _, (ix, iy) = cv2.minMaxLoc(cmap)
    competitors = _competing_mass(cmap, c_max, ix, iy, params.tolerance_radius * coarse_pre.shape[1], params)
    return _ContextPeak(levels, size, ix, iy, float(c_max), _second_peak(cmap, ix, iy), competitors)


def _match_in_context(pre: np.ndarray, post: np.ndarray, params: CorrespondenceParams, levels: int) -> EyeMatch:
    """The default profile (module doc): the context search at 1/2**levels with a patch of
    `patch_size` there (wider while its peak is not distinct), refined, relocated and aligned
    at full resolution; confidence c1(context) d b."""
    pyramid = _Pyramid(pre)
    pyramid.level(levels)  # first: the registration's coarser level is then made from it
    brightness = _brightness(pyramid, post, params)
    peak = _context_peak(pyramid, post, params, levels, brightness)
    if peak is None:
        return _match_plain(pre, post, params, 0)  # too small an image for a context
    for wider in range(levels + 1, levels + 1 + params.wider_context_levels):
        if peak.margin >= params.distinct_margin:
            break
        candidate = _context_peak(pyramid, post, params, wider, brightness)
        if candidate is None:
            break
        if candidate.margin > peak.margin:
            peak = candidate
    scale = 2 ** peak.levels
    pw, ph = params.patch_size
    f = params.refine_patch_factor or (2.0 if pre.shape[1] <= 400 else 3.0)
    refine_size = (min(int(round(f * pw)), pre.shape[1] - 2), min(int(round(f * ph)), pre.shape[0] - 2))
    patch = as_grey_float(foveal_patch(post, refine_size))
    x, y, c_max = _refine(pre, patch, _coarse_centre(peak.ix, peak.iy, peak.size, scale), 2 * scale, params,
                          brightness)
    if params.refine_sigma_fraction > 0:
        x, y = centre_weighted_peak(pre, patch, x, y, params.refine_sigma_fraction * refine_size[0])
    if params.alignment_iterations > 0:
        x, y = warp_aligned(pre, patch, x, y, params.alignment_iterations, params.alignment_warp)
    c1, c2 = _eqs_4_6(c_max, peak.competitors, params)
    backward = _backward_distance(pre, post, x, y, params)
    c1_context, _ = _eqs_4_6(peak.c_max, 0.0, params, params.context_min_correlation)
    distinct = 1.0 - np.exp(-(max(0.0, peak.margin) / params.distinct_margin) ** 2)
    agrees = 0.0 if backward < 0 else 1.0 / (1.0 + (backward / params.backward_tolerance_px) ** 4)
    return EyeMatch(x=float(x), y=float(y), c_max=c_max, c1=c1, c2=c2, competitors=peak.competitors,
                    confidence=float(c1_context * distinct * agrees), context_c_max=peak.c_max,
                    second_peak=peak.second, backward_px=backward, brightness=brightness)


_PEAK_RADIUS = 3  # coarse pixels: a peak is the maximum of its 7 x 7 neighbourhood
_PEAK_KERNEL = cv2.getStructuringElement(cv2.MORPH_RECT, (2 * _PEAK_RADIUS + 1, 2 * _PEAK_RADIUS + 1))


def _second_peak(cmap: np.ndarray, ix: int, iy: int) -> float:
    """The best local maximum of `cmap` other than the peak at (ix, iy), however far (-1: none)."""
    return float(second_peak(cmap, cv2.dilate(cmap, _PEAK_KERNEL), ix, iy, _PEAK_RADIUS))


def _backward_distance(pre: np.ndarray, post: np.ndarray, x: float, y: float,
                       params: CorrespondenceParams) -> float:
    """Forward-backward check: the pre-fixation patch at (x, y) (`patch_size` times
    `backward_patch_factor`), searched in the post-fixation image within `backward_radius_px`
    of the fovea; how far from the fovea it lands (px, -1 if the patch at (x, y) leaves the
    image)."""
    pw, ph = (min(int(round(params.backward_patch_factor * side)), limit - 2)
              for side, limit in zip(params.patch_size, (pre.shape[1], pre.shape[0])))
    a0, b0 = int(round(x - (pw - 1) / 2.0)), int(round(y - (ph - 1) / 2.0))
    if a0 < 0 or b0 < 0 or a0 + pw > pre.shape[1] or b0 + ph > pre.shape[0]:
        return -1.0
    template = as_grey_float(pre[b0:b0 + ph, a0:a0 + pw])
    h, w = post.shape
    fx, fy = (w - pw) // 2, (h - ph) // 2  # the foveal patch's top-left
    r = params.backward_radius_px
    u0, v0 = max(0, fx - r), max(0, fy - r)
    window = as_grey_float(post[v0:min(h, fy + ph + r), u0:min(w, fx + pw + r)])
    scores = cv2.matchTemplate(window, template, cv2.TM_CCOEFF_NORMED)
    cv2.patchNaNs(scores, 0.0)
    _, _, _, (lx, ly) = cv2.minMaxLoc(scores)
    u, v = subpixel_peak(scores, ly, lx)
    # The template was cut at whole pixels: (x, y)'s fraction shifts where it should land.
    dx = u0 + u - fx - (x - (pw - 1) / 2.0 - a0)
    dy = v0 + v - fy - (y - (ph - 1) / 2.0 - b0)
    return float(np.hypot(dx, dy))


def _competing_mass(cmap: np.ndarray, c_max: float, ix: int, iy: int, sigma_c: float,
                    params: CorrespondenceParams) -> float:
    """Eq. 5 summed over the map: T(C - delta) times the squared distance from the peak / sigma_c."""
    if c_max <= 0:
        return 0.0
    delta = params.min_ratio_to_compete * c_max  # eq. 5's threshold, delta = R * c_max
    return float(competing_mass(cmap, ix, iy, delta, sigma_c))


def match_fixation(pre_left: np.ndarray, pre_right: np.ndarray, post_left: np.ndarray, post_right: np.ndarray,
                   params: CorrespondenceParams | None = None) -> FixationMatch:
    """r* = (x*, y*, d*) of a fixation and its confidence, from the pre- and post-fixation pairs."""
    params = params or CorrespondenceParams()
    # The two eyes are independent, and OpenCV and the compiled kernels release the GIL: the
    # right eye is matched on a second thread while this one does the left (a pair then takes
    # little more than one eye's CPU time: `benchmarks.bench.fixation`).
    right = _eye_pool().submit(match_eye, pre_right, post_right, params)
    left = match_eye(pre_left, post_left, params)
    return FixationMatch(left, right.result())


def warm_up() -> float:
    """Compile (or load from numba's cache) the matching's kernels now, on a made-up stereo
    pair; returns the seconds it took. numba compiles on first call: about 10 s on the first
    run after an install, a fraction of a second from the cache beside
    `_correspondence_kernels.py`. Paid at startup, it is not paid inside the first fixation."""
    start_s = time.perf_counter()
    rng = np.random.default_rng(0)
    image = cv2.GaussianBlur((rng.random((240, 320)) * 255).astype(np.uint8), (0, 0), 2.0)
    match_fixation(image, image, image, image)
    return time.perf_counter() - start_s


_POOL: ThreadPoolExecutor | None = None
_POOL_LOCK = threading.Lock()


def _eye_pool() -> ThreadPoolExecutor:
    """One worker thread, made on first use and kept for the process: matching the right eye."""
    global _POOL
    with _POOL_LOCK:
        if _POOL is None:
            _POOL = ThreadPoolExecutor(max_workers=1, thread_name_prefix="correspondence-right-eye")
        return _POOL
