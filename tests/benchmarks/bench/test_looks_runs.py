"""The looks_daemon runs pooled: the shares, their interval, the failures' kinds, where they lie."""
from __future__ import annotations

import json
from pathlib import Path

import pytest

from benchmarks.bench.looks_runs import FailureClass, Seed, failure_class, figures, main, report, wilson_interval


def look(x: float, on: bool, outcome: str = "on target", detail: str = "", true_px: float | None = 0.4,
         state: str | None = None, vergence_off_deg: float | None = None) -> dict:
    row = {"xy": [x, 100.0], "state": state or ("done" if on else "failed"), "outcome": outcome,
           "detail": detail, "on_target": on, "true_error_px": true_px}
    if vergence_off_deg is not None:  # recorded by later runs only
        row["vergence_off_deg"] = vergence_off_deg
    return row


AMBIGUOUS = ("target not found again", "the target's patch is ambiguous: two places match it, NCC 0.90 and 0.89")
AT_LIMITS = ("target beyond the joint limits", "1.46 px from the fovea; tilt -25.2 outside [-25, 25] deg")


def write_run(directory: Path, name: str, seeds: list[list[dict]], world: str = "realistic",
              config: str = "sim.yaml") -> list[Path]:
    paths = []
    for i, rows in enumerate(seeds):
        path = directory / f"{name}-{i}.json"
        path.write_text(json.dumps({"config": config, "world": world, "rows": rows,
                                    "final_error_px": {"p90": 0.8}, "duration_s": {"p50": 0.4}}))
        paths.append(path)
    return paths


def test_the_score_interval_of_95_in_100_is_wilsons():
    low, high = wilson_interval(95, 100)
    assert low == pytest.approx(0.8883, abs=5e-4)
    assert high == pytest.approx(0.9785, abs=5e-4)


def test_the_score_interval_of_all_or_none_is_not_empty_and_stays_within_0_and_1():
    # p +- z se would be [1, 1]: ten looks on target do not make a certainty.
    low, high = wilson_interval(10, 10)
    assert low == pytest.approx(0.7225, abs=5e-4)
    assert high == pytest.approx(1.0)
    low, high = wilson_interval(0, 10)
    assert low == pytest.approx(0.0) and high == pytest.approx(0.2775, abs=5e-4)


def test_a_look_at_the_limits_counts_there_whatever_else_its_detail_says():
    assert failure_class(look(5, False, AT_LIMITS[0], "pan -40.3 outside [-40, 40] deg; " + AMBIGUOUS[1])) \
        is FailureClass.JOINT_LIMITS
    assert failure_class(look(5, False, *AMBIGUOUS)) is FailureClass.AMBIGUOUS
    assert failure_class(look(5, False, "target not on the fovea", "3.39 px from the fovea")) \
        is FailureClass.OFF_THE_FOVEA
    # A patch refused as repetitive in its own view is not the ambiguity after a saccade.
    assert failure_class(look(5, False, "no patch to find the target by",
                              "the target's patch at (215.2, 136.4) is ambiguous in its own view")) \
        is FailureClass.OTHER


def test_figures_count_the_looks_taken_on_the_look_alikes_and_where_the_failures_lie(tmp_path):
    rows = [look(10, True), look(20, True), look(30, True, true_px=4.1, vergence_off_deg=-4.2),  # a look-alike
            look(300, False, *AMBIGUOUS), look(310, False, *AT_LIMITS),
            look(150, False, "422", "beyond the joint limits", None, state="refused")]
    seed = Seed(tmp_path / "s.json", rows, 0.8, 0.4)
    f = figures([seed], width=320, columns=2)
    assert (f["taken_on"], f["on_target"]) == (5, 3)
    assert f["pooled"]["fraction"] == pytest.approx(0.6)
    assert f["truly_on_target"]["looks"] == 2
    assert [a["xy"][0] for a in f["look_alikes"]] == [30.0]
    assert "(30, 100) 4.1 px (eyes -4.2 deg from the planned vergence)" in report("run", f)
    assert f["pooled_without_joint_limits"] == pytest.approx(3 / 4)
    assert f["failures"] == {"ambiguous": 1, "at the joint limits": 1,
                             "off the fovea after the corrective steps": 0, "other": 0}
    assert [(b["taken_on"], b["on_target"], b["look_alikes"], b["failed"]) for b in f["by_column"]] == \
        [(3, 3, 1, 0), (2, 0, 0, 2)]


def test_the_seeds_median_is_of_their_own_shares_and_the_pool_of_all_their_looks(tmp_path):
    few = Seed(tmp_path / "a.json", [look(10, True), look(20, False, *AMBIGUOUS)], 0.8, 0.4)  # 1 of 2
    many = Seed(tmp_path / "b.json", [look(10, True)] * 8, 0.8, 0.4)  # 8 of 8
    f = figures([few, many], width=320, columns=1)
    assert f["on_target_fraction"]["median"] == pytest.approx(0.75)
    assert f["pooled"]["fraction"] == pytest.approx(9 / 10)


def test_the_runs_of_one_world_are_pooled_and_plotted(tmp_path, capsys):
    one = write_run(tmp_path, "one", [[look(10, True), look(300, False, *AMBIGUOUS)], [look(50, True)]])
    two = write_run(tmp_path, "two", [[look(60, True), look(70, True)]])
    ideal = write_run(tmp_path, "ideal", [[look(60, True)]], world="ideal", config="sim-ideal.yaml")
    out, picture = tmp_path / "f.json", tmp_path / "looks.png"
    assert main(["--run", f"one={tmp_path}/one-*.json", "--run", f"two={two[0]}", "--run", f"ideal={ideal[0]}",
                 "--plot", str(picture), "--json", str(out)]) == 0
    written = json.loads(out.read_text())
    assert written["runs"]["one"]["files"] == [str(p) for p in one]
    assert list(written["together"]) == ["sim.yaml (realistic)"]
    assert written["together"]["sim.yaml (realistic)"]["on_target"] == 4
    assert picture.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert "together: sim.yaml (realistic), one + two" in capsys.readouterr().out


def test_a_run_mixing_two_worlds_is_refused_naming_them(tmp_path, capsys):
    write_run(tmp_path, "looks-sim", [[look(10, True)]])
    write_run(tmp_path, "looks-sim-ideal", [[look(10, True)]], world="ideal", config="sim-ideal.yaml")
    with pytest.raises(SystemExit):
        main(["--run", f"mixed={tmp_path}/looks-sim-*.json"])
    error = capsys.readouterr().err
    assert "--run mixed" in error and "sim-ideal.yaml (ideal)" in error and "sim.yaml (realistic)" in error


def test_a_file_that_is_not_a_run_of_looks_is_named(tmp_path):
    path = tmp_path / "other.json"
    path.write_text(json.dumps({"looks": 3}))
    with pytest.raises(SystemExit, match="other.json: no 'rows'"):
        main(["--run", f"x={path}"])
