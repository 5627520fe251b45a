"""Looks and events apart from HTTP (headctl.service.looks, headctl.service.events): the queue the
fixation thread serves and the hub the event stream reads; the answer each refusal becomes is the
API's (headctl.api.app.control_status)."""
from __future__ import annotations

import threading

import numpy as np
import pytest

from headctl.api.app import control_status
from headctl.errors import ControlError, NotFoundError, QueueFullError
from headctl.service.events import EventHub
from headctl.service.looks import LookKind, LookQueue, LookRequest, LookState

CANCELLED, DONE, RUNNING = LookState.CANCELLED, LookState.DONE, LookState.RUNNING

TARGET = LookRequest(LookKind.TARGET, (10.0, 20.0, -3.0))


def test_looks_run_in_order_and_finish_once():
    q = LookQueue(size=4)
    a, b = q.submit(TARGET), q.submit(LookRequest(LookKind.ANGLES, (1.0, 2.0, 3.0), relative=True))
    assert (a.id, b.id) == (1, 2) and q.pending() == 2
    taken = q.take()
    assert taken is a and a.state == RUNNING and a.started_s is not None
    q.finish(a, DONE, "taught", result={"landing_error_px": 1.5})
    assert a.done.is_set() and q.get(1).result == {"landing_error_px": 1.5}
    assert q.take() is b and q.take() is None
    assert b.request.as_dict() == {"kind": "angles", "pan": 1.0, "tilt": 2.0, "vergence": 3.0, "relative": True}


def test_a_full_queue_refuses_and_replace_cancels_the_waiting_ones():
    q = LookQueue(size=2)
    first, second = q.submit(TARGET), q.submit(TARGET)
    with pytest.raises(QueueFullError) as err:
        q.submit(TARGET)
    assert control_status(err.value) == 429
    newest = q.submit(TARGET, replace=True)
    assert first.state == second.state == CANCELLED and first.outcome == "replaced"
    assert q.pending() == 1 and q.take() is newest


def test_a_queued_look_is_cancelled_at_once_a_running_one_on_request_an_ended_one_not_at_all():
    q = LookQueue()
    a, b = q.submit(TARGET), q.submit(TARGET)
    q.take()
    assert q.cancel(b.id).state == CANCELLED and b.done.is_set() and q.take() is None
    # The running look is asked to stop; it ends when the fixation thread has stopped it.
    assert q.cancel(a.id) is a and a.state == RUNNING and not a.done.is_set()
    assert a.cancel_requested.is_set() and a.as_dict()["cancel_requested"] is True
    assert (a.cancel_outcome, a.cancel_detail) == ("cancelled", "cancelled by a client")
    q.finish(a, CANCELLED, a.cancel_outcome, a.cancel_detail)
    with pytest.raises(ControlError, match="look 1 is cancelled already") as err:
        q.cancel(a.id)
    assert err.value.field == "id"
    with pytest.raises(NotFoundError) as err:
        q.get(99)
    assert err.value.field == "id" and control_status(err.value) == 404


def test_replace_stops_the_running_look_but_not_a_finished_one():
    q = LookQueue()
    running = q.submit(TARGET)
    q.take()
    newest = q.submit(TARGET, replace=True)
    assert running.cancel_requested.is_set() and running.cancel_outcome == "replaced"
    assert not newest.cancel_requested.is_set()
    q.finish(running, CANCELLED, running.cancel_outcome)
    q.take()
    q.finish(newest, DONE, "taught")
    q.submit(TARGET, replace=True)
    assert not newest.cancel_requested.is_set()  # it had ended: nothing to stop


def test_done_callbacks_run_once_whenever_they_are_added():
    q = LookQueue()
    job = q.submit(TARGET)
    calls = []
    job.add_done_callback(lambda j: calls.append(("before", j.state)))
    q.finish(q.take(), DONE, "taught")
    job.add_done_callback(lambda j: calls.append(("after", j.state)))
    assert calls == [("before", DONE), ("after", DONE)]


def test_the_fixation_thread_wakes_when_a_look_arrives():
    q = LookQueue()
    woke = threading.Event()

    def server():
        if q.wait_for_work(10.0):
            woke.set()

    t = threading.Thread(target=server)
    t.start()
    q.submit(TARGET)
    t.join(10)
    assert woke.is_set() and q.take().state == RUNNING


def test_events_reach_subscribers_and_a_late_one_gets_the_backlog():
    hub = EventHub(history=3)
    got = []
    unsubscribe = hub.subscribe(got.append)
    for i in range(5):
        hub.publish("saccade_onset", goal=np.array([i, 0.5, np.nan]))
    assert [e["seq"] for e in got] == [1, 2, 3, 4, 5] and hub.seq == 5
    assert got[0]["goal"] == [0, 0.5, None]  # JSON-ready: numpy to lists, NaN to null
    late = []
    hub.subscribe(late.append, after_seq=3)
    assert [e["seq"] for e in late] == [4, 5]  # what it missed, of what is kept
    unsubscribe()
    hub.publish("fault", key="servo_bus", message="down")
    assert len(got) == 5 and late[-1]["type"] == "fault" and hub.counts["saccade_onset"] == 5


def test_a_failing_subscriber_does_not_stop_the_publisher():
    hub = EventHub()
    got = []

    def broken(event):
        raise RuntimeError("client gone")

    hub.subscribe(broken)
    hub.subscribe(got.append)
    hub.publish("torque", enabled=False)
    assert got[0]["enabled"] is False
