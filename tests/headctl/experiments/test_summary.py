"""`headctl.experiments.summary`: the figures read from a run's JSON and the printed table."""
from __future__ import annotations

from headctl.experiments.summary import SettingSummary, SweepSummary, run_figures


def readaptation_run(recovery_at_1000: int | None, recovery_at_2000: int | None) -> dict:
    """A re-adaptation run's summary JSON, shaped as `headctl experiment` writes it."""
    return {
        "experiment": "baseline", "fixations": 3000, "seconds": 12.5, "floor_px": 4.2,
        "landing_error_px": 0.5, "landing_over_floor": 0.5 / 4.2,
        "final": {"pan_deg": 0.11, "tilt_deg": 0.12, "vergence_deg": 0.13, "retinal_error": 0.014},
        "steady": {"pan_deg": 0.21, "tilt_deg": 0.22, "vergence_deg": 0.23, "retinal_error": 0.024},
        "changes": [
            {"at": 1000, "recovery_fixations": recovery_at_1000, "landing_before_px": 0.6,
             "landing_worst_after_px": 9.5, "landing_700_after_px": 0.7},
            {"at": 2000, "recovery_fixations": recovery_at_2000, "landing_before_px": 0.8,
             "landing_worst_after_px": 3.5, "landing_700_after_px": 0.9},
        ],
        "landing_curve_px": [[1000, 0.6], [1100, 9.5], [2000, 0.8], [3000, 0.5]],
    }


def test_a_readaptation_runs_figures_hold_both_windows_the_floor_and_each_change():
    figures, curve = run_figures(readaptation_run(51, None))
    assert (figures["pan_deg_last10"], figures["tilt_deg_last10"], figures["vergence_deg_last10"]) == (
        0.11, 0.12, 0.13)
    assert (figures["retinal_error_last10"], figures["retinal_error_last200"]) == (0.014, 0.024)
    assert figures["floor_px"] == 4.2
    assert (figures["landing_before_1000_px"], figures["landing_worst_after_1000_px"],
            figures["landing_700_after_1000_px"]) == (0.6, 9.5, 0.7)
    assert figures["landing_before_2000_px"] == 0.8
    assert figures["recovery_at_1000"] == 51 and figures["recovery_at_2000"] is None  # not back within the run
    assert curve[1] == (1100.0, 9.5)


def test_the_printed_table_gives_each_changes_recovery_in_the_order_of_the_changes():
    setting = SettingSummary("profile=default")
    for seed, (first, second) in enumerate([(51, 60), (53, None), (70, 90)]):
        figures, curve = run_figures(readaptation_run(first, second))
        setting.seeds.append(seed)
        for name, value in figures.items():
            setting.figures.setdefault(name, []).append(value)
        setting.curves.append(curve)
    lines = SweepSummary("baseline", {"profile=default": setting}).table().splitlines()
    recovery = [line.split() for line in lines if "recovery_at_" in line]
    assert [row[0] for row in recovery] == ["recovery_at_1000", "recovery_at_2000"]
    assert recovery[0][1] == "53" and recovery[0][-1] == "n=3"
    assert recovery[1][-1] == "n=2"  # the seed that never came back is not in the median; n tells
