"""The step-disparity diagnostic: corrective steps near a converged fovea, on looks made up to know its answer."""
from __future__ import annotations

import json

import pytest

from benchmarks.diag.step_disparity import FOVEA, main, near_fovea_steps, tally

PATCH = (32, 20)


def fixation(aim_offset, d, planned_vergence, moved_vergence, truth, converged=True):
    return {"aim": [float(FOVEA[0] + aim_offset[0]), float(FOVEA[1] + aim_offset[1]), d], "converged": converged,
            "planned": [0.1, 0.0, planned_vergence], "pose_before": [0.0, 0.0, 2.0],
            "pose_after": [0.1, 0.0, 2.0 + moved_vergence], "true_error_px": truth}


def search(seen=None):
    return {"search": 1.0, "why": "", **({"seen_at_px": list(seen)} if seen is not None else {})}


def look(*steps):
    return {"state": "failed", "steps": list(steps)}


def test_a_step_near_the_converged_fovea_is_told_undone_where_fine_vergence_turned_its_vergence_back():
    first = fixation((60.0, 0.0), 0.0, 0.0, 0.0, 2.5)
    # Planned +0.9 deg with d -4 px; fine vergence turned it back by 1.0 (the eyes end 0.1 from where
    # they were): undone, and the target truly 2.2 px off after it.
    [row] = near_fovea_steps(look(first, search((2.5, 0.0)), fixation((2.5, 0.0), -4.0, 0.9, -0.1, 2.2)), PATCH)
    assert row["undone"] and row["d"] == -4.0 and row["fine_vergence_deg"] == pytest.approx(-1.0)
    # The plan kept (fine vergence moved 0.1 more): not undone.
    [row] = near_fovea_steps(look(first, search((2.5, 0.0)), fixation((2.5, 0.0), -4.0, 0.9, 1.0, 0.3)), PATCH)
    assert not row["undone"]
    # A change within the play (0.2 deg) turned back is not told undone.
    [row] = near_fovea_steps(look(first, search((2.5, 0.0)), fixation((2.5, 0.0), -0.8, 0.2, 0.0, 0.3)), PATCH)
    assert not row["undone"]


def test_only_steps_whose_target_shared_a_converged_fovea_are_read():
    far = look(fixation((60.0, 0.0), 0.0, 0.0, 0.0, 9.0), search((9.0, 0.0)), fixation((9.0, 0.0), -4.0, 0.9, -0.1, 1.0))
    unconverged = look(fixation((60.0, 0.0), 0.0, 0.0, 0.0, 2.0, converged=False), search((2.0, 0.0)),
                       fixation((2.0, 0.0), -4.0, 0.9, -0.1, 1.0))
    assert near_fovea_steps(far, PATCH) == [] and near_fovea_steps(unconverged, PATCH) == []
    # Without the sighting's offset recorded, the step's aim stands for it.
    older = look(fixation((60.0, 0.0), 0.0, 0.0, 0.0, 2.0), search(), fixation((2.0, 1.0), -4.0, 0.9, -0.1, 1.0))
    assert len(near_fovea_steps(older, PATCH)) == 1


def test_the_tally_bands_by_d_and_the_command_names_a_missing_file(tmp_path, capsys):
    first = fixation((60.0, 0.0), 0.0, 0.0, 0.0, 2.5)
    looks = [look(first, search((2.5, 0.0)), fixation((2.5, 0.0), -4.0, 0.9, -0.1, 2.2)),
             look(first, search((1.5, 0.0)), fixation((1.5, 0.0), 0.3, -0.05, -0.05, 0.4))]
    path = tmp_path / "steps.json"
    path.write_text(json.dumps({"looks": looks}))
    rows = {row["d_px"]: row for row in tally([path], PATCH)}
    assert (rows[(0.0, 1.0)]["steps"], rows[(0.0, 1.0)]["on_fovea_after"]) == (1, 1)
    assert (rows[(2.0, float("inf"))]["steps"], rows[(2.0, float("inf"))]["undone"]) == (1, 1)
    assert rows[(2.0, float("inf"))]["on_fovea_after"] == 0
    assert main([str(path)]) == 0
    assert ">= 2" in capsys.readouterr().out
    with pytest.raises(SystemExit):
        main([str(tmp_path / "nothing.json")])
    assert "no such recording" in capsys.readouterr().err
