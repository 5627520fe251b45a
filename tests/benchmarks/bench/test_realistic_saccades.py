"""The realistic saccades benchmark's cases (benchmarks/bench/realistic_saccades.py, made by
benchmarks/support/camera_saccades.py): each condition's cameras really apply their effect.

Every condition's cases are the same saccades with the same added noise, so a condition's
images differ from the ideal camera's by its effect alone."""
from __future__ import annotations

import numpy as np
import pytest

from benchmarks.bench.realistic_saccades import conditions, gain_rows
from benchmarks.support.camera_saccades import CameraSetup, camera_cases
from calib_free.sim.head_model import HeadModel
from drivers.sim.scene import shared_scene
from headctl.experiments.saccades import SaccadeCase, saccade_cases

MODEL = HeadModel.default(320, 240)
SACCADES = 4
AE_TARGET = 0.45 * 255  # the uvc_webcam preset's ae_target, in grey levels


def cases_of(setup: CameraSetup) -> list[SaccadeCase]:
    return camera_cases(setup, MODEL, seed=0, count=SACCADES)


@pytest.fixture(scope="module")
def ideal() -> list[SaccadeCase]:
    return cases_of(conditions()["ideal"])


def middle(image: np.ndarray) -> float:
    """The mean of the middle half each way (what the auto exposure meters)."""
    h, w = image.shape
    return float(image[h // 4:h - h // 4, w // 4:w - w // 4].mean())


def corners(image: np.ndarray, size: int = 40) -> float:
    return float(np.mean([image[:size, :size].mean(), image[:size, -size:].mean(),
                          image[-size:, :size].mean(), image[-size:, -size:].mean()]))


def test_the_ideal_cameras_give_the_renderers_cases(ideal):
    plain = saccade_cases(shared_scene(0, False, "photos"), MODEL, SACCADES, seed=100)
    assert len(ideal) == len(plain) > 0
    for a, b in zip(ideal, plain):
        assert np.array_equal(a.pre, b.pre) and np.array_equal(a.post, b.post)
        assert np.allclose(a.truth, b.truth)


def test_vignetting_darkens_the_corners_and_not_the_centre(ideal):
    vignetted = cases_of(conditions()["vignetting"])
    for a, v in zip(ideal, vignetted):
        assert corners(v.post) < 0.85 * corners(a.post)
        assert v.post[110:130, 150:170].mean() == pytest.approx(a.post[110:130, 150:170].mean(), rel=0.01)


def test_a_running_auto_exposure_follows_the_view_and_a_locked_one_holds(ideal):
    running = cases_of(conditions()["auto exposure, running"])
    locked = cases_of(conditions()["auto exposure, locked"])
    for a, r, k in zip(ideal, running, locked):
        assert middle(r.pre) == pytest.approx(AE_TARGET, rel=0.02)  # settled on the pre view
        assert middle(k.pre) == pytest.approx(AE_TARGET, rel=0.02)
        # locked: the view's own change of brightness; running: back toward the target
        assert middle(k.post) / middle(k.pre) == pytest.approx(middle(a.post) / middle(a.pre), abs=0.01)
        assert abs(middle(r.post) - AE_TARGET) <= abs(middle(k.post) - AE_TARGET) + 0.5
    assert np.mean([abs(middle(r.post) - AE_TARGET) for r in running]) < \
        0.5 * np.mean([abs(middle(k.post) - AE_TARGET) for k in locked])


def test_the_lamp_is_switched_between_the_two_images(ideal):
    lit = cases_of(conditions()["flicker + lamp step"])
    steps = [(f.post.mean() / a.post.mean()) / (f.pre.mean() / a.pre.mean()) for a, f in zip(ideal, lit)]
    assert all(s > 1.1 or s < 1 / 1.1 for s in steps)
    assert any(s > 1.1 for s in steps) and any(s < 1 / 1.1 for s in steps)  # on, then off


def test_lens_differences_move_what_the_fovea_sees(ideal):
    erred = cases_of(conditions()["lens differences"])
    moved = [np.hypot(*(e.truth - a.truth)) for a, e in zip(ideal, erred)]
    assert np.median(moved) > 0.5
    assert not np.array_equal(erred[0].post, ideal[0].post)


def test_mjpeg_changes_the_images_a_little(ideal):
    compressed = cases_of(conditions()["MJPEG q80"])
    for a, c in zip(ideal, compressed):
        difference = np.abs(c.post.astype(float) - a.post.astype(float)).mean()
        assert 0.3 < difference < 6.0


def test_a_gain_row_changes_the_post_images_exposure_within_its_range(ideal):
    changed = cases_of(gain_rows()["gain within +-20 %"])
    ratios = []
    for a, c in zip(ideal, changed):
        assert np.array_equal(c.pre, a.pre)  # the pre image at the reference exposure
        ratios.append(middle(c.post) / middle(a.post))
    assert all(0.78 < r < 1.22 for r in ratios)
    assert max(abs(r - 1) for r in ratios) > 0.03
