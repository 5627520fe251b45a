"""A client's target look through the fixation thread (headctl.service.fixation_thread): its
state says whether the head ended on the target, and its result's figures come only from
accepted measurements. The head looks at a textured plane (`tests.support.planar_head`),
so where the target really ended is known; the thread's look runs on the test's thread."""
from __future__ import annotations

import threading

import numpy as np
import pytest

from calib_free.gaze.fixation import FixationController, FixationParams
from headctl.service.events import EventHub
from headctl.service.fixation_thread import FixationThread, Interrupt
from headctl.service.looks import LookKind, LookQueue, LookRequest, LookState
from tests.support.planar_head import HEIGHT, WIDTH, LinearMap, PlanarHead

FOVEA = np.array([(WIDTH - 1) / 2, (HEIGHT - 1) / 2])


class ServiceHead(PlanarHead):
    """The plane head with what the fixation thread also asks of the service's `Head`."""

    def set_phase(self, phase: str) -> None:
        pass


def run_look(head, request, gain=0.8, params=None):
    """Queue `request`, let the fixation thread carry it out, return (job, events)."""
    controller = FixationController(head, LinearMap(gain), params or FixationParams(), seed=0)
    looks, hub = LookQueue(), EventHub()
    thread = FixationThread(controller, head, Interrupt(threading.Event()), looks, hub, lambda: None)
    looks.submit(request)
    job = looks.take()
    thread._look(job)  # what the thread's loop does with a look it takes
    return job, hub.recent(512), thread


def events_of(hub_events):
    return [e["type"] for e in hub_events]


def test_a_look_ends_done_only_with_the_target_on_the_fovea():
    head = ServiceHead()
    target = (255.0, 75.0)
    texel = head.texel_at(target)
    job, events, thread = run_look(head, LookRequest(LookKind.TARGET, (*target, 0.0)))
    result = job.result
    assert job.state is LookState.DONE and job.outcome == "on target"
    assert result["on_target"] and result["final_error_px"] <= result["tolerance_px"] == 1.0
    truth = float(np.hypot(*(head.image_position(texel) - FOVEA)))
    assert truth <= 1.0 and result["final_error_px"] == pytest.approx(truth, abs=0.3)
    assert 1 <= result["corrective_steps"] <= 3 and len(result["fixations"]) == result["corrective_steps"] + 1
    assert result["attempts"] == 1
    assert result["landing_error_px"] > 5  # the open-loop figure: the first saccade fell short
    assert result["taught"] == len(result["fixations"]) and thread.taught == result["taught"]
    assert list(thread.landing_errors_px) == [pytest.approx(result["landing_error_px"], abs=1e-3)]
    # One fixation event per step, between the look's start and end.
    kinds = events_of(events)
    assert kinds[0] == "look_started" and kinds[-1] == "look_done"
    assert kinds.count("fixation_converged") == len(result["fixations"])


def test_a_look_whose_target_is_occluded_after_the_saccade_fails_without_an_error_figure():
    head = ServiceHead()
    target = (90.0, 180.0)
    u, v = (int(round(c)) for c in head.texel_at(target))

    def cover(h) -> None:
        if len(h.moves) == 1:
            h.plane = h.plane.copy()
            h.plane[v - 40:v + 40, u - 40:u + 40] = 128.0

    head.on_move = cover
    job, _, _ = run_look(head, LookRequest(LookKind.TARGET, (*target, 0.0)))
    assert job.state is LookState.FAILED and job.outcome == "target not found again"
    assert job.result["final_error_px"] is None and job.result["on_target"] is False
    assert job.result["target_px"] is None


def test_a_refused_correspondence_gives_no_landing_error_position_or_confidence():
    head = ServiceHead()
    job, _, thread = run_look(head, LookRequest(LookKind.TARGET, (230.0, 160.0, 0.0)),
                              params=FixationParams(confidence_floor=1.0))
    result = job.result
    assert all(f["outcome"] == "confidence below the floor" for f in result["fixations"])
    assert result["landing_error_px"] is None and result["position"] is None and result["confidence"] is None
    assert not thread.landing_errors_px
    # The head is on the target all the same, and the look says so.
    assert job.state is LookState.DONE and result["final_error_px"] <= 1.0


def test_a_look_that_cannot_reach_its_target_fails_with_the_reason():
    head = ServiceHead(pose=(39.5, 0.0, 8.0))  # at the left end of pan
    job, _, _ = run_look(head, LookRequest(LookKind.TARGET, (20.0, 120.0, 0.0)), gain=1.0)
    assert job.state is LookState.FAILED and job.outcome == "target beyond the joint limits"
    assert "pan" in job.detail


def test_a_queued_target_is_looked_at_from_the_view_it_was_chosen_in():
    head = ServiceHead()
    reference = tuple(head.read_pose().tolist())
    target = (120.0, 60.0)
    texel = head.texel_at(target)
    head.move_to(np.array([-10.0, 6.0, 8.0]))
    job, _, _ = run_look(head, LookRequest(LookKind.TARGET, (*target, 0.0), reference_pose=reference))
    assert job.result["head_moved_deg"] == pytest.approx(10.0)
    assert job.state is LookState.DONE
    assert np.hypot(*(head.image_position(texel) - FOVEA)) <= 1.0


def test_a_relative_angles_look_starts_from_the_reading_clamped_to_the_limits():
    # The eyes read 0.08 deg below the vergence range [1, 20] (the play at the limit): a
    # relative look that leaves the vergence as it is turns the head, from the limit.
    head = ServiceHead()
    head.pose = np.array([0.0, 0.0, 0.92])
    job, _, _ = run_look(head, LookRequest(LookKind.ANGLES, (2.0, -1.0, 0.0), relative=True))
    assert job.state is LookState.DONE, job.detail
    assert head.moves[-1] == pytest.approx([2.0, -1.0, 1.0])
    # Past the limit by the client's own values: refused, nothing sent.
    moves = len(head.moves)
    job, _, _ = run_look(head, LookRequest(LookKind.ANGLES, (0.0, 0.0, -0.5), relative=True))
    assert job.state is LookState.FAILED and "vergence 0.50 outside [1, 20]" in job.detail
    assert len(head.moves) == moves
