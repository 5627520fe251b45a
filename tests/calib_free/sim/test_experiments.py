"""The paper's experiments and `headctl experiment`: re-adaptation, CSV, plot, summary, errors."""
from __future__ import annotations

import csv
import dataclasses
import json

import numpy as np
import pytest

from calib_free.map.gaze_map import GazeMap
from calib_free.sim.experiments import EXPERIMENTS, Change, ExperimentSpec, representation_floor, run_experiment, running_mean
from calib_free.sim.head_model import HeadModel
from headctl.cli.main import main


def test_running_mean_averages_the_last_n():
    values = np.array([1.0, 2.0, 3.0, 4.0, 5.0])
    np.testing.assert_allclose(running_mean(values, 2), [1.0, 1.5, 2.5, 3.5, 4.5])
    np.testing.assert_allclose(running_mean(values, 10), [1.0, 1.5, 2.0, 2.5, 3.0])


def test_changes_switch_on_their_perturbation():
    head = HeadModel.default()
    after = Change(5, baseline_delta_m=0.01).apply(Change(1, baseline_delta_m=0.01).apply(head))
    assert after.effective_baseline_m == pytest.approx(0.080)
    assert Change(1, vertical_prism=True).apply(head).perturbation.vertical_prism
    assert head.perturbation.vertical_prism is False  # the original is untouched


@pytest.mark.parametrize("name", ["prism", "pan-defect"])
def test_default_profile_re_adapts_after_a_change(name):
    spec = dataclasses.replace(EXPERIMENTS[name], fixations=1000,
                               changes=(dataclasses.replace(EXPERIMENTS[name].changes[0], at=500),))
    result = run_experiment(spec, GazeMap.for_image(320, 240, seed=0), seed=0, landing_every=100)
    landing = dict(result.landing)
    before = result.retinal_error[400:500].mean()
    assert result.retinal_error[500:520].mean() > 2 * before  # the change hurts...
    assert landing[1000] < 1.5 * landing[500]  # ...and is learned away
    recovery = result.recovery_fixations(500)
    assert recovery is not None and recovery <= 500


def test_representation_floor_shrinks_with_more_samples():
    head = HeadModel.default()
    coarse, _ = representation_floor(head, (-60, 60), samples=300)
    fine, _ = representation_floor(head, (-60, 60), samples=5000)
    assert fine < coarse
    assert 1.0 < fine < 10.0


def test_experiment_command_writes_csv_plot_and_summary(tmp_path, capsys):
    code = main(["--log-level", "WARNING", "experiment", "prism", "--fixations", "400", "--floor-samples", "2000",
                 "--landing-every", "100", "--out", str(tmp_path)])
    assert code == 0
    out = capsys.readouterr().out
    assert "prism (default profile), 400 fixations" in out
    assert "landing error" in out and "floor (k-NN)" in out
    with open(tmp_path / "prism-default.csv") as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == 400
    assert float(rows[-1]["retinal_error_avg10"]) > 0
    assert rows[99]["landing_error_median_px"] != "" and rows[98]["landing_error_median_px"] == ""
    png = (tmp_path / "prism-default.png").read_bytes()
    assert png.startswith(b"\x89PNG") and len(png) > 10_000
    summary = json.loads((tmp_path / "prism-default.json").read_text())
    assert summary["fixations"] == 400 and summary["changes"] == []  # the change at 1,000 is past the end
    assert summary["floor_px"] > 0


def test_experiment_command_rejects_bad_arguments(tmp_path, capsys):
    assert main(["experiment", "learn", "--fixations", "0", "--out", str(tmp_path)]) == 2
    assert "--fixations must be at least 1" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["experiment", "no-such-experiment"])
    assert "invalid choice: 'no-such-experiment'" in capsys.readouterr().err


def test_every_named_experiment_is_well_formed():
    for name, spec in EXPERIMENTS.items():
        assert isinstance(spec, ExperimentSpec) and spec.name == name
        assert all(0 < c.at < spec.fixations for c in spec.changes)
