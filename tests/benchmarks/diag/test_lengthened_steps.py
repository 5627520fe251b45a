"""The lengthened-steps diagnostic: which corrective steps a look lengthened, on looks made up to know its answer."""
from __future__ import annotations

import json

import pytest

from benchmarks.diag.lengthened_steps import FOVEA, lengthened_steps, main, tally


def fixation(aim_offset, truth):
    return {"aim": [float(FOVEA[0] + aim_offset[0]), float(FOVEA[1] + aim_offset[1]), 0.0], "true_error_px": truth}


def search(seen, keep_offset=True):
    out = {"search": float((seen[0] ** 2 + seen[1] ** 2) ** 0.5), "why": ""}
    if keep_offset:
        out["seen_at_px"] = list(seen)
    return out


def test_a_step_aimed_twice_as_far_as_the_target_was_seen_is_lengthened_and_says_how_far_the_one_before_moved():
    # The target seen 3 px right; the step carries it 3 px left (moved 6 px); the next aims 6 px left.
    crossed = {"steps": [fixation((40.0, 0.0), 3.0), search((3.0, 0.0)), fixation((3.0, 0.0), 3.0),
                         search((-3.0, 0.0)), fixation((-6.0, 0.0), 9.0), search((9.0, 0.0))]}
    [row] = lengthened_steps(crossed)
    assert row["moved_px"] == pytest.approx(6.0) and row["boost"] == pytest.approx(2.0)
    assert (row["true_before_px"], row["true_after_px"]) == (3.0, 9.0)
    # A step that did not move it (within 0.1 px), then one twice as long that brought it home.
    stuck = {"steps": [fixation((40.0, 0.0), 2.0), search((2.0, 0.0)), fixation((2.0, 0.0), 2.0),
                       search((2.1, 0.0)), fixation((4.2, 0.0), 0.3), search((0.3, 0.0))]}
    [row] = lengthened_steps(stuck)
    assert row["moved_px"] == pytest.approx(0.1)
    assert lengthened_steps({"steps": [fixation((40.0, 0.0), 2.0), search((2.0, 0.0)), fixation((2.0, 0.0), 0.5),
                                       search((0.5, 0.0))]}) == []  # as planned


def test_a_recording_without_offsets_is_read_by_the_distance_rule_it_ran_under():
    # The distance unchanged (3 px either side): that rule lengthened the next step.
    crossed = {"steps": [fixation((40.0, 0.0), 3.0), search((3.0, 0.0), False), fixation((3.0, 0.0), 3.0),
                         search((-3.0, 0.0), False), fixation((-6.0, 0.0), 9.0), search((9.0, 0.0), False)]}
    [row] = lengthened_steps(crossed)
    assert row["moved_px"] == pytest.approx(6.0) and row["boost"] == pytest.approx(2.0)


def test_the_tally_counts_by_motion_and_truth_and_the_command_names_a_missing_file(tmp_path, capsys):
    crossed = {"state": "failed", "steps": [fixation((40.0, 0.0), 3.0), search((3.0, 0.0)), fixation((3.0, 0.0), 3.0),
                                            search((-3.0, 0.0)), fixation((-6.0, 0.0), 9.0), search((9.0, 0.0))]}
    path = tmp_path / "steps.json"
    path.write_text(json.dumps({"looks": [crossed]}))
    steps, counts, rows = tally([path])
    assert steps == 2 and counts == {"moved, farther": 1} and rows[0]["recording"] == "steps.json"
    with pytest.raises(SystemExit):
        main([str(tmp_path / "nothing.json")])
    assert "no such recording" in capsys.readouterr().err
