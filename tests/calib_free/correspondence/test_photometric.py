"""Correspondence when the brightness of the view changed between the two images: the estimate
of the change, the default profile matching through it, the paper's profile untouched, and
the refusals kept."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from calib_free.correspondence.photometric import NO_CHANGE, brightness_change
from calib_free.correspondence.search import CorrespondenceParams, FixationMatch, match_eye
from calib_free.sim.head_model import HeadModel, JointLimits
from drivers.sim.scene import shared_scene
from headctl.experiments.saccades import SaccadeCase, accuracy, saccade_cases, scored

W, H = 320, 240
PAPER = CorrespondenceParams.profile_values("paper")
FLOOR = 0.3  # the fixation's confidence floor (FixationParams.confidence_floor)


def changed(image: np.ndarray, gain: float, offset: float) -> np.ndarray:
    """A sensor's gain about black and a black-level offset, saturating as uint8 does."""
    return np.clip(np.rint(image.astype(np.float32) * gain + offset), 0, 255).astype(np.uint8)


def scene_texture(seed: int, shape: tuple[int, int] = (600, 800)) -> np.ndarray:
    """Fine texture on shading that spans most grey levels (a room's walls, bright and dark)."""
    rng = np.random.default_rng(seed)
    fine = cv2.GaussianBlur(rng.random(shape, dtype=np.float32), (0, 0), 2.0)
    coarse = cv2.GaussianBlur(rng.random(shape, dtype=np.float32), (0, 0), 40.0)
    out = cv2.normalize(fine, None, -40, 40, cv2.NORM_MINMAX) + cv2.normalize(coarse, None, 50, 200, cv2.NORM_MINMAX)
    return np.clip(out, 0, 255).astype(np.uint8)


def view(tex: np.ndarray, x0: int, y0: int) -> np.ndarray:
    return tex[y0:y0 + H, x0:x0 + W].copy()


@pytest.mark.parametrize("gain, offset", [(1.4, 0.0), (1 / 1.4, 0.0), (1.0, 10.0), (1.0, -10.0), (1.3, -8.0)])
def test_the_estimate_recovers_the_change_across_a_saccade(gain, offset):
    tex = scene_texture(1)
    pre, post = view(tex, 200, 150), changed(view(tex, 250, 120), gain, offset)
    change = brightness_change(pre, post, 2.0, 32.0)
    assert change.gain == pytest.approx(gain, rel=0.04)
    assert change.gain * 128 + change.offset == pytest.approx(gain * 128 + offset, abs=2.0)  # at mid-grey
    assert change.registration_ncc > 0.8


def test_no_change_is_seen_where_there_is_none():
    """Across a saccade without a change of brightness the estimate's own spread is no change."""
    tex = scene_texture(1)
    for dx, dy in ((50, -30), (-40, 25), (15, 60)):
        change = brightness_change(view(tex, 200, 150), view(tex, 200 + dx, 150 + dy), 2.0, 32.0)
        assert (change.gain, change.offset) == (1.0, 0.0) and change.registration_ncc > 0.8


def test_saturated_highlights_leave_the_gain_alone():
    """Bright shading clipped at 255 by a gain of 1.4: the clipped quantiles are left out."""
    tex = np.clip(scene_texture(2).astype(np.float32) + 50, 0, 255).astype(np.uint8)
    pre, post = view(tex, 200, 150), changed(view(tex, 230, 170), 1.4, 0.0)
    assert np.mean(post >= 255) > 0.1, "the test needs saturated highlights"
    assert brightness_change(pre, post, 2.0, 32.0).gain == pytest.approx(1.4, rel=0.05)


def test_a_change_beyond_the_bounds_is_clamped_and_nothing_shared_is_no_change():
    tex = scene_texture(3)
    pre = view(tex, 200, 150)
    strong = brightness_change(pre, changed(view(tex, 210, 160), 0.3, 0.0), 2.0, 32.0)
    assert strong.gain == 0.5
    assert brightness_change(pre, changed(view(tex, 210, 160), 1.0, 60.0), 2.0, 32.0).offset == 32.0
    flat = np.full((H, W), 120, np.uint8)
    assert (brightness_change(pre, flat, 2.0, 32.0).gain, brightness_change(flat, flat, 2.0, 32.0).offset) == (1.0, 0.0)


