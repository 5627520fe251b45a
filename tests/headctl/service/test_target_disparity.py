"""The disparity a target sent without d is looked at with (`headctl.service.control`): measured
along a band of rows of the right image, else 0 where the look can find the target by its
patch, else refused naming `d`. Synthetic pairs whose true disparity is known."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from calib_free.gaze.fixation import LookParams
from headctl.errors import InvalidRequestError
from headctl.service.control import DISPARITY_BAND_PX, disparity_at, target_disparity

PATCH = (32, 20)  # fixation.vergence_patch_size's default
RANGE = (-60.0, 60.0)  # the map's disparity range's default


def textured(seed: int, shape: tuple[int, int] = (240, 320)) -> np.ndarray:
    """Smooth random texture, grey levels 0-255: every patch distinct."""
    noise = np.random.default_rng(seed).normal(size=shape).astype(np.float32)
    smooth = cv2.GaussianBlur(noise, (0, 0), 1.5)
    return (smooth - smooth.min()) * (255.0 / float(np.ptp(smooth)))


def shifted(image: np.ndarray, dx: int, dy: int) -> np.ndarray:
    """The image with its content moved right by dx and down by dy pixels."""
    return np.roll(image, (dy, dx), axis=(0, 1))


@pytest.mark.parametrize("dy", [0, -2, DISPARITY_BAND_PX])
def test_a_disparity_is_measured_across_a_few_rows_of_vertical_disparity(dy):
    left = textured(1)
    d, ncc = disparity_at(left, shifted(left, 7, dy), 150.3, 110.0, PATCH, RANGE)
    assert d == pytest.approx(7.0, abs=0.3) and ncc > 0.9


def test_a_target_whose_disparity_cannot_be_measured_is_looked_at_from_the_fixation_depth():
    left = textured(2)
    for right, where in ((textured(3), "seen by the left eye only"),
                         (shifted(left, 7, DISPARITY_BAND_PX + 4), "a vertical disparity beyond the band"),
                         (shifted(left, 70, 0), "a disparity beyond the map's range")):
        found = target_disparity(left, right, 150.0, 110.0, PATCH, RANGE, LookParams())
        assert not found.measured and found.ncc is None and found.d == 0.0, where
        assert "could not be measured" in found.reason and "d = 0" in found.reason, where
    # Near the border the 32 x 20 patch does not fit, the look's 21 x 21 does.
    near = target_disparity(left, shifted(left, 5, 0), 12.0, 120.0, PATCH, RANGE, LookParams())
    assert not near.measured and near.d == 0.0
    measured = target_disparity(left, shifted(left, 5, 0), 150.0, 110.0, PATCH, RANGE, LookParams())
    assert measured.measured and measured.d == pytest.approx(5.0, abs=0.3) and measured.reason == ""


def test_a_target_without_a_patch_to_find_it_by_is_refused_naming_d():
    left = textured(4)
    left[60:180, 80:240] = 128.0  # a uniform wall
    stripes = np.tile(np.where(np.arange(320) % 8 < 4, 40.0, 200.0), (240, 1))
    for image, x, y, why in ((left, 160.0, 120.0, "no texture"), (left, 2.0, 2.0, "beyond the image"),
                             (stripes, 160.0, 120.0, "ambiguous")):
        with pytest.raises(InvalidRequestError) as err:
            target_disparity(image, textured(5), x, y, PATCH, RANGE, LookParams())
        assert err.value.field == "d" and "cannot be looked at" in str(err.value) and why in str(err.value)
    # Its d measured or not: 9.6 rows from the top the 32 x 20 patch fits, the look's 21 x 21 does not.
    measurable = textured(6)
    assert disparity_at(measurable, shifted(measurable, 5, 0), 150.0, 9.6, PATCH, RANGE)[1] > 0.9
    for image, x, y, why in ((measurable, 150.0, 9.6, "beyond the image"), (stripes, 160.0, 120.0, "ambiguous")):
        with pytest.raises(InvalidRequestError) as err:
            target_disparity(image, shifted(image, 5, 0), x, y, PATCH, RANGE, LookParams())
        assert err.value.field == "d" and "cannot be looked at" in str(err.value) and why in str(err.value)
