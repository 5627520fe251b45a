"""`headctl.experiments.paper`: requests read from options, and a sweep's run done without the CLI."""
from __future__ import annotations

import json

import pytest

from headctl.config.head import DEFAULT_CONFIG
from headctl.experiments.paper import ExperimentError, ExperimentRequest, learn
from headctl.experiments.report import format_summary, summary_of
from headctl.experiments.runs import LOG_FILE
from headctl.experiments.sweep import build_runs, run_task


def test_options_given_as_text_are_read_and_checked():
    request = ExperimentRequest.from_options("online", "paper", 3, {"fixations": "50", "room": "photos"}, pose=False)
    assert request == ExperimentRequest("online", "paper", fixations=50, seed=3, room="photos", pose=False)
    assert request.spec().fixations == 50 and request.spec().changes == ()
    for options, message in (({"fixations": "many"}, "invalid int value: 'many'"),
                             ({"room": "cellar"}, "invalid choice: 'cellar'"),
                             ({"colour": "red"}, "unrecognized argument: --colour")):
        with pytest.raises(ExperimentError, match=message):
            ExperimentRequest.from_options("online", "default", 0, options)
    with pytest.raises(ExperimentError, match="invalid choice: 'pursuit'"):
        ExperimentRequest.from_options("pursuit", "default", 0, {})


def test_requests_that_do_not_apply_are_refused_before_anything_runs():
    assert ExperimentRequest("learn").problem() is None
    for request, words in ((ExperimentRequest("learn", fixations=0), "--fixations must be at least 1"),
                           (ExperimentRequest("online", lens="equidistant"), "--lens applies"),
                           (ExperimentRequest("learn", room="photos"), "--exploration, --room and --config apply")):
        assert words in (request.problem() or "")
        with pytest.raises(ExperimentError, match=words):
            learn(request)


def test_a_sweeps_run_is_the_experiments_function_and_writes_what_the_command_writes():
    good, _other_lens = build_runs("learn", [0], ["default"], [("lens", ["foveated", "equidistant"])],
                               ["--fixations", "12", "--floor-samples", "0", "--landing-every", "6"])
    result = run_task(good)
    assert result.code == 0
    assert set(result.files) == {"learn-default.csv", "learn-default.png", "learn-default.json", LOG_FILE}
    summary = json.loads(result.files["learn-default.json"])
    assert summary["fixations"] == 12 and summary["pose"] is True
    assert b"learn (default profile), 12 fixations" in result.files[LOG_FILE]
    refused_online = build_runs("online", [0], ["default"], [], ["--lens", "equidistant"])[0]
    result = run_task(refused_online)
    assert result.code == 2 and b"--lens applies" in result.files[LOG_FILE]


def test_the_online_summary_compares_with_fig_7_and_names_its_world(tmp_path):
    config = tmp_path / "head.yaml"
    config.write_text(DEFAULT_CONFIG.read_text())
    report = learn(ExperimentRequest("online", fixations=3, landing_every=0, config=str(config)))
    text = format_summary(summary_of(report))
    assert "paper fig. 7 (1,700 fixations)" in text and "fig. 5" not in text
    assert "1.70 deg" in text and "0.34 deg" in text  # fig. 7's pan and vergence errors
    assert f"in the simulated world of {config} (" in text
    geometric = learn(ExperimentRequest("learn", fixations=12, landing_every=0, floor_samples=0))
    assert "paper fig. 5 (2,000 fixations)" in format_summary(summary_of(geometric))
    with pytest.raises(ExperimentError, match="--config apply to the online"):
        learn(ExperimentRequest("learn", config=str(config)))
