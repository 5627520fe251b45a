"""The lens's magnification as the looks learn it (calib_free.gaze.magnification), and the
first search that narrows its scales by it (calib_free.gaze.refind.find_first_sighting)."""
from __future__ import annotations

import numpy as np
import pytest

from calib_free.gaze.fixation import LookParams
from calib_free.gaze.look import LookOutcome
from calib_free.gaze.magnification import (MEMORY, MIN_SAMPLES, LearnedMagnification, MagnificationFileError,
                                           radial_scale)
from calib_free.gaze.refind import find_first_sighting, find_target, radial_scale_grid, warped_patch
from calib_free.gaze.target_patch import target_patch_problem
from tests.calib_free.gaze.test_look import looker
from tests.support.planar_head import HEIGHT, WIDTH, PlanarHead, rich_texture

FOVEA = np.array([(WIDTH - 1) / 2, (HEIGHT - 1) / 2])


def radial_stretch(source_xy, scale: float) -> np.ndarray:
    radial = (np.asarray(source_xy) - FOVEA) / np.hypot(*(np.asarray(source_xy) - FOVEA))
    rotation = np.column_stack([radial, [-radial[1], radial[0]]])
    return rotation @ np.diag([scale, 1.0]) @ rotation.T


def test_the_radial_scale_is_the_warps_stretch_along_the_line_from_the_centre():
    xy = (FOVEA[0] + 60.0, FOVEA[1] - 80.0)
    assert radial_scale(radial_stretch(xy, 1.4), xy, tuple(FOVEA)) == pytest.approx(1.4)
    # across the radius the same warp does not stretch: the other point's scale is 1
    across = (FOVEA[0] + 80.0, FOVEA[1] + 60.0)
    assert radial_scale(radial_stretch(xy, 1.4), across, tuple(FOVEA)) == pytest.approx(1.0)


def test_the_magnification_is_known_once_enough_looks_found_it_nearby_and_forgets_the_old():
    profile = LearnedMagnification()
    for k in range(MIN_SAMPLES - 1):
        profile.record(100.0 + k, 1.2)
    assert profile.expected(100.0) is None  # too few yet
    profile.record(108.0, 1.3)
    assert profile.expected(104.0) == pytest.approx(1.2)  # the median
    assert profile.expected(150.0) is None  # nothing learned that far out
    for _ in range(MEMORY):
        profile.record(103.0, 1.5)  # the lens changed: the newest scales replace the oldest
    assert profile.expected(103.0) == pytest.approx(1.5)
    grid = radial_scale_grid(4.0)
    scales = profile.radial_scales(103.0, grid)
    assert scales is not None and all(1.5 / 1.3 <= s <= 1.5 * 1.3 for s in scales) and len(scales) >= 1
    assert profile.radial_scales(150.0, grid) is None  # every scale where nothing is known


def scene_with_a_stretched_look_alike(seed: int = 5):
    """A view before the saccade with a target 70 px right of the fovea, and one after it with
    the target on the fovea (as the lens shows it there, unstretched, with sensor noise) and,
    30 px below, the target's patch stretched 2.1 times along the radius, exactly: the grid's
    2.1x warp matches the look-alike perfectly, the target only by its 1x warp, and less well."""
    source = rich_texture(seed=seed, size=(WIDTH, HEIGHT))
    source_xy = (float(FOVEA[0] + 70.0), float(FOVEA[1]))
    after = rich_texture(seed=seed + 1, size=(WIDTH, HEIGHT))
    rng = np.random.default_rng(seed)
    size = 27
    true = warped_patch(source, source_xy, np.eye(2), (size, size))
    stretch = radial_scale_grid(4.0)[5]
    look_alike = warped_patch(source, source_xy, radial_stretch(source_xy, stretch), (size, size))
    assert true is not None and look_alike is not None
    half = size // 2
    cx, cy = int(FOVEA[0] + 0.5), int(FOVEA[1] + 0.5)  # the patch centre lands on a pixel
    after[cy - half:cy + half + 1, cx - half:cx + half + 1] = true + rng.normal(0, 0.35 * float(true.std()), true.shape)
    after[cy + 30 - half:cy + 30 + half + 1, cx - half:cx + half + 1] = look_alike
    return source, source_xy, after, (cx, cy), (cx, cy + 30)


def test_a_look_alike_matching_only_when_stretched_beyond_the_learned_lens_is_not_taken():
    source, source_xy, after, target, look_alike = scene_with_a_stretched_look_alike()
    params = LookParams()
    unlearned, _ = find_target(source, source_xy, after, params)
    assert unlearned is not None and unlearned.distance_px(look_alike) <= 1.0  # every scale: the look-alike wins
    profile = LearnedMagnification()
    for k in range(MIN_SAMPLES):
        profile.record(68.0 + k, 1.03)  # the looks found targets from this far off barely stretched
    sighting, variant, why = find_first_sighting(source, source_xy, after, [params], profile)
    assert why == "" and sighting is not None and variant == params
    assert sighting.distance_px(target) <= 1.0


