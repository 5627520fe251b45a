"""A view turned about the optical axis between a look's images (a neck that pans while the
head is tilted): the fallbacks of calib_free.gaze.refind's first and later searches."""
from __future__ import annotations

import dataclasses

import cv2
import numpy as np
import pytest

import calib_free.gaze.look as look_module
import calib_free.gaze.refind as refind
from calib_free.gaze.fixation import LookParams
from calib_free.gaze.magnification import LearnedMagnification
from calib_free.gaze.refind import (TURNS_DEG, SearchStage, TargetSighting, candidate_warps, fallback_note,
                                    find_first_sighting, find_later_sighting, find_target, turned)
from tests.calib_free.gaze.test_look import looker
from tests.support.planar_head import HEIGHT, WIDTH, PlanarHead

FOVEA = np.array([(WIDTH - 1) / 2, (HEIGHT - 1) / 2])
SOURCE_XY = (262.3, 71.6)


def fine_texture(seed: int) -> np.ndarray:
    """Noise about a pixel fine: a patch of it matches its own view turned by 14 deg below
    min_target_ncc, as the realistic world's fine textures do."""
    noise = np.random.default_rng(seed).uniform(0.0, 255.0, (HEIGHT, WIDTH)).astype(np.float32)
    smooth = cv2.GaussianBlur(noise, (0, 0), 0.8)
    return np.clip((smooth - smooth.mean()) * 5.0 + 128.0, 0.0, 255.0)


def turning(angle_deg: float) -> np.ndarray:
    a = np.radians(angle_deg)
    return np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])


def view_after(image: np.ndarray, linear: np.ndarray, landed: np.ndarray) -> np.ndarray:
    """`image` as a view whose linear change about `SOURCE_XY` is `linear`, the target landing at `landed`."""
    matrix = np.hstack([linear, (landed - linear @ np.array(SOURCE_XY))[:, None]])
    return cv2.warpAffine(image, matrix, (WIDTH, HEIGHT), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)


def radial(scale: float) -> np.ndarray:
    direction = (np.array(SOURCE_XY) - FOVEA) / np.hypot(*(np.array(SOURCE_XY) - FOVEA))
    rotation = np.column_stack([direction, [-direction[1], direction[0]]])
    return rotation @ np.diag([scale, 1.0]) @ rotation.T


def test_turned_warps_turn_each_warp_by_each_angle():
    warps = [np.eye(2), np.diag([1.5, 1.0])]
    out = turned(warps, (10.0, -20.0))
    assert len(out) == 4
    assert np.allclose(out[0], turning(10.0)) and np.allclose(out[3], turning(-20.0) @ np.diag([1.5, 1.0]))
    assert len(turned(warps)) == len(TURNS_DEG) * 2


def test_a_view_turned_about_its_axis_is_found_by_the_turned_warps():
    image = fine_texture(seed=5)
    linear = turning(14.0) @ radial(1.2)  # a 14 deg turn: what a 55 deg pan at a 15 deg tilt does
    landed = FOVEA + np.array([0.6, -0.4])
    after = view_after(image, linear, landed)
    params = LookParams()
    unturned, why = find_target(image, SOURCE_XY, after, params)
    assert unturned is None and "NCC" in why  # no warp of the grid turns: the target is not found by them
    sighting, variant, why = find_first_sighting(image, SOURCE_XY, after, [params], LearnedMagnification())
    assert why == "" and sighting is not None and variant == params
    assert sighting.distance_px(tuple(landed)) <= 0.3 and sighting.found_by is SearchStage.TURNED
    assert np.allclose(sighting.warp, linear, atol=0.05)  # ECC fits the turn the grid came near


def no_turn(*args, **kwargs):
    raise AssertionError("a turned search was tried")


