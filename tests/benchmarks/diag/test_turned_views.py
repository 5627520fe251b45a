"""The turned-views diagnostic: the turn of a view measured at the truth, on searches made up to know it."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from benchmarks.diag.turned_views import main, pan_turn_deg, summary, turn_at_truth, turn_deg, turned_searches
from calib_free.gaze.fixation import LookParams
from tests.support.planar_head import HEIGHT, WIDTH, rich_texture

FOVEA = np.array([(WIDTH - 1) / 2, (HEIGHT - 1) / 2])
SOURCE_XY = (250.0, 80.0)


def turning(angle_deg: float) -> np.ndarray:
    a = np.radians(angle_deg)
    return np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])


def saved_search(angle_deg: float, landed_offset: tuple[float, float]) -> dict[str, np.ndarray]:
    """A search's saved inputs: the source, and the view after it turned by `angle_deg` and
    stretched 1.2 times across x, the target landing `landed_offset` from the fovea."""
    source = rich_texture(seed=4, size=(WIDTH, HEIGHT))
    linear = turning(angle_deg) @ np.diag([1.2, 1.0])
    landed = FOVEA + np.asarray(landed_offset)
    matrix = np.hstack([linear, (landed - linear @ np.array(SOURCE_XY))[:, None]])
    image = cv2.warpAffine(source, matrix, (WIDTH, HEIGHT), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
    return {"source": source, "image": image, "source_xy": np.array(SOURCE_XY), "patch": np.array([21, 21]),
            "warps": np.zeros((0, 2, 2))}


def test_the_turn_is_the_rotation_part_of_a_linear_map():
    assert turn_deg(turning(7.0) @ np.diag([1.5, 0.9])) == pytest.approx(7.0)
    assert turn_deg(np.diag([1.3, 1.1])) == pytest.approx(0.0)


def test_the_pan_turns_the_view_by_the_pan_times_the_sine_of_the_tilt():
    assert pan_turn_deg([0.0, 20.0, 2.0], [30.0, 10.0, 2.0]) == pytest.approx(-30.0 * np.sin(np.radians(15.0)))
    assert pan_turn_deg([0.0, 0.0, 2.0], [30.0, 0.0, 2.0]) == pytest.approx(0.0)  # level: no turn


@pytest.mark.parametrize("angle", [-8.0, 5.0])
def test_the_turn_at_the_truth_is_the_views(angle):
    turn, fit = turn_at_truth(saved_search(angle, (0.4, -0.3)), (0.4, -0.3), LookParams())
    assert turn == pytest.approx(angle, abs=0.3) and fit > 0.95


def test_searches_are_rowed_by_whether_they_found_the_target_and_summarised(tmp_path):
    np.savez(tmp_path / "search-000.npz", **saved_search(6.0, (0.5, 0.0)))
    np.savez(tmp_path / "search-001.npz", **saved_search(-4.0, (0.2, 0.1)))
    first = {"aim": [1.0, 2.0, 0.0], "pose_before": [0.0, 20.0, 2.0], "pose_after": [-20.0, 10.0, 2.0],
             "true_offset_px": [0.5, 0.0]}
    step = {"aim": [1.0, 2.0, 0.0], "pose_before": [-20.0, 10.0, 2.0], "pose_after": [-21.0, 10.0, 2.0],
            "true_offset_px": [0.2, 0.1]}
    far = {**step, "true_offset_px": [4.0, 0.0]}  # beyond --near-px: no row
    looks = [{"kind": "textured", "steps": [
        first, {"search": 0.5, "seen_at_px": [0.5, 0.1], "why": "", "saved": 0, "patch": [21, 21]},
        step, {"search": None, "seen_at_px": None, "why": "the best match scores NCC 0.61 < 0.7", "saved": 1,
               "patch": [21, 21]},
        far, {"search": 4.0, "seen_at_px": [4.0, 0.0], "why": "", "saved": 1, "patch": [21, 21]}]}]
    rows = turned_searches(looks, tmp_path, LookParams(), 1.5)
    assert [r["found"] for r in rows] == [True, False]
    assert rows[0]["turn_deg"] == pytest.approx(6.0, abs=0.3)
    assert rows[0]["pan_turn_deg"] == pytest.approx(20.0 * np.sin(np.radians(15.0)), abs=0.01)
    assert rows[1]["after_step"] and rows[1]["pan_turn_deg"] == pytest.approx(21.0 * np.sin(np.radians(15.0)), abs=0.01)
    out = summary(rows, 0.7)
    assert out["found"]["searches"] == 1 and out["not_found_below_min_ncc"]["searches"] == 1
    assert out["found"]["turn_minus_pan_turn_deg"]["p50"] == pytest.approx(abs(6.0 - 20.0 * np.sin(np.radians(15.0))),
                                                                           abs=0.3)


def test_a_missing_map_is_a_usage_error_naming_it(tmp_path, capsys):
    with pytest.raises(SystemExit):
        main(["--map", str(tmp_path / "nowhere.npz")])
    assert "nowhere.npz" in capsys.readouterr().err
