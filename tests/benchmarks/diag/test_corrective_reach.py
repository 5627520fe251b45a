"""The corrective-reach diagnostic: which σ it replays a search with, and its counts against the truth."""
from __future__ import annotations

import json

import cv2
import numpy as np

from benchmarks.diag.corrective_reach import corrective_searches, counts, step_error_px
from tests.support.planar_head import HEIGHT, WIDTH, rich_texture


def test_the_sigma_is_the_recorded_one_else_the_steps_own_prior_else_its_aim():
    aimed = {"aim": [162.5, 123.5, 0.0]}  # 5 px from the fovea of a 320 x 240 image
    assert step_error_px({"step_error_px": 2.5, "expected_error_px": 9.0}, aimed, (320, 240)) == 2.5
    assert step_error_px({"expected_error_px": 9.0, "expected_offset_px": None}, aimed, (320, 240)) == 9.0
    assert step_error_px({"expected_error_px": 0.4, "expected_offset_px": [1.0, 2.0]}, aimed,
                         (320, 240)) == 5.0


def test_a_search_that_took_a_sharper_copy_beyond_the_steps_reach_is_right_once_bounded(tmp_path):
    """The target lies 2 px from the fovea with noise over it (NCC 0.8 with its patch); a clean
    copy of it 30 px away (NCC 0.94) is the best match unbounded. The step's σ of 2 px keeps the search within 6 px."""
    source = rich_texture(seed=6, size=(WIDTH, HEIGHT))
    source_xy = (230.4, 80.7)
    fovea = np.array([(WIDTH - 1) / 2, (HEIGHT - 1) / 2])
    landed = fovea + np.array([2.0, 0.0])
    shift = np.array([[1.0, 0.0, landed[0] - source_xy[0]], [0.0, 1.0, landed[1] - source_xy[1]]])
    image = cv2.warpAffine(source, shift, (WIDTH, HEIGHT), flags=cv2.INTER_LINEAR)
    u, v = int(round(landed[0])), int(round(landed[1]))
    copy = image[v - 15:v + 16, u - 15:u + 16].copy()
    image[v - 15:v + 16, u - 15:u + 16] += np.random.default_rng(3).normal(
        0.0, 0.3 * float(source.std()), copy.shape).astype(np.float32)
    image[v - 15:v + 16, u + 15:u + 46] = copy  # 30 px to the right
    np.savez_compressed(tmp_path / "search-000.npz", source=source, source_xy=np.array(source_xy), image=image,
                        patch=np.array([21, 21]), warps=np.array([np.eye(2)]), expected=np.array(np.nan),
                        offset=np.array([np.nan, np.nan]))
    fixations = [{"aim": [200.0, 100.0, 0.0], "true_error_px": 40.0},
                 {"aim": [161.5, 119.5, 0.0], "true_error_px": 2.0}]
    looks = {"looks": [{"steps": [fixations[0], {"search": 40.0, "saved": None},
                                  fixations[1], {"search": 32.0, "saved": 0, "step_error_px": 2.0}]}]}
    (tmp_path / "steps.json").write_text(json.dumps(looks))
    rows = corrective_searches(tmp_path / "steps.json", tmp_path)
    assert len(rows) == 1  # the first search (no step before it, nothing saved) is not replayed
    row = rows[0]
    assert row["unbounded"] is not None and abs(row["unbounded"] - 32.0) < 3.0
    assert row["bounded"] is not None and abs(row["bounded"] - 2.0) < 0.5
    assert counts(rows, "unbounded", 3.0) == {"right": 0, "wrong": 1, "not found": 0}
    assert counts(rows, "bounded", 3.0) == {"right": 1, "wrong": 0, "not found": 0}
