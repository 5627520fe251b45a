"""The depth-edge diagnostic: depth jumps across a patch, on a made-up room whose depth is known."""
from __future__ import annotations

import numpy as np
import pytest

import benchmarks.diag.depth_edges as depth_edges
from benchmarks.diag.depth_edges import depth_jump, ending, main, tally

JOINTS = {"pan": 0.0, "tilt": 0.0, "left_eye": 0.0, "right_eye": 0.0}


class Model:
    def eye_frames_from_joints(self, *joints):
        return (np.eye(3), np.zeros(3)), (np.eye(3), np.zeros(3))


class Lens:
    """A pinhole about (160, 120), 200 px focal length."""

    def unproject(self, pixels):
        rays = np.column_stack([pixels[:, 0] - 160.0, pixels[:, 1] - 120.0, np.full(len(pixels), 200.0)])
        return rays / np.linalg.norm(rays, axis=1, keepdims=True)


def step_room(scene, origin, direction):
    """A near box left of the image centre's column (1 m), the far wall right of it (2.5 m)."""
    distance = 1.0 if direction[0] < 0 else 2.5
    return origin + distance * direction / direction[2]


@pytest.fixture
def room(monkeypatch):
    monkeypatch.setattr(depth_edges, "first_surface", step_room)


def test_a_patch_across_the_near_boxs_rim_jumps_by_the_ratio_of_the_depths(room):
    assert depth_jump(Model(), None, Lens(), JOINTS, (160.5, 120.0)) == pytest.approx(2.5, rel=0.01)


def test_a_patch_on_one_surface_does_not_jump(room):
    assert depth_jump(Model(), None, Lens(), JOINTS, (200.0, 120.0)) == pytest.approx(1.0, abs=0.01)
    assert depth_jump(Model(), None, Lens(), JOINTS, (100.0, 60.0)) == pytest.approx(1.0, abs=0.01)


def test_looks_are_tallied_by_depth_edge_and_ending():
    looks = [{"depth_jump": 2.0, "on_target": True, "true_error_px": 0.4, "outcome": "on target"},
             {"depth_jump": 2.0, "on_target": True, "true_error_px": 6.0, "outcome": "on target"},
             {"depth_jump": 1.5, "on_target": False, "true_error_px": 0.3, "outcome": "target not found again"},
             {"depth_jump": 1.0, "on_target": True, "true_error_px": 0.2, "outcome": "on target"}]
    assert [ending(lk) for lk in looks] == ["on target", "look-alike", "target not found again", "on target"]
    out = tally(looks, 1.15)
    assert out["depth edge"]["looks"] == 3 and out["depth edge"]["not_truly_on_target"] == 2
    assert out["depth edge"]["endings"] == {"on target": 1, "look-alike": 1, "target not found again": 1}
    assert out["one surface"] == {"looks": 1, "not_truly_on_target": 0, "not_truly_on_target_fraction": 0.0,
                                  "endings": {"on target": 1}}


def test_bad_arguments_are_usage_errors_naming_them(tmp_path, capsys):
    with pytest.raises(SystemExit):
        main(["--map", str(tmp_path / "nowhere.npz")])
    assert "nowhere.npz" in capsys.readouterr().err
    (tmp_path / "map.npz").write_bytes(b"")
    with pytest.raises(SystemExit):
        main(["--map", str(tmp_path / "map.npz"), "--jump", "0.9"])
    assert "--jump must be above 1, got 0.9" in capsys.readouterr().err
