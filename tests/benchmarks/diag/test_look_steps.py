"""The look-steps diagnostic: its summary, on looks made up to know its answer; its recorder, on a plane head."""
from __future__ import annotations

import numpy as np

from benchmarks.diag.look_steps import StepRecorder, summary
from calib_free.gaze.fixation import FixationController, FixationParams
from calib_free.gaze.look import LookController, LookOutcome
from tests.support.planar_head import LinearMap, PlanarHead


def fixation(truth, before_vergence, after_vergence, outcome="taught"):
    return {"aim": [160.0, 120.0, 0.0], "outcome": outcome, "converged": True, "vergence_steps": 1,
            "pose_before": [0.0, 0.0, before_vergence], "pose_after": [0.0, 0.0, after_vergence],
            "true_error_px": truth}


def look(state, on_target, *steps):
    return {"state": state, "on_target": on_target, "steps": list(steps)}


def test_the_summary_counts_failures_by_the_first_saccades_truth_and_the_corrective_vergence():
    looks = [
        look("refused", False),
        look("done", True, fixation(0.4, 2.0, 2.1), {"search": 0.5, "why": ""}),
        # landed on target, then the search took a repeat and the corrective step turned the eyes
        look("failed", False, fixation(0.8, 2.0, 2.0, "left and right matches disagree"), {"search": 8.0, "why": ""},
             fixation(8.1, 2.0, 3.5), {"search": 7.9, "why": ""}),
        look("failed", False, fixation(1.5, 3.0, 3.0), {"search": None, "why": "ambiguous"}),
        look("failed", False, fixation(12.0, 1.0, 1.0), {"search": 11.0, "why": ""},
             fixation(3.0, 1.0, 1.2)),
        look("failed", False, fixation(None, 1.0, 1.0, "vergence did not converge")),
    ]
    out = summary(looks)
    assert (out["looks"], out["taken_on"], out["on_target"]) == (6, 5, 1)
    assert out["failed_by_first_saccade_true_error"] == {"<= 1 px": 1, "1-2 px": 1, "> 2 px": 1, "unknown": 1}
    assert out["fixation_outcomes"] == {"taught": 5, "left and right matches disagree": 1,
                                        "vergence did not converge": 1}
    assert out["corrective_steps"] == 2
    assert out["corrective_vergence_change_deg"]["over_0.5"] == 1
    assert abs(out["corrective_vergence_change_deg"]["p50"] - 0.85) < 1e-9


def search(distance, radius, scale):
    return {"search": distance, "why": "", "target_radius_px": radius, "warp_scales": [scale, 1.0]}


def test_first_sightings_bin_the_lens_scale_of_those_the_truth_agrees_with_and_list_the_rest():
    looks = [
        look("done", True, fixation(0.4, 2.0, 2.0), search(0.5, 30.0, 1.02)),
        look("done", True, fixation(1.0, 2.0, 2.0), search(2.5, 35.0, 1.04)),  # within 2 px of the truth
        look("done", True, fixation(0.3, 2.0, 2.0), search(0.2, 130.0, 1.40)),
        # the truth says the saccade landed; the search took a look-alike 14 px off, stretched 2.1x
        look("failed", False, fixation(0.7, 2.0, 2.0), search(14.4, 75.0, 2.12), fixation(14.5, 2.0, 2.0)),
        look("failed", False, fixation(None, 2.0, 2.0), search(3.0, 50.0, 1.1)),  # no truth: not judged
        look("failed", False, fixation(2.0, 2.0, 2.0), {"search": None, "why": "ambiguous"}),
    ]
    out = summary(looks)["first_sightings"]
    bins = out["agreeing_scale_by_radius_px"]
    assert set(bins) == {"20-40", "120-140"}
    assert bins["20-40"]["n"] == 2 and abs(bins["20-40"]["p50"] - 1.03) < 1e-9
    assert (bins["20-40"]["min"], bins["20-40"]["max"]) == (1.02, 1.04)
    assert out["refuted_by_truth"] == [{"target_radius_px": 75.0, "scale": 2.12, "search_px": 14.4, "true_px": 0.7}]


def test_the_recorder_sees_every_fixation_and_search_of_a_look_even_one_refused_before_the_saccade():
    """Installed, the recorder wraps the look's fixations and searches as the look calls them,
    a target judged before the saccade included."""
    recorder = StepRecorder(world=None, lens=None)
    with recorder.installed():
        looks = LookController(FixationController(PlanarHead(), LinearMap(0.9), FixationParams(), seed=0))
        record = looks.look((236.0, 84.0, 0.0))
        flat = LookController(FixationController(PlanarHead(plane=np.full((800, 1000), 128.0, np.float32)),
                                                 LinearMap(0.9), FixationParams(), seed=0))
        refused = flat.look((236.0, 84.0, 0.0))
    steps = recorder.take()
    assert record.on_target and refused.outcome is LookOutcome.NO_TARGET_PATCH
    fixations = [s for s in steps if "aim" in s]
    assert len(fixations) == len(record.fixations) + 1
    assert fixations[-1]["outcome"] == "target refused before the saccade" and fixations[-1]["true_error_px"] is None
    # Each fixation's saccade plan and the foveal disparity before each vergence step, as the look ran them.
    for recorded, ran in zip(fixations, record.fixations):
        assert recorded["planned"] == [round(float(v), 3) for v in ran.planned]
        assert len(recorded["vergence_disparities_px"]) == len(ran.vergence_disparities_px) >= 1
    assert fixations[-1]["planned"] is None
    assert len([s for s in steps if "search" in s]) == len(record.sightings)
    # Where each search saw the target, from the fovea, as the look's sightings say.
    for recorded, sighting in zip([s for s in steps if "search" in s], record.sightings):
        assert recorded["seen_at_px"] == [round(sighting.x - 159.5, 2), round(sighting.y - 119.5, 2)]
    # A corrective step records the d measured before it (the plane's: 0 at converged eyes); the
    # first fixation measures none.
    look_fixations = fixations[:len(record.fixations)]
    assert record.corrective_steps >= 1 and look_fixations[0]["measured_d"] is None
    assert all(f["measured_d"] is not None and abs(f["measured_d"]) <= 1.0 and f["measured_d"] == f["aim"][2]
               for f in look_fixations[1:])