def test_a_lens_that_changed_is_still_searched_with_every_scale():
    source, source_xy, after, target, look_alike = scene_with_a_stretched_look_alike()
    after[target[1] - 13:target[1] + 14, target[0] - 13:target[0] + 14] = after[0:27, 0:27]  # no target at 1x
    profile = LearnedMagnification()
    for k in range(MIN_SAMPLES):
        profile.record(70.0, 1.03)
    sighting, _, why = find_first_sighting(source, source_xy, after, [LookParams()], profile)
    assert why == "" and sighting is not None  # the learned scales find nothing: every scale is tried
    assert sighting.distance_px(look_alike) <= 1.0 and radial_scale(sighting.warp, source_xy, tuple(FOVEA)) > 1.3


def test_looks_on_target_teach_the_lens_scale_their_target_was_found_with():
    head = PlanarHead()  # a view that moves without magnifying: every scale is 1
    controller, _ = looker(head, gain=0.9)
    taught = 0
    for a in np.linspace(0.0, 2 * np.pi, 24, endpoint=False):
        x, y = FOVEA[0] + 80.0 * np.cos(a), FOVEA[1] + 80.0 * np.sin(a)
        head.move_to(np.array([0.0, 0.0, 8.0]))
        left, _ = head.wait_pair(0.0, 1.0)
        if target_patch_problem(left, (x, y), LookParams()):
            continue  # a patch that repeats in its own view: no look would be taken on
        record = controller.look((x, y, 0.0))
        assert record.outcome is LookOutcome.ON_TARGET
        taught += 1
        if taught == MIN_SAMPLES:
            break
    assert taught == MIN_SAMPLES
    learned = controller.magnification.expected(80.0)
    assert learned is not None and learned == pytest.approx(1.0, abs=0.05)
    assert controller.magnification.expected(20.0) is None


def test_a_target_the_learned_scale_cannot_tell_from_a_repeat_is_not_searched_at_other_scales():
    source, source_xy, after, target, look_alike = scene_with_a_stretched_look_alike()
    copy = (target[0] - 32, target[1])  # a repeat of the target, as the lens shows it there too
    after[copy[1] - 13:copy[1] + 14, copy[0] - 13:copy[0] + 14] = after[target[1] - 13:target[1] + 14,
                                                                        target[0] - 13:target[0] + 14]
    everything, _ = find_target(source, source_xy, after, LookParams())
    assert everything is not None and everything.distance_px(look_alike) <= 1.0  # every scale: the look-alike
    profile = LearnedMagnification()
    for k in range(MIN_SAMPLES):
        profile.record(70.0, 1.03)
    sighting, _, why = find_first_sighting(source, source_xy, after, [LookParams()], profile)
    assert sighting is None and "ambiguous" in why


def test_a_profile_read_back_from_its_dict_expects_the_same_scales_and_keeps_each_bins_newest():
    profile = LearnedMagnification()
    for k in range(MIN_SAMPLES):
        profile.record(83.0 + k, 1.10 + 0.01 * k)
    profile.record(150.0, 1.5)
    assert profile.revision == MIN_SAMPLES + 1
    again = LearnedMagnification.from_dict(profile.as_dict(), "here")
    assert again.expected(85.0) == pytest.approx(profile.expected(85.0)) == pytest.approx(1.12)
    assert again.expected(150.0) is None  # one scale there: not yet learned, read back or not
    data = profile.as_dict()
    data["scales_by_distance_px"]["80"] = [1.0] * MEMORY + [2.0] * MEMORY  # twice what a bin keeps
    assert LearnedMagnification.from_dict(data, "here").expected(85.0) == pytest.approx(2.0)


@pytest.mark.parametrize("data, says", [
    ([1.1, 1.2], "not a lens magnification profile of format 1"),
    ({"format": 2, "bin_px": 10.0, "scales_by_distance_px": {}}, "format 2"),
    ({"format": 1, "bin_px": 5.0, "scales_by_distance_px": {}}, "bin_px is 5.0, expected 10"),
    ({"format": 1, "bin_px": 10.0, "scales_by_distance_px": {"80": [1.1, -1.0]}}, "scales_by_distance_px.80"),
    ({"format": 1, "bin_px": 10.0, "scales_by_distance_px": {"far": [1.1]}}, "'far' is no distance"),
    ({"format": 1, "bin_px": 10.0, "scales_by_distance_px": {"80": "1.1"}}, "a list of positive scales"),
])
def test_a_dict_that_is_no_profile_is_refused_naming_where_and_what(data, says):
    with pytest.raises(MagnificationFileError) as err:
        LearnedMagnification.from_dict(data, "/state/lens_magnification.json")
    assert str(err.value).startswith("/state/lens_magnification.json: ") and says in str(err.value)
