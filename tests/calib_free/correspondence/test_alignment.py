"""The default profile's last steps against their references: the centre-weighted NCC against
OpenCV's masked definition evaluated directly, the affine alignment against known warps and
`cv2.findTransformECC`, the quadratic alignment against a compression that changes across the
patch."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from calib_free.correspondence.alignment import centre_weighted_ncc, centre_weighted_peak, warp_aligned


def texture(seed: int, shape: tuple[int, int], blur: float = 1.5) -> np.ndarray:
    rng = np.random.default_rng(seed)
    tex = cv2.GaussianBlur(rng.random(shape, dtype=np.float32) * 255, (0, 0), blur)
    return cv2.normalize(tex, None, 10, 245, cv2.NORM_MINMAX)


def masked_ncc_by_definition(window: np.ndarray, template: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """OpenCV's TM_CCOEFF_NORMED with a mask M, placement by placement in float64: T' = M (T -
    m_T), I' = M (I - m_I) with M-weighted means, score = sum T' I' / sqrt(sum T'^2 sum I'^2)."""
    th, tw = template.shape
    m = mask.astype(np.float64)
    t = template.astype(np.float64)
    t_prime = m * (t - np.sum(m * t) / m.sum())
    out = np.zeros((window.shape[0] - th + 1, window.shape[1] - tw + 1))
    for v in range(out.shape[0]):
        for u in range(out.shape[1]):
            i = window[v:v + th, u:u + tw].astype(np.float64)
            i_prime = m * (i - np.sum(m * i) / m.sum())
            out[v, u] = np.sum(t_prime * i_prime) / np.sqrt(np.sum(t_prime ** 2) * np.sum(i_prime ** 2))
    return out


@pytest.mark.parametrize("size, radius", [((60, 60), 4), ((40, 40), 4), ((20, 12), 2), ((5, 9), 3)])
def test_centre_weighted_ncc_is_opencvs_masked_ncc(size, radius):
    tw, th = size
    tex = texture(1, (th + 2 * radius + 10, tw + 2 * radius + 10))
    rng = np.random.default_rng(2)
    window = tex[3:3 + th + 2 * radius, 5:5 + tw + 2 * radius]
    template = tex[3 + radius + 1:3 + radius + 1 + th, 5 + radius - 1:5 + radius - 1 + tw]
    template = template + rng.normal(0, 2, template.shape).astype(np.float32)
    sigma = 0.25 * tw
    mask = cv2.getGaussianKernel(th, sigma, cv2.CV_32F) @ cv2.getGaussianKernel(tw, sigma, cv2.CV_32F).T
    scores = centre_weighted_ncc(window, template, sigma)
    assert scores.shape == (2 * radius + 1, 2 * radius + 1)
    np.testing.assert_allclose(scores, masked_ncc_by_definition(window, template, mask), atol=1e-4)
    opencv = cv2.matchTemplate(window, template, cv2.TM_CCOEFF_NORMED, mask=mask)
    np.testing.assert_allclose(scores, opencv, atol=2e-2)  # OpenCV's float32 sums are coarser
    assert np.unravel_index(np.argmax(scores), scores.shape) == (radius + 1, radius - 1)


def test_centre_weighted_ncc_scores_flat_windows_and_templates_0():
    window = texture(3, (28, 28))
    window[:12, :] = 80.0  # the top placements see a flat window
    template = texture(4, (20, 20))
    scores = centre_weighted_ncc(window, template, 5.0)
    assert np.all(np.isfinite(scores))
    flat_template = centre_weighted_ncc(texture(5, (28, 28)), np.full((20, 20), 50.0, np.float32), 5.0)
    assert np.all(flat_template == 0.0)
    uniform = centre_weighted_ncc(np.full((28, 28), 80.0, np.float32), template, 5.0)
    assert np.all(uniform == 0.0)


def test_centre_weighted_peak_finds_a_shift_to_a_fraction_of_a_pixel():
    tex = texture(6, (200, 200), blur=2.5)
    patch = tex[70:130, 80:140]  # centred at (109.5, 99.5)
    shifted = cv2.warpAffine(tex, np.float32([[1, 0, 0.3], [0, 1, -0.2]]), (200, 200))
    x, y = centre_weighted_peak(shifted, patch, 109.0, 100.0, 15.0)
    assert (x, y) == pytest.approx((109.8, 99.3), abs=0.1)


def affine_case(seed: int, matrix: np.ndarray) -> tuple[np.ndarray, np.ndarray, tuple[float, float]]:
    """A 60 x 60 patch and an image that holds it under `matrix` (image = matrix * patch
    coordinates, about the patch centre), and where the patch centre lies in the image."""
    tex = texture(seed, (240, 240), blur=2.0)
    patch = tex[90:150, 90:150].copy()
    centre = np.array([119.5, 119.5])
    to_image = np.hstack([matrix, (centre - matrix @ centre)[:, None]])  # fixes the patch centre
    image = cv2.warpAffine(tex, to_image.astype(np.float32), (240, 240), flags=cv2.INTER_LINEAR)
    return image, patch, (119.5, 119.5)


