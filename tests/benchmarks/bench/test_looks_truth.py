"""The looks benchmark's truth (`benchmarks.bench.looks.true_error_px`) agrees with the images the
realistic world renders: a realistic camera's own lens differs from the head model's (focal
length, optical centre, roll: pixels some 1-8 px apart), and its room holds the passers-by; the
truth must see the room the pixels show, through the lens they were rendered by."""
from __future__ import annotations

import cv2
import numpy as np

from benchmarks.bench.looks import true_error_px
from calib_free.correspondence.disparity import as_grey_float, subpixel_peak
from calib_free.gaze.refind import distinct_places
from headctl.experiments.online import SimulatedHeadRig

HALF = 20  # the patch found again: 41 x 41 px
# Searched around where a 3 deg pan brings it, about 12 px to the right: the room's texture
# repeats some 15 px apart, so a search as tall would find its repeats.
SEARCH_X_PX, SEARCH_Y_PX = 12, 6


def left_image(rig: SimulatedHeadRig) -> np.ndarray:
    return as_grey_float(rig.head.wait_pair(rig.head.wait_settled(3.0), 2.0)[0])


def test_the_truth_of_a_pixel_after_a_turn_is_where_the_rendered_image_shows_its_patch():
    with SimulatedHeadRig(seed=0) as rig:  # configs/sim.yaml: the realistic world
        world = rig.devices.world
        before_image, before = left_image(rig), world.true_joints()
        rig.head.move_to(rig.head.read_pose() + np.array([3.0, 0.0, 0.0]))
        after_image, after = left_image(rig), world.true_joints()
        cx, cy = (before_image.shape[1] - 1) / 2.0, (before_image.shape[0] - 1) / 2.0
        compared = 0
        for x, y in ((140, 100), (200, 150), (179, 127), (100, 160), (230, 80)):
            template = before_image[y - HALF:y + HALF + 1, x - HALF:x + HALF + 1]
            x0, y0 = x + 12 - SEARCH_X_PX - HALF, y - SEARCH_Y_PX - HALF
            window = after_image[y0:y0 + 2 * (SEARCH_Y_PX + HALF) + 1, x0:x0 + 2 * (SEARCH_X_PX + HALF) + 1]
            scores = cv2.matchTemplate(window, template, cv2.TM_CCOEFF_NORMED)
            places = distinct_places(scores, float(scores.max()) - 0.1, 4.0)
            if len(places) > 1:
                continue  # the room's texture repeats within the search: the image cannot say which
            (iu, iv), peak = places[0], float(scores.max())
            assert peak > 0.7, (x, y, peak)
            u, v = subpixel_peak(scores, iv, iu)
            seen_px = float(np.hypot(x0 + u + HALF - cx, y0 + v + HALF - cy))
            truth_px, hidden = true_error_px(rig, before, after, (float(x), float(y)))
            assert not hidden
            assert abs(truth_px - seen_px) <= 0.5, (x, y, truth_px, seen_px)
            compared += 1
        assert compared >= 3
