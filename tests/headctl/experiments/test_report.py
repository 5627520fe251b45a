"""`headctl.experiments.report`: an online run's changes judged on its fixations' measured landing."""
from __future__ import annotations

import numpy as np
import pytest

from calib_free.correspondence.search import EyeMatch, FixationMatch
from calib_free.gaze.fixation import FixationKind, FixationOutcome, FixationRecord
from calib_free.map.gaze_map import AdaptResult
from calib_free.sim.experiments import Change
from headctl.experiments.online import OnlineResult, OnlineSpec
from headctl.experiments.report import change_summaries
from headctl.experiments.summary import run_figures

AIM = np.array([160.0, 120.0, 0.0])


def record(index: int, landing_px: float | None) -> FixationRecord:
    """An exploratory fixation that taught, landing `landing_px` right of its aim; refused if None."""
    if landing_px is None:
        return FixationRecord(index, FixationKind.EXPLORE, explore_target=AIM,
                              outcome=FixationOutcome.LOW_CONFIDENCE)
    x = AIM[0] + landing_px
    match = FixationMatch(EyeMatch(x, AIM[1], 0.9, 1, 1, 0), EyeMatch(x + 10, AIM[1], 0.9, 1, 1, 0))
    return FixationRecord(index, FixationKind.EXPLORE, explore_target=AIM, match=match,
                          outcome=FixationOutcome.TAUGHT)


def online_run(landings: list[float | None], change_at: int) -> OnlineResult:
    spec = OnlineSpec("online-prism", len(landings), (Change(change_at, vertical_prism=True),))
    result = OnlineResult(spec, records=[record(n, px) for n, px in enumerate(landings)])
    taught = [r.index for r in result.records if r.taught]
    result.adaptations = [(n, AdaptResult(True, retinal_error=0.02, output_error=np.full(3, 0.1))) for n in taught]
    return result


def test_an_online_runs_change_gives_its_measured_landings_recovery_in_fixations():
    # 300 fixations at 0.5 px, the change, 100 refused, 40 at 4 px, then 0.5 px again: back at
    # the 26th good one of the window, 100 + 40 + 26 fixations after the change.
    landings = [0.5] * 300 + [None] * 100 + [4.0] * 40 + [0.5] * 200
    online = online_run(landings, 300)
    result = online.as_experiment_result()
    (change,) = change_summaries(result, online)
    assert change["at"] == 300 and change["at_fixation"] == 300
    assert change["measured_landing_recovery_fixations"] == 166
    assert change["measured_landing_before_px"] == pytest.approx(0.5)
    assert change["measured_landing_bar_px"] == pytest.approx(0.625)
    assert change["measured_landing_peak_after_px"] == pytest.approx(4.0)


def test_the_sweep_keys_the_measured_recovery_by_the_changes_fixation():
    # Online, `at` counts adaptations (each seed its own); the measured figures go by fixation.
    landings = [None] * 50 + [0.5] * 250 + [0.5] * 100
    online = online_run(landings, 300)
    (change,) = change_summaries(online.as_experiment_result(), online)
    assert change["at"] == 250 and change["at_fixation"] == 300
    figures, _ = run_figures({"final": {"pan_deg": 0, "tilt_deg": 0, "vergence_deg": 0, "retinal_error": 0},
                              "steady": {"pan_deg": 0, "tilt_deg": 0, "vergence_deg": 0, "retinal_error": 0},
                              "changes": [change]})
    assert figures["measured_landing_recovery_at_300"] == 50
    assert figures["measured_landing_before_300_px"] == pytest.approx(0.5)
    assert "recovery_at_250" in figures and "measured_landing_recovery_at_250" not in figures


def test_a_geometric_runs_change_has_no_measured_landing():
    online = online_run([0.5] * 400, 300)
    (change,) = change_summaries(online.as_experiment_result())
    assert change["measured_landing_recovery_fixations"] is None and change["measured_landing_before_px"] is None
    figures, _ = run_figures({"final": {"pan_deg": 0, "tilt_deg": 0, "vergence_deg": 0, "retinal_error": 0},
                              "steady": {"pan_deg": 0, "tilt_deg": 0, "vergence_deg": 0, "retinal_error": 0},
                              "changes": [change]})
    assert not any(f.startswith("measured_landing") for f in figures)