def test_a_later_search_tries_the_warp_carried_then_every_warp_turned_and_no_other(monkeypatch):
    """Where the warp carried matches nothing, every candidate warp turned; not every candidate
    warp unturned, which after a step found look-alikes more often than targets."""
    image = fine_texture(seed=6)
    after = view_after(image, radial(1.15), FOVEA + np.array([0.5, 0.3]))
    carried = [turning(-14.0) @ radial(1.9)]  # a warp found before, unlike the view's now
    tried: list[list[np.ndarray]] = []
    real = refind.search_target

    def recorded(source, source_xy, image, params, warps=None, *args):
        tried.append(warps)
        return real(source, source_xy, image, params, warps, *args)

    monkeypatch.setattr(refind, "search_target", recorded)
    params = LookParams()
    find_later_sighting(image, SOURCE_XY, after, [params], carried, None, None, 1.5)
    every_turned = turned(candidate_warps(SOURCE_XY, tuple(FOVEA), params.max_target_scale))
    assert len(tried) == 2 and tried[0] is carried
    assert len(tried[1]) == len(every_turned) and all(np.allclose(a, b) for a, b in zip(tried[1], every_turned))


def test_a_step_whose_view_also_turned_is_searched_with_every_warp_turned():
    image = fine_texture(seed=7)
    linear = turning(-18.0) @ radial(1.15)
    landed = FOVEA + np.array([-0.4, 0.5])
    after = view_after(image, linear, landed)
    params = LookParams()
    every, _ = find_target(image, SOURCE_XY, after, params, candidate_warps(SOURCE_XY, tuple(FOVEA), 4.0), None, None,
                           1.5)
    assert every is None
    sighting, _, why = find_later_sighting(image, SOURCE_XY, after, [params], [radial(1.9)], None, None, 1.5)
    assert why == "" and sighting is not None and sighting.distance_px(tuple(landed)) <= 0.3
    assert sighting.found_by is SearchStage.TURNED
    # A view the warp carried still fits is found by it.
    again, _, _ = find_later_sighting(image, SOURCE_XY, after, [params], [sighting.warp], None, None, 1.5)
    assert again is not None and again.found_by is SearchStage.CARRIED


@pytest.mark.parametrize("later", [False, True])
def test_a_search_that_matched_a_place_tries_no_other_warp(monkeypatch, later):
    """A place matched at min_target_ncc but not told from a repeat: the lens shows the patch as
    the warps tried, and a stretch or a turn beyond them would only find a look-alike."""
    image = fine_texture(seed=8)
    landed = FOVEA + np.array([0.4, 0.2])
    after = view_after(image, radial(1.2), landed)
    patch = after[int(landed[1]) - 12:int(landed[1]) + 13, int(landed[0]) - 12:int(landed[0]) + 13].copy()
    after[int(landed[1]) - 12:int(landed[1]) + 13, int(landed[0]) + 18:int(landed[0]) + 43] = patch  # a repeat

    monkeypatch.setattr(refind, "turned", no_turn)
    params = LookParams()
    if later:
        sighting, _, why = find_later_sighting(image, SOURCE_XY, after, [params], [radial(1.2)], None, None, None)
    else:
        sighting, _, why = find_first_sighting(image, SOURCE_XY, after, [params], LearnedMagnification())
    assert sighting is None and "ambiguous" in why


def test_a_look_says_when_a_turned_search_found_its_target():
    def seen(stage):
        return TargetSighting(160.0, 120.0, 0.9, np.eye(2), stage)

    assert fallback_note([seen(SearchStage.EVERY_SCALE), seen(SearchStage.CARRIED)]) == ""
    note = fallback_note([seen(SearchStage.LEARNED_SCALES), seen(SearchStage.TURNED), seen(SearchStage.CARRIED),
                          seen(SearchStage.TURNED)])
    assert note == f"; found again by {SearchStage.TURNED}"


def test_a_look_on_target_says_the_fallback_search_that_found_its_target(monkeypatch):
    real = look_module.find_later_sighting

    def found_turned(*args):  # the later searches as they are, said to be found turned
        sighting, variant, why = real(*args)
        return (None if sighting is None else dataclasses.replace(sighting, found_by=SearchStage.TURNED)), variant, why

    monkeypatch.setattr(look_module, "find_later_sighting", found_turned)
    controller, _ = looker(PlanarHead(), gain=0.8)  # every saccade falls 20 % short: a corrective step
    record = controller.look((262.0, 58.0, 0.0))
    assert record.on_target and record.corrective_steps >= 1
    assert f"found again by {SearchStage.TURNED}" in record.detail