# --- rendered saccades of the photo room ------------------------------------------------------
@pytest.fixture(scope="module")
def photo_cases() -> list[SaccadeCase]:
    model = HeadModel.default(W, H, limits=JointLimits(vergence=(1.0, 20.0)))
    return saccade_cases(shared_scene(3, False, "photos"), model, 60, seed=23)


def with_change(cases: list[SaccadeCase], gain: float, offset: float) -> list[SaccadeCase]:
    return [SaccadeCase(c.pre, changed(c.post, gain, offset), c.truth, c.eye, c.texture, c.patch_std) for c in cases]


@pytest.mark.parametrize("gain, offset", [(1.4, 0.0), (1 / 1.4, 0.0), (1.0, 10.0), (1.0, -10.0)])
def test_the_default_profile_matches_through_a_change_of_brightness(photo_cases, gain, offset):
    """The true place found and accepted as at unchanged brightness. Without the compensation
    the factors read the exposure as another patch: a gain refuses most right matches, an
    offset lowers their confidence."""
    trial = with_change(photo_cases, gain, offset)
    results = list(scored(trial, CorrespondenceParams()))
    default = accuracy(results)
    assert default.cases >= 80
    assert default.within_1px >= 0.95, default.line()
    assert default.wrong_accepted <= 0.01, default.line()
    assert default.right_accepted >= 0.85, default.line()
    plain = list(scored(trial, CorrespondenceParams(compensate_brightness=False)))
    if gain != 1.0:
        assert accuracy(plain).right_accepted < 0.5, accuracy(plain).line()
    right = [k for k, r in enumerate(results) if r.case.textured and r.error_px <= 1.0]
    assert np.median([plain[k].match.confidence for k in right]) < np.median([results[k].match.confidence
                                                                              for k in right])


def test_the_paper_profile_reads_no_change(photo_cases):
    """Eqs. 1-7 as written: the compensation's settings change nothing in the paper's profile."""
    for case in with_change(photo_cases[:12], 1.4, 10.0):
        paper = match_eye(case.pre, case.post, PAPER)
        off = match_eye(case.pre, case.post, CorrespondenceParams.profile_values("paper", compensate_brightness=False))
        assert paper == off and paper.brightness == NO_CHANGE


# --- what must still be refused ------------------------------------------------------------
@pytest.mark.parametrize("gain, offset", [(1.4, 10.0), (1 / 1.4, -10.0)])
def test_a_textureless_patch_is_still_refused(gain, offset):
    """Sensor noise on a smooth wall: nothing to match, whatever the exposure."""
    rng = np.random.default_rng(4)
    wall = cv2.GaussianBlur(rng.random((600, 800), dtype=np.float32), (0, 0), 60.0)
    wall = cv2.normalize(wall, None, 90, 150, cv2.NORM_MINMAX)

    def noisy(image: np.ndarray) -> np.ndarray:
        return np.clip(image + rng.normal(0, 2.0, image.shape), 0, 255).astype(np.uint8)

    pre, post = noisy(view(wall, 200, 150)), changed(noisy(view(wall, 240, 130)), gain, offset)
    m = match_eye(pre, post, CorrespondenceParams())
    assert FixationMatch(m, m).confidence < FLOOR, m


@pytest.mark.parametrize("gain, offset", [(1.0, 0.0), (1.4, 10.0), (1 / 1.4, -10.0)])
def test_a_repeated_texture_is_still_refused(gain, offset):
    """A tile of 48 x 48 px repeated over the wall: the fovea and its context match every
    repeat alike, so no place is the fovea's."""
    rng = np.random.default_rng(5)
    tile = cv2.GaussianBlur(rng.random((48, 48), dtype=np.float32) * 200 + 30, (0, 0), 1.5)
    wall = np.tile(tile, (14, 18))
    pre = np.clip(view(wall, 100, 100) + rng.normal(0, 2.0, (H, W)), 0, 255).astype(np.uint8)
    post = changed(np.clip(view(wall, 131, 117) + rng.normal(0, 2.0, (H, W)), 0, 255), gain, offset)
    m = match_eye(pre, post, CorrespondenceParams())
    assert FixationMatch(m, m).confidence < FLOOR, m
