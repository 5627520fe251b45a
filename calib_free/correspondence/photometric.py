"""How the brightness of the view changed between the pre- and post-fixation images.

A camera's auto exposure and gain follow what the view holds, so the image after a saccade
can be brighter or darker than the one before it, and a sensor's black level can shift: the
post-fixation image is, to first order, an affine change of grey levels of the pre-fixation
one, post = gain * pre + offset, the same over the whole image. NCC does not see such a
change; eq. 1's mean and variance factors read every patch's statistics through it, so that
a gain of 1.2 alone turns the true match into "a patch of other brightness and contrast"
(docs/method.md). The default profile estimates the change and reads the foveal patch's
statistics in the pre-fixation image's grey levels (`BrightnessChange.to_pre`), so that the
factors compare what they are meant to: the patch's own brightness and contrast against its
look-alikes', not the camera's exposure.

The estimate (`brightness_change`): both images at about `REGISTRATION_WIDTH_PX` wide (block
means); the central half of the post-fixation one found in the pre-fixation one by NCC
(which a change of brightness leaves alone): the view the two share. The grey levels of the
two overlapping windows are then matched quantile by quantile (5 % to 95 %), and the gain
and offset are the least-squares line through those pairs. Quantiles rather than pixel
pairs: the lens distorts the two windows differently and the saccade's parallax moves near
things against far ones, which would scatter pixel pairs, while the distribution of grey
levels of the same view barely changes. Quantiles at which either window is saturated (a
gain that clips highlights) are left out. On rendered saccades of the photo room it is
within 4 % of the true gain and 1 grey level of the fovea's true mean at p10-p90
(`benchmarks.bench.photometric`).

A gain that brightens saturates highlights (and one that darkens, with a negative offset,
shadows): a foveal patch partly clipped has lost the mean and variance of its surface, and
no estimate gives them back, so where more than `MAX_CLIPPED_SHARE` of it is clipped the
factors are left out for it and C is its NCC (`clipped`). On the generated room, brighter
than the photo room, a gain of 1.4 clips a fifth of the foveae this much.

A change that moves no grey level of the shared view by more than `UNSEEN_CHANGE` is within
the estimate's own spread: none is assumed, and the factors read the images as they are.

A change beyond `max_gain` or `max_offset` is clamped to those bounds: what remains is read
by the factors as a difference of the patches, as without compensation. Where the shared
view cannot be found (registration NCC below `MIN_REGISTRATION_NCC`: a view with nothing in
common) or either window's grey levels span too little to fit a line (a flat view), no change
is assumed.
"""
from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from calib_free.correspondence._kernels import block_means, quantile_line
from calib_free.correspondence.disparity import as_grey_float

REGISTRATION_WIDTH_PX = 80  # the images are registered at about this width (block means)
MIN_REGISTRATION_NCC = 0.3  # a shared view found worse than this: no change assumed
QUANTILES = np.arange(5.0, 96.0, 5.0)  # percent: the grey-level quantiles matched
SATURATED = (4.0, 251.0)  # grey levels: a quantile outside this open range in either window is left out
# A foveal patch with more than this share of its pixels at the ends of the 8-bit range
# (0 or 255) has lost its mean and variance to the clipping: the factors are not applied to it.
MAX_CLIPPED_SHARE = 0.05
# A change moving no grey level of the shared view (its 5-95 % range) by more than this is
# within the estimate's own spread, and none is assumed: on rendered saccades without a change
# the estimate moves some level of that range by 3.2 grey levels at p90 in the photo room,
# 5.5 in the generated one.
UNSEEN_CHANGE = 4.0
MIN_SPAN = 4.0  # grey levels: the quantiles used must span at least this in each window (else no line to fit)


@dataclass(frozen=True)
class BrightnessChange:
    """post = gain * pre + offset, in grey levels; `registration_ncc` is how well the shared
    view was found (NaN: not estimated)."""

    gain: float = 1.0
    offset: float = 0.0
    registration_ncc: float = float("nan")

    def to_pre(self, mean: float, variance: float) -> tuple[float, float]:
        """A post-fixation patch's mean and variance in the pre-fixation image's grey levels."""
        return (mean - self.offset) / self.gain, variance / (self.gain * self.gain)


NO_CHANGE = BrightnessChange()


def clipped(patch: np.ndarray) -> bool:
    """Whether more than `MAX_CLIPPED_SHARE` of a grey patch (0-255) lies at 0 or 255."""
    return bool(np.count_nonzero((patch <= 0.0) | (patch >= 255.0)) > MAX_CLIPPED_SHARE * patch.size)


def registration_level(width: int) -> int:
    """The pyramid level (a power of 2) that brings `width` nearest `REGISTRATION_WIDTH_PX`."""
    return max(0, int(round(np.log2(max(width, 1) / REGISTRATION_WIDTH_PX))))


def _blocks(image: np.ndarray, scale: int) -> np.ndarray:
    """Block means of `scale` x `scale` (the image as float32 for 1)."""
    if scale == 1:
        return as_grey_float(image)
    if image.dtype == np.uint8:
        return np.asarray(block_means(np.ascontiguousarray(image), scale))
    grey = as_grey_float(image)
    return cv2.resize(grey, (grey.shape[1] // scale, grey.shape[0] // scale), interpolation=cv2.INTER_AREA)


def brightness_change(pre: np.ndarray, post: np.ndarray, max_gain: float, max_offset: float,
                      coarse_pre: np.ndarray | None = None) -> BrightnessChange:
    """The affine change of grey levels from `pre` to `post` (2-D grey images of one shape),
    clamped to a gain in [1/max_gain, max_gain] and an offset within +-max_offset (module
    doc). `coarse_pre`: `pre` already at the registration level, if the caller has it."""
    height, width = post.shape
    scale = 2 ** registration_level(width)
    # The post-fixation image's central half, from its own blocks (where the sides allow).
    th, tw = height // scale // 2, width // scale // 2
    y0, x0 = (height // scale - th) // 2 * scale, (width // scale - tw) // 2 * scale
    template = _blocks(post[y0:y0 + th * scale, x0:x0 + tw * scale], scale)
    coarse = coarse_pre if coarse_pre is not None else _blocks(pre, scale)
    if min(th, tw) < 3 or template.shape[0] > coarse.shape[0] or template.shape[1] > coarse.shape[1]:
        return NO_CHANGE
    scores = cv2.matchTemplate(coarse, template, cv2.TM_CCOEFF_NORMED)
    cv2.patchNaNs(scores, 0.0)
    _, ncc, _, (ix, iy) = cv2.minMaxLoc(scores)
    if not ncc >= MIN_REGISTRATION_NCC:
        return BrightnessChange(registration_ncc=float(ncc))
    shared = coarse[iy:iy + template.shape[0], ix:ix + template.shape[1]]
    gain, offset, mean_pre, low, high, fitted = quantile_line(
        np.sort(shared, axis=None), np.sort(template, axis=None), QUANTILES, *SATURATED, MIN_SPAN)
    if not fitted or max(abs((gain - 1.0) * low + offset), abs((gain - 1.0) * high + offset)) <= UNSEEN_CHANGE:
        return BrightnessChange(registration_ncc=float(ncc))
    clamped = float(np.clip(gain, 1.0 / max_gain, max_gain))
    # A clamped gain's offset: the line of that slope through the quantiles' means, then bounded.
    offset += (gain - clamped) * mean_pre
    return BrightnessChange(clamped, float(np.clip(offset, -max_offset, max_offset)), float(ncc))
