"""The scaled own-view diagnostic: a repeat seen at another scale, and the refusals it counts."""
from __future__ import annotations

import cv2
import numpy as np

from benchmarks.diag.scaled_own_view import own_view_margins, refusals
from tests.support.planar_head import HEIGHT, WIDTH


def test_a_repeat_magnified_by_a_quarter_lowers_the_scaled_margin_not_the_plain_one():
    noise = np.random.default_rng(4).uniform(0.0, 255.0, (HEIGHT, WIDTH)).astype(np.float32)
    image = cv2.GaussianBlur(noise, (0, 0), 1.5)  # fine texture: a quarter's magnification changes it
    xy = (100.0, 120.0)
    unique = own_view_margins(image, xy, (0.8, 1.25))
    assert unique is not None and min(unique) > 0.2  # nothing like it elsewhere, at any scale tried
    # The target's surroundings, magnified 1.25 times, copied 60 px to its right.
    u, v, half = int(xy[0]), int(xy[1]), 20
    region = image[v - half:v + half + 1, u - half:u + half + 1]
    magnified = cv2.resize(region, None, fx=1.25, fy=1.25, interpolation=cv2.INTER_LINEAR)
    h, w = magnified.shape
    copied = image.copy()
    copied[v - h // 2:v - h // 2 + h, u + 60 - w // 2:u + 60 - w // 2 + w] = magnified
    plain, scaled = own_view_margins(copied, xy, (0.8, 1.25))
    assert plain > 0.1  # unlike the target at its own scale: the plain check takes it
    assert scaled < 0.05  # the patch resampled 1.25 times finds the copy
    assert own_view_margins(image, (5.0, 120.0), (1.1,)) is None  # the patch reaches beyond the image


def test_refusals_count_the_looks_below_the_threshold_by_how_they_ended():
    rows = [{"on_target": True, "ambiguous": False, "plain": 0.3, "scaled": 0.08},
            {"on_target": False, "ambiguous": True, "plain": 0.12, "scaled": 0.04},
            {"on_target": False, "ambiguous": False, "plain": 0.05, "scaled": 0.05}]
    assert refusals(rows, "plain", 0.1) == (0, 0)
    assert refusals(rows, "scaled", 0.1) == (1, 1)
