"""The offline looks recorded step by step (benchmarks.diag.offline_steps), on a random map."""
from __future__ import annotations

from benchmarks.diag.offline_steps import KINDS, offline_rig, recorded_looks
from calib_free.map.file import write_map
from calib_free.map.gaze_map import GazeMap


def test_each_look_is_recorded_with_its_kind_first_joints_fixations_and_searches(tmp_path):
    write_map(GazeMap.for_image(320, 240, seed=0), tmp_path / "map.npz")
    with offline_rig(tmp_path / "map.npz", seed=3) as offline:
        looks = recorded_looks(offline, 3, 2, tmp_path / "images")
    assert {lk["kind"] for lk in looks} <= {kind for kind, _ in KINDS} and looks
    for look in looks:
        assert set(look["joints_before"]) == {"pan", "tilt", "left_eye", "right_eye"}
        fixations = [s for s in look["steps"] if "aim" in s]
        searches = [s for s in look["steps"] if "search" in s]
        assert fixations, look  # every look taken on fixates at least once
        assert len(searches) <= len(fixations)
        for search in searches:
            assert (tmp_path / "images" / f"search-{search['saved']:03d}.npz").is_file()
