"""A point's disparity along a band of rows (`calib_free.correspondence.disparity.disparity_at`):
synthetic pairs whose true disparity is known."""
from __future__ import annotations

import numpy as np
import pytest

from calib_free.correspondence.disparity import DISPARITY_BAND_PX, MIN_DISPARITY_NCC, disparity_at
from calib_free.errors import CalibFreeError, DisparityError
from tests.support.planar_head import HEIGHT, WIDTH, rich_texture

PATCH = (32, 20)
RANGE = (-60.0, 60.0)


def moved(image: np.ndarray, dx: int, dy: int) -> np.ndarray:
    return np.roll(image, (dy, dx), axis=(0, 1))


@pytest.mark.parametrize("dy", [0, 3, -DISPARITY_BAND_PX])
def test_a_disparity_is_found_within_the_band_of_rows(dy):
    left = rich_texture(seed=1, size=(WIDTH, HEIGHT))
    d, ncc = disparity_at(left, moved(left, -9, dy), 170.0, 100.0, PATCH, RANGE)
    assert d == pytest.approx(-9.0, abs=0.3) and ncc > 0.9


def test_a_disparity_the_pair_does_not_give_is_refused_saying_why():
    left = rich_texture(seed=1, size=(WIDTH, HEIGHT))
    for right in (rich_texture(seed=2, size=(WIDTH, HEIGHT)), moved(left, 4, DISPARITY_BAND_PX + 5),
                  moved(left, 80, 0)):
        with pytest.raises(DisparityError) as err:
            disparity_at(left, right, 170.0, 100.0, PATCH, RANGE)
        assert isinstance(err.value, CalibFreeError)
        assert str(err.value).startswith("the disparity at (170, 100) could not be measured (the best match "
                                         "in the right image scores NCC ")
        assert f"< {MIN_DISPARITY_NCC}: too near the border" in str(err.value)
    with pytest.raises(DisparityError):  # the patch does not fit: no match at all
        disparity_at(left, left, 5.0, 100.0, PATCH, RANGE)
