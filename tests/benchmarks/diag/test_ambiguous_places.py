"""The ambiguous-places diagnostic: a target and its copy, each scored plain and with its warp fitted."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from benchmarks.diag.ambiguous_places import (beyond_plan_shift_px, landing_measured, places_against_truth, verdict,
                                              verdict_by_distance)
from tests.support.planar_head import HEIGHT, WIDTH, rich_texture

FOVEA = np.array([(WIDTH - 1) / 2, (HEIGHT - 1) / 2])


def after_saccade(source: np.ndarray, source_xy: tuple[float, float], landed: np.ndarray,
                  copy_offset: tuple[int, int] | None) -> np.ndarray:
    """`source` moved so that `source_xy` lies at `landed`, with the square of 41 px about it
    copied `copy_offset` px away (a repeat) when given."""
    shift = np.array([[1.0, 0.0, landed[0] - source_xy[0]], [0.0, 1.0, landed[1] - source_xy[1]]])
    image = cv2.warpAffine(source, shift, (WIDTH, HEIGHT), flags=cv2.INTER_LINEAR)
    if copy_offset is not None:
        u, v, h = int(round(landed[0])), int(round(landed[1])), 12
        du, dv = copy_offset
        image[v + dv - h:v + dv + h + 1, u + du - h:u + du + h + 1] = image[v - h:v + h + 1, u - h:u + h + 1].copy()
    return image


def test_a_copy_of_the_target_scores_as_high_as_the_target_once_fitted_and_a_unique_one_does_not():
    source = rich_texture(seed=6, size=(WIDTH, HEIGHT))
    source_xy, landed = (230.4, 80.7), FOVEA + np.array([0.4, -0.3])
    truth = (float(landed[0]), float(landed[1]))
    copied = places_against_truth(source, source_xy, after_saccade(source, source_xy, landed, (30, 0)), (21, 21),
                                  truth, margin=0.15)
    assert copied is not None
    assert copied["nearest_place_px"] < 1.0 and copied["truth_fitted"] > 0.95
    assert any(abs(p["from_truth_px"] - 30.0) < 1.5 for p in copied["places"])
    assert copied["best_repeat_fitted"] > 0.95  # the copy: nothing in the image tells it from the target
    unique = places_against_truth(source, source_xy, after_saccade(source, source_xy, landed, None), (21, 21),
                                  truth, margin=0.15)
    assert unique is not None and unique["truth_fitted"] > 0.95
    assert unique["best_repeat_fitted"] is None or unique["best_repeat_fitted"] < 0.9


def test_a_search_is_right_near_the_truth_wrong_beyond_three_pixels_and_says_when_it_found_nothing():
    assert verdict(None, (10.0, 10.0)) == "none"
    assert verdict((11.0, 11.0), (10.0, 10.0)) == "right"
    assert verdict((12.0, 11.0), (10.0, 10.0)) == "near"
    assert verdict((13.5, 10.0), (10.0, 10.0)) == "wrong"


def test_by_the_distance_alone_a_place_at_the_true_distance_is_right_whatever_its_direction():
    fovea = (100.0, 50.0)
    assert verdict_by_distance(None, fovea, 2.0) == "none"
    assert verdict_by_distance((102.0, 50.0), fovea, 2.0) == "right"
    assert verdict_by_distance((100.0, 48.0), fovea, 2.0) == "right"  # the other side: not told
    assert verdict_by_distance((103.0, 52.0), fovea, 2.0) == "near"
    assert verdict_by_distance((110.0, 50.0), fovea, 2.0) == "wrong"


def test_a_motion_beyond_the_plan_shifts_the_view_by_pan_and_tilt_and_half_the_vergence_against_the_pan():
    fixation = {"pose_before": [1.0, 2.0, 3.0], "planned": [-5.0, 1.0, 0.5], "pose_after": [-3.5, 2.5, 5.5]}
    shift, whole = beyond_plan_shift_px(fixation, 4.0)  # 0.5 pan, -0.5 tilt, 2.0 vergence beyond
    assert shift == pytest.approx((4.0 * (0.5 - 1.0), -2.0))
    assert whole == pytest.approx(4.0 * (np.hypot(0.5, 0.5) + 1.0))
    assert beyond_plan_shift_px({"pose_before": [0, 0, 0], "pose_after": [1, 0, 0]}, 4.0) is None  # no plan kept


def test_a_landing_is_measured_only_where_the_saved_offset_is_in_the_sources_pixels(tmp_path):
    def saved(offset, in_image=None):
        arrays = {"offset": np.asarray(offset, dtype=float)}
        if in_image is not None:
            arrays["in_image"] = np.asarray(in_image)
        np.savez(tmp_path / "s.npz", **arrays)
        return np.load(tmp_path / "s.npz")

    assert landing_measured(saved((2.0, -1.0)))  # a recording from before the encoders' shift was kept
    assert landing_measured(saved((2.0, -1.0), False))
    assert not landing_measured(saved((2.0, -1.0), True))  # the encoders' shift, no landing
    assert not landing_measured(saved((np.nan, np.nan), False))
