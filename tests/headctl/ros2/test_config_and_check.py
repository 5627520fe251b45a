"""The `ros2:` section read and refused as every section is, and `headctl check` / `run`
naming the install step when the section is on but cyclonedds is missing."""
from __future__ import annotations

from pathlib import Path

import pytest

from headctl.cli.main import main
from headctl.config.head import load_config
from headctl.errors import ConfigError
from tests.support.sections import refusals_without, with_section


def write(tmp_path: Path, ros2: object) -> Path:
    return with_section(tmp_path, "ros2", ros2)


def test_off_by_default_and_existing_configs_keep_working() -> None:
    ros2 = load_config().ros2
    assert not ros2.enabled and not ros2.commands and ros2.domain_id == 0 and ros2.distro == "jazzy"
    assert ros2.rates.joint_states_hz is None and ros2.qos.images == "best_effort" and ros2.qos.images_depth == 5
    assert ros2.mechanics.baseline_m == 0.060 and ros2.mechanics.eye_offset_m == (0.02, 0.06)  # the sim head's


def test_the_section_read(tmp_path: Path) -> None:
    config = load_config(write(tmp_path, {"enabled": True, "domain_id": 7, "namespace": "/head1", "distro": "humble",
                                          "commands": True, "localhost_only": True,
                                          "rates": {"joint_states_hz": 50}, "qos": {"images": "reliable"}}))
    ros2 = config.ros2
    assert (ros2.domain_id, ros2.namespace, ros2.distro, ros2.commands) == (7, "/head1", "humble", True)
    assert ros2.topic("joint_states") == "/head1/joint_states" and ros2.rates.joint_states_hz == 50.0


@pytest.mark.parametrize("ros2, message", [
    ({"domain_id": 233}, "ros2.domain_id: got 233, expected a DDS domain id, 0 to 232"),
    ({"distro": "iron"}, "ros2.distro: got 'iron', expected humble or jazzy or kilted"),
    ({"namespace": "head1"}, "ros2.namespace: got 'head1', expected '' or a ROS 2 namespace"),
    ({"rates": {"joint_states_hz": 0}}, "ros2.rates.joint_states_hz: got 0"),
    ({"qos": {"images": "fast"}}, "ros2.qos.images: got 'fast', expected best_effort or reliable"),
    ({"mechanics": {"baseline_m": -1}}, "ros2.mechanics.baseline_m: got -1"),
    ({"comands": True}, "ros2.comands"),
])
def test_bad_values_are_refused_naming_key_value_and_expected(tmp_path: Path, ros2: object, message: str) -> None:
    path = write(tmp_path, ros2)
    with pytest.raises(ConfigError) as err:
        load_config(path)
    assert str(err.value).startswith(f"{path}: ") and message in str(err.value), str(err.value)


def test_check_and_run_name_the_install_step_when_cyclonedds_is_missing(tmp_path: Path, monkeypatch, capsys) -> None:
    path = write(tmp_path, {"enabled": True})
    for command, err in refusals_without("cyclonedds", path, monkeypatch, capsys).items():
        assert f"headctl {command}: {path}: ros2.enabled is true but cyclonedds is not installed" in err
        assert "pip install 'headctl[ros2]'" in err and "cyclonedds-dev" in err


def test_check_tells_the_interface_when_it_is_on(tmp_path: Path, capsys) -> None:
    path = write(tmp_path, {"enabled": True, "domain_id": 9, "localhost_only": True})
    assert main(["check", "--config", str(path), "--no-connect"]) == 0
    out = capsys.readouterr().out
    assert "  ros2: node /headctl on DDS domain 9 (jazzy), localhost only, commands off" in out