@pytest.mark.parametrize("matrix", [np.eye(2), np.array([[0.93, 0.02], [-0.03, 1.0]]),
                                    np.array([[1.0, 0.05], [0.0, 0.9]])])
@pytest.mark.parametrize("warp", ["affine", "quadratic"])
def test_alignment_lands_on_the_centre_under_a_local_compression(matrix, warp):
    image, patch, (tx, ty) = affine_case(7, matrix)
    x, y = warp_aligned(image, patch, tx + 1.0, ty - 0.8, 5, warp)  # a guess off by a pixel or so
    assert (x, y) == pytest.approx((tx, ty), abs=0.05)


def test_affine_alignment_agrees_with_opencvs_ecc():
    image, patch, (tx, ty) = affine_case(8, np.array([[0.95, 0.03], [0.01, 0.97]]))
    x, y = warp_aligned(image, patch, tx + 0.7, ty + 0.6, 5, "affine")
    a0, b0 = int(round(tx + 0.7 - 29.5)) - 6, int(round(ty + 0.6 - 29.5)) - 6
    warp = np.float32([[1, 0, tx + 0.7 - 29.5 - a0], [0, 1, ty + 0.6 - 29.5 - b0]])
    _, warp = cv2.findTransformECC(patch, np.ascontiguousarray(image[b0:b0 + 72, a0:a0 + 72]), warp,
                                   cv2.MOTION_AFFINE, (cv2.TERM_CRITERIA_COUNT, 30, 0), None, 1)
    reference = warp.astype(np.float64) @ np.array([29.5, 29.5, 1.0]) + (a0, b0)
    assert (x, y) == pytest.approx(tuple(reference), abs=0.05)


@pytest.mark.parametrize("warp", ["affine", "quadratic"])
def test_alignment_keeps_the_guess_without_evidence(warp):
    image, patch, (tx, ty) = affine_case(9, np.eye(2))
    assert warp_aligned(image, np.full_like(patch, 90.0), tx, ty, 5, warp) == (tx, ty)  # a flat patch
    assert warp_aligned(image, patch, 33.0, ty, 5, warp) == (33.0, ty)  # the window leaves the image
    far = texture(10, (60, 60))  # another surface: no alignment within 3 px, or a diverging one
    x, y = warp_aligned(image, far, tx, ty, 5, warp)
    assert np.hypot(x - tx, y - ty) <= 3.0


def graded_compression_case(seed: int, scale: float, gradient: float) -> tuple[np.ndarray, np.ndarray]:
    """A 60 x 60 patch centred at (119.5, 119.5) of a texture, and an image that holds it
    compressed along x by a factor that changes across the patch, as the fish-eye's periphery
    does: image column X shows the texture at 119.5 + scale X' + gradient X'^2 (X' = X - 119.5),
    so the patch centre stays at (119.5, 119.5)."""
    tex = texture(seed, (240, 240), blur=2.0)
    patch = tex[90:150, 90:150].copy()
    offset = np.arange(240, dtype=np.float32) - 119.5
    map_x = np.tile(119.5 + scale * offset + gradient * offset ** 2, (240, 1)).astype(np.float32)
    map_y = np.tile(np.arange(240, dtype=np.float32)[:, None], (1, 240))
    return cv2.remap(tex, map_x, map_y, cv2.INTER_LINEAR), patch


@pytest.mark.parametrize("gradient", [1.5e-3, -1.5e-3])
def test_quadratic_alignment_follows_a_compression_that_changes_across_the_patch(gradient):
    image, patch = graded_compression_case(11, 1.1, gradient)
    quadratic = warp_aligned(image, patch, 120.3, 119.0, 10, "quadratic")
    affine = warp_aligned(image, patch, 120.3, 119.0, 10, "affine")
    assert quadratic == pytest.approx((119.5, 119.5), abs=0.05)
    # The best affine fit averages the compression over the patch and misplaces its centre
    # towards the less compressed side (-x for a positive gradient), as the periphery's matches
    # lie nearer the image centre than the truth.
    assert np.sign(affine[0] - 119.5) == np.sign(-gradient) and abs(affine[0] - 119.5) > 0.1


def test_an_unknown_warp_is_refused_by_name():
    image, patch, (tx, ty) = affine_case(9, np.eye(2))
    with pytest.raises(ValueError, match="projective"):
        warp_aligned(image, patch, tx, ty, 5, "projective")
