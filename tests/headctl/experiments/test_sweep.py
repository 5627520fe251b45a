"""`headctl experiment sweep`: the grid, a sweep on a local Dask cluster, keeping and skipping runs."""
from __future__ import annotations

import csv
import json

import pytest

from headctl.cli.main import main
from headctl.experiments.sweep import SweepError, build_runs, finished, parse_seeds, parse_set, pending, run_dir, run_sweep
from headctl.experiments.summary import fixations_to_share, spread


def test_seeds_and_settings_are_parsed_and_checked():
    assert parse_seeds("0-2,7,1") == [0, 1, 2, 7]
    assert parse_set(["exploration=random,teaching", "--landing-every=10"]) == [
        ("exploration", ["random", "teaching"]), ("landing_every", ["10"])]
    for bad in ("3-1", "a", "-1"):
        with pytest.raises(SweepError, match="--seeds"):
            parse_seeds(bad)
    with pytest.raises(SweepError, match="the sweep sets it itself"):
        parse_set(["seed=1,2"])
    with pytest.raises(SweepError, match="not an option a sweep can vary"):
        parse_set(["colour=red"])
    with pytest.raises(SweepError, match="expected key=value"):
        parse_set(["fixations"])


def test_every_run_of_the_grid_is_checked_by_the_experiments_parser():
    runs = build_runs("learn", [0, 1], ["default", "paper"], [("fixations", ["20", "40"])], ["--floor-samples", "0"])
    assert len(runs) == 8 and len({r.run_id for r in runs}) == 8
    assert len({r.setting_id for r in runs}) == 4  # seeds are what a setting aggregates over
    run = runs[0]
    assert run.argv[:2] == ("experiment", "learn") and "--floor-samples" in run.argv
    with pytest.raises(SweepError, match="invalid choice: 'sideways'"):
        build_runs("online", [0], ["default"], [("exploration", ["sideways"])])


def test_spread_and_the_fixations_to_most_of_the_improvement():
    s = spread([4.0, 1.0, 3.0, None, 2.0, float("nan")])
    assert (s["n"], s["median"], s["q25"], s["q75"], s["min"], s["max"]) == (4, 2.5, 1.75, 3.25, 1.0, 4.0)
    # from 100 px to 10 px: 90 % of the improvement is made at 19 px
    curve = [(0, 100.0), (50, 40.0), (100, 18.0), (150, 12.0), (200, 10.0)]
    assert fixations_to_share(curve) == 100
    assert fixations_to_share([(0, 5.0), (50, 6.0)]) is None  # no improvement to share


def test_a_sweep_runs_on_a_local_cluster_keeps_each_run_and_aggregates(tmp_path, capsys):
    out = tmp_path / "sweep"
    argv = ["experiment", "sweep", "learn", "--seeds", "0-1", "--set", "fixations=20,40", "--floor-samples", "0",
            "--landing-every", "10", "--out", str(out)]
    assert main(argv) == 0
    printed = capsys.readouterr().out
    assert "fixations=20 (seeds 0, 1)" in printed and "landing_error_px" in printed
    runs = build_runs("learn", [0, 1], ["default"], [("fixations", ["20", "40"])],
                      ["--floor-samples", "0", "--landing-every", "10"])
    for run in runs:
        folder = run_dir(out, run)
        assert finished(out, run)
        record = json.loads((folder / "run.json").read_text())
        assert record["code"] == 0 and record["seed"] == run.seed
        result = json.loads((folder / "learn-default.json").read_text())
        assert result["fixations"] == int(dict(run.settings)["fixations"])
        assert (folder / "learn-default.csv").read_text().count("\n") == result["fixations"] + 1
    summary = json.loads((out / "summary.json").read_text())
    settings = summary["settings"]
    assert set(settings) == {"profile=default, fixations=20", "profile=default, fixations=40"}
    for name, setting in settings.items():
        landing = setting["figures"]["landing_error_px"]
        assert landing["n"] == 2 and landing["q25"] <= landing["median"] <= landing["q75"]
        assert sorted(setting["per_seed"]["landing_error_px"]) == [landing["min"], landing["max"]]
    with open(out / "summary.csv") as f:
        rows = list(csv.DictReader(f))
    assert {r["setting"] for r in rows} == set(settings) and all(r["n"] == "2" for r in rows if r["median"])
    assert (out / "summary.png").stat().st_size > 0

    # Run again: every run is finished and skipped, no cluster is needed.
    done, failed = run_sweep(runs, out, progress=False)
    assert len(done) == 4 and failed == []


def test_a_killed_sweep_keeps_finished_runs_and_redoes_the_rest(tmp_path):
    out = tmp_path / "sweep"
    runs = build_runs("learn", [0, 1], ["default"], [], ["--fixations", "10", "--floor-samples", "0"])
    finished_run, cut_run = runs
    folder = run_dir(out, finished_run)
    folder.mkdir(parents=True)
    (folder / "learn-default.json").write_text(json.dumps({"fixations": 10}))
    (folder / "run.json").write_text(json.dumps({"code": 0, "argv": list(finished_run.argv)}))
    cut = run_dir(out, cut_run)
    cut.mkdir()
    (cut / "run.json").write_text(json.dumps({"code": 0, "argv": list(cut_run.argv)}))
    (cut / "learn-default.json").write_text('{"fixat')  # cut short
    scratch = out / "runs" / f".{cut.name}.1234abcd.tmp"
    scratch.mkdir()
    assert finished(out, finished_run) and not finished(out, cut_run)
    done, todo = pending(runs, out)
    assert done == [finished_run] and todo == [cut_run]
    assert not scratch.exists()  # what the killed sweep left half-written is gone
    # The same run with other options given to the sweep is another run: done again.
    longer = build_runs("learn", [0, 1], ["default"], [], ["--fixations", "20", "--floor-samples", "0"])
    assert longer[0].run_id == finished_run.run_id and not finished(out, longer[0])
