"""`measured_landing_recovery`: a change's recovery judged on the fixations' own measured landing."""
from __future__ import annotations

import math

import pytest

from calib_free.sim.experiments import measured_landing_recovery

LEVEL_PX = 0.5  # the steady landing before the change in these series


def steady(count: int, level: float = LEVEL_PX) -> list[float | None]:
    """`count` measured landings whose median is `level` (alternating 0.8 and 1.2 times it)."""
    return [level * (0.8 if n % 2 else 1.2) for n in range(count)]


def test_a_step_up_then_a_decay_is_back_where_the_median_of_the_last_50_crosses_the_bar():
    # 4.5 px worse at the change, decaying by 10 % a fixation: 0.5 + 4.5 * 0.9 ** k, k since it.
    after = [LEVEL_PX + 4.5 * 0.9 ** k for k in range(500)]
    got = measured_landing_recovery(steady(300) + after, 300)
    # Falling values: the window's median at k is the mean of the values at k - 24 and k - 25;
    # it is <= 1.25 x 0.5 px once 4.5 * 0.9 ** (k - 25) * 1.9 / 2 <= 0.125, and k + 1 fixations
    # have been made since the change.
    k = 25 + math.ceil(math.log(0.125 / 4.5 / 0.95) / math.log(0.9))
    assert got.fixations == k + 1
    assert got.before_px == pytest.approx(LEVEL_PX)
    assert got.bar_px == pytest.approx(1.25 * LEVEL_PX)  # above level + the 0.1 px floor
    assert got.peak_after_px == pytest.approx((after[24] + after[25]) / 2)  # the first full window


def test_a_landing_that_stays_worse_is_never_back():
    got = measured_landing_recovery(steady(300) + [1.0] * 700, 300)
    assert got.fixations is None
    assert got.peak_after_px == pytest.approx(1.0)


def test_fewer_measured_landings_than_the_window_since_the_change_are_not_back():
    # Good landings before the change must not fill the window after it, and 49 good ones after
    # it, then nothing measured, are one short of a window.
    got = measured_landing_recovery(steady(300) + steady(49) + [None] * 600, 300)
    assert got.fixations is None
    assert got.peak_after_px is None  # no window was ever full
    assert measured_landing_recovery(steady(300) + steady(50) + [None] * 600, 300).fixations == 50


def test_refused_fixations_neither_fill_the_window_nor_make_it_back_early():
    # 30 bad landings, 200 refusals with no measure, then good landings: back once 26 of the last
    # 50 measured are good, at the 26th good one, 30 + 200 + 26 fixations after the change.
    after = [3.0] * 30 + [None] * 200 + steady(300)
    assert measured_landing_recovery(steady(300) + after, 300).fixations == 256


def test_recovery_counts_fixations_not_measurements():
    # Every other fixation after the change refused: the 100 bad and then good measured landings
    # are back at the 126th measured one, the 252nd fixation.
    measured = [3.0] * 100 + steady(200)
    after: list[float | None] = []
    for px in measured:
        after += [None, px]
    assert measured_landing_recovery(steady(300) + after, 300).fixations == 252


def test_the_level_before_is_the_median_of_the_last_200_measured_before_the_change():
    # Earlier, worse landings and refusals between the last 200 do not move it.
    before: list[float | None] = [2.0] * 300
    for px in steady(200, 0.4):
        before += [px, None]
    got = measured_landing_recovery(before + steady(100, 0.4), len(before))
    assert got.before_px == pytest.approx(0.4)
    assert got.fixations == 50  # the first full window after the change


def test_a_small_level_is_given_the_floor_above_it():
    # At 0.1 px, 1.25 x would be 0.125 px: closer than two windows of a steady map differ.
    got = measured_landing_recovery(steady(300, 0.1) + [0.18] * 100, 300, floor_px=0.1)
    assert got.bar_px == pytest.approx(0.2)
    assert got.fixations == 50
    assert measured_landing_recovery(steady(300, 0.1) + [0.18] * 100, 300, floor_px=0.0).fixations is None


def test_a_run_without_measured_landings_before_the_change_has_no_recovery():
    got = measured_landing_recovery([None] * 300 + steady(100), 300)
    assert (got.fixations, got.before_px, got.bar_px) == (None, None, None)
