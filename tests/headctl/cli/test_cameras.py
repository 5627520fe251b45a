"""`headctl snapshot` and `headctl cameras`, and the `cameras:` config section they read."""
from __future__ import annotations


import cv2
import pytest

from drivers.cameras.config import StereoCamerasConfig
from drivers.errors import CameraConfigError
from headctl.cli.main import main
from tests.support import CONFIGS

EXAMPLE = CONFIGS / "sim-cameras.yaml"


def test_snapshot_of_the_simulated_head_saves_a_pair(tmp_path, capsys):
    assert main(["snapshot", "--config", str(EXAMPLE), "--out", str(tmp_path), "--pose", "5", "0", "3", "-3"]) == 0
    left, right = cv2.imread(str(tmp_path / "left.png")), cv2.imread(str(tmp_path / "right.png"))
    assert left.shape == right.shape == (240, 320, 3)
    assert (left != right).any()
    assert "pair skew 0.000 ms" in capsys.readouterr().out


def test_snapshot_reads_the_cameras_of_a_whole_head_config(tmp_path, capsys):
    assert main(["snapshot", "--config", str(CONFIGS / "sim.yaml"), "--out", str(tmp_path)]) == 0
    left, right = cv2.imread(str(tmp_path / "left.png")), cv2.imread(str(tmp_path / "right.png"))
    assert left.shape == right.shape == (240, 320, 3)


def test_snapshot_validates_the_rest_of_a_whole_head_config(tmp_path, capsys):
    config = tmp_path / "head.yaml"
    config.write_text((CONFIGS / "sim.yaml").read_text().replace("servo_rate_hz: 100", "servo_rate_hz: 0", 1))
    assert main(["snapshot", "--config", str(config), "--out", str(tmp_path)]) == 2
    assert f"{config}: service.servo_rate_hz: got 0.0, expected a rate in [1, 1000] Hz" in capsys.readouterr().err
    assert not (tmp_path / "left.png").exists()


def test_snapshot_refuses_unknown_keys_naming_file_and_key_path(tmp_path, capsys):
    config = tmp_path / "bad.yaml"
    config.write_text(EXAMPLE.read_text().replace("noise_std:", "noise:", 1))  # the left camera's
    assert main(["snapshot", "--config", str(config), "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert f"{config}: cameras.left.noise: got 1.0, expected a known key (cameras.left takes backend, " in err
    assert "'noise' is an unknown key" in err


def test_snapshot_refuses_eyes_that_disagree(tmp_path, capsys):
    config = tmp_path / "seeds.yaml"
    text = EXAMPLE.read_text()
    head, _, tail = text.rpartition("    seed: 0\n")
    config.write_text(head + "    seed: 4\n" + tail)
    assert main(["snapshot", "--config", str(config), "--out", str(tmp_path)]) == 2
    expected = "0 like cameras.left: both eyes of the simulated head see one scene through one lens"
    assert f"{config}: cameras.right.seed: got 4, expected {expected}" in capsys.readouterr().err


def test_stereo_section_shape_is_checked():
    with pytest.raises(CameraConfigError, match=r"cameras\.right: missing"):
        StereoCamerasConfig.from_mapping({"left": {"backend": "sim", "eye": "left"}})
    with pytest.raises(CameraConfigError, match=r"cameras\.centre: got \{\}, expected a known key \(cameras takes "
                                                r"left, right, tolerance_s, scene\); 'centre' is an unknown key"):
        StereoCamerasConfig.from_mapping({"left": {}, "right": {}, "centre": {}})
    with pytest.raises(CameraConfigError, match=r"cameras\.tolerance_s: got 'x', expected a number"):
        StereoCamerasConfig.from_mapping({"left": {}, "right": {}, "tolerance_s": "x"})
    with pytest.raises(CameraConfigError, match=r"cameras\.tolerance_s: got -1\.0, expected a number >= 0"):
        StereoCamerasConfig.from_mapping({"left": {}, "right": {}, "tolerance_s": -1})


def test_cameras_lists_the_aravis_fake_camera(capsys):
    assert main(["cameras", "--fake"]) == 0
    out = capsys.readouterr().out
    assert "V4L2 devices:" in out
    assert "id Fake_1  serial 1  Aravis Fake" in out and "Mono8" in out
