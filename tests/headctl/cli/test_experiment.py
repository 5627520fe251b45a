"""`headctl experiment`: the online options reach `run_online`, and what its summary keeps."""
from __future__ import annotations

from typing import Any

import pytest

from headctl.cli import experiment as cmd_experiment
from headctl.cli.main import build_parser, main
from headctl.config.head import DEFAULT_CONFIG, load_config
from headctl.experiments import paper
from headctl.experiments.online import ONLINE_EXPERIMENTS, OnlineResult
from headctl.experiments.report import online_summary
from headctl.experiments.sweep import build_runs


class _Stop(Exception):
    """Raised by the stand-in for `run_online` once it has seen its arguments."""


@pytest.fixture
def run_online_calls(monkeypatch) -> list[dict[str, Any]]:
    calls: list[dict[str, Any]] = []

    def fake_run_online(spec, profile, **kwargs):
        calls.append({"spec": spec, "profile": profile, **kwargs})
        raise _Stop

    monkeypatch.setattr(paper, "run_online", fake_run_online)
    return calls


@pytest.mark.parametrize("extra, room, use_pose", [
    ([], None, True),  # the config's room
    (["--room", "photos"], "photos", True),
    (["--room", "generated", "--no-pose"], "generated", False),
])
def test_the_room_and_the_pose_reach_run_online(run_online_calls, tmp_path, extra, room, use_pose):
    with pytest.raises(_Stop):
        main(["experiment", "online", "--fixations", "7", "--out", str(tmp_path), *extra])
    (call,) = run_online_calls
    assert (call["room"], call["use_pose"], call["spec"].fixations) == (room, use_pose, 7)
    assert call["config"].path == DEFAULT_CONFIG  # no --config: the packaged configs/sim.yaml


def test_the_config_reaches_run_online(run_online_calls, tmp_path):
    ideal = DEFAULT_CONFIG.with_name("sim-ideal.yaml")
    with pytest.raises(_Stop):
        main(["experiment", "online", "--fixations", "7", "--out", str(tmp_path), "--config", str(ideal)])
    (call,) = run_online_calls
    assert call["config"].path == ideal and call["config"].state_dir != load_config().state_dir


def test_a_room_is_refused_by_the_geometric_experiments_and_unknown_rooms_by_the_parser(tmp_path, capsys):
    assert main(["experiment", "learn", "--room", "photos", "--fixations", "5", "--out", str(tmp_path)]) == 2
    assert "--room" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        build_parser().parse_args(["experiment", "online", "--room", "cellar"])


def test_a_sweep_varies_the_room_of_its_runs():
    runs = build_runs("online", [0], ["default"], [("room", ["generated", "photos"])], ["--fixations", "1000"])
    assert [dict(r.settings)["room"] for r in runs] == ["generated", "photos"]
    for run, room in zip(runs, ("generated", "photos")):
        args = build_parser().parse_args(list(run.argv))
        assert args.room == room and args.fixations == 1000


def test_the_online_summary_gives_the_joint_range_landing_error_beside_the_rooms():
    result = OnlineResult(ONLINE_EXPERIMENTS["online"])
    assert online_summary(result)["landing_joint_range_px"] is None  # no landing checks
    result.landing = [(40, 9.0), (80, 3.0)]
    result.landing_joint_range = [(40, 20.0), (80, 6.5)]
    assert online_summary(result)["landing_joint_range_px"] == 6.5  # the last check's


def test_a_sweep_without_the_pose_passes_no_pose_to_every_run(monkeypatch):
    seen: list[list[str]] = []

    def fake_sweep_run(args, base):
        seen.append(list(base))
        return 0

    monkeypatch.setattr(cmd_experiment, "run_sweep_command", fake_sweep_run)
    assert main(["experiment", "sweep", "online", "--no-pose", "--room", "photos", "--fixations", "50"]) == 0
    assert main(["experiment", "sweep", "online", "--fixations", "50"]) == 0
    with_pose_off, default = seen
    assert "--no-pose" in with_pose_off and with_pose_off[with_pose_off.index("--room") + 1] == "photos"
    assert "--no-pose" not in default and "--room" not in default
