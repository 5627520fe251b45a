"""The correspondence map and the context search's parts against their definitions, evaluated
directly in the tests: eq. 1 with the bounded factors, eq. 5's competing mass, the best other
peak, the shared pyramid; and a match does not depend on the images' type."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from calib_free.correspondence import search as correspondence
from calib_free.correspondence.search import CorrespondenceParams, correspondence_map, foveal_patch, match_eye


def texture(seed: int, shape: tuple[int, int], blur: float = 1.5) -> np.ndarray:
    rng = np.random.default_rng(seed)
    tex = cv2.GaussianBlur(rng.random(shape, dtype=np.float32) * 255, (0, 0), blur)
    return cv2.normalize(tex, None, 10, 245, cv2.NORM_MINMAX)


def map_by_definition(pre: np.ndarray, patch: np.ndarray, mean_scale: float) -> np.ndarray:
    """C = NCC f1 f2 placement by placement in float64 (module doc of `correspondence`)."""
    ph, pw = patch.shape
    t = patch.astype(np.float64)
    out = np.zeros((pre.shape[0] - ph + 1, pre.shape[1] - pw + 1))
    for v in range(out.shape[0]):
        for u in range(out.shape[1]):
            i = pre[v:v + ph, u:u + pw].astype(np.float64)
            di, dt = i - i.mean(), t - t.mean()
            denominator = np.sqrt(np.sum(di * di) * np.sum(dt * dt))
            ncc = np.sum(di * dt) / denominator if denominator > 0 else 0.0
            f1 = 1.0 / (1.0 + abs(i.mean() - t.mean()) / mean_scale)
            f2 = 2.0 * min(i.var(), t.var()) / (i.var() + t.var() + 1e-6)
            out[v, u] = ncc * f1 * f2
    return out


def test_the_correspondence_map_is_eq_1_with_the_bounded_factors():
    pre = texture(1, (60, 70))
    pre[5:30, 40:70] = 100.0  # flat windows: no evidence
    patch = 0.6 * texture(2, (12, 16)) + 40.0  # another mean and contrast than the image's
    patch[3:9, 4:12] = pre[20:26, 8:16]
    cmap = correspondence_map(pre, patch, CorrespondenceParams(mean_scale=10.0))
    np.testing.assert_allclose(cmap, map_by_definition(pre, patch, 10.0), atol=1e-4)


def test_the_competing_mass_is_eq_5():
    rng = np.random.default_rng(3)
    cmap = rng.uniform(-0.2, 0.6, (40, 50)).astype(np.float32)
    cmap[10, 12] = 0.9  # the peak
    cmap[30, 40] = 0.88  # far competitors above delta = 0.95 * 0.9 = 0.855
    cmap[11, 13] = 0.86
    sigma_c = 5.0
    expected = sum((c - 0.855) * ((u - 12) ** 2 + (v - 10) ** 2) / sigma_c ** 2
                   for (v, u), c in np.ndenumerate(cmap.astype(np.float64)) if c >= 0.855)
    mass = correspondence._competing_mass(cmap, 0.9, 12, 10, sigma_c, CorrespondenceParams())
    assert mass == pytest.approx(expected, rel=1e-5)
    assert correspondence._competing_mass(cmap - 1.0, -0.1, 12, 10, sigma_c, CorrespondenceParams()) == 0.0


def test_the_second_peak_is_the_best_other_local_maximum_however_far():
    yy, xx = np.mgrid[0:40, 0:60]
    bumps = [(10, 12, 0.9), (12, 14, 0.85), (30, 50, 0.7), (5, 40, 0.6)]  # (row, col, height)
    cmap = np.zeros((40, 60), np.float32)
    for v, u, c in bumps:
        cmap = np.maximum(cmap, c * np.exp(-((yy - v) ** 2 + (xx - u) ** 2) / 2.0)).astype(np.float32)
    # (12, 14) lies within the peak's 7 x 7 square: not a rival; (30, 50) is the best beyond it.
    assert correspondence._second_peak(cmap, 12, 10) == pytest.approx(0.7)
    assert correspondence._second_peak(np.full((20, 20), 0.3, np.float32), 5, 5) == pytest.approx(0.3)
    single = np.zeros((20, 20), np.float32) - 1.0
    single[5, 5] = 0.5
    assert correspondence._second_peak(single, 5, 5) == pytest.approx(-1.0)


@pytest.mark.parametrize("shape, dtype", [((480, 640), np.uint8), ((480, 640), np.float32),
                                          ((242, 322), np.uint8), ((240, 320), np.float64)])
def test_the_pyramid_and_the_coarse_fovea_are_those_of_the_whole_image(shape, dtype):
    image = (texture(11, shape) if dtype != np.uint8 else texture(11, shape).round()).astype(dtype)
    pyramid = correspondence._Pyramid(correspondence._grey(image))
    reference = image.astype(np.float32)
    for levels in (2, 3, 1):  # out of order: a level is made from the finest one made before
        h, w = shape[0] // 2 ** levels, shape[1] // 2 ** levels
        expected = cv2.resize(reference, (w, h), interpolation=cv2.INTER_AREA)
        if dtype == np.uint8:  # sums of integers: exact, however the level is made
            np.testing.assert_array_equal(pyramid.level(levels), expected)
        else:  # from a finer level: the same to float32's rounding
            np.testing.assert_allclose(pyramid.level(levels), expected, rtol=1e-6)
        fovea = correspondence._coarse_fovea(correspondence._grey(image), levels, (20, 20))
        np.testing.assert_array_equal(fovea, foveal_patch(expected, (20, 20)))


def test_a_match_does_not_depend_on_the_images_type():
    tex = texture(12, (700, 900)).round()
    pre, post = tex[100:580, 100:740], tex[157:637, 17:657]
    as_uint8 = match_eye(pre.astype(np.uint8), post.astype(np.uint8), CorrespondenceParams())
    as_float = match_eye(pre.astype(np.float32), post.astype(np.float32), CorrespondenceParams())
    bgr = match_eye(cv2.cvtColor(pre.astype(np.uint8), cv2.COLOR_GRAY2BGR),
                    cv2.cvtColor(post.astype(np.uint8), cv2.COLOR_GRAY2BGR), CorrespondenceParams())
    assert as_uint8 == as_float == bgr
    assert (as_uint8.x, as_uint8.y) == pytest.approx((319.5 - 83, 239.5 + 57), abs=0.1)


def test_warm_up_runs_every_kernel_of_the_matching(monkeypatch):
    """numba compiles a kernel on its first call: warm-up must make every one of them."""
    from calib_free.correspondence import alignment as patch_alignment

    called = set()
    for module, names in ((correspondence, ("block_means", "correspondence_factors", "second_peak", "competing_mass")),
                          (patch_alignment, ("centre_weighted_terms", "centre_weighted_scores", "ecc_polynomial"))):
        for name in names:
            kernel = getattr(module, name)
            monkeypatch.setattr(module, name, lambda *a, _k=kernel, _n=name: called.add(_n) or _k(*a))
    assert correspondence.warm_up() >= 0.0
    assert called == {"block_means", "correspondence_factors", "second_peak", "competing_mass",
                      "centre_weighted_terms", "centre_weighted_scores", "ecc_polynomial"}
