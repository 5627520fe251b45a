"""The fixation thread backs off while fixations fail on a failed part (the servo loop gone:
"no servo state within 1.0 s" at once, again and again), and is back to back as soon as the
part answers again; stop() cuts a wait short."""
from __future__ import annotations

import threading
import time

import pytest

from calib_free.gaze.fixation import FixationKind, FixationOutcome, FixationParams, FixationRecord
from drivers.clock import SYSTEM_CLOCK
from headctl.service.events import EventHub
from headctl.service.fixation_thread import BACKOFF_FIRST_S, BACKOFF_MAX_S, FixationThread, Interrupt
from headctl.service.looks import LookQueue


class IdleHead:
    def set_phase(self, phase: str) -> None:
        pass


class FlakyController:
    """A `FixationController` whose servo loop is gone (every fixation refused at once, as the
    real one is when the loop's process died) until `answer` is set."""

    params = FixationParams()
    clock = staticmethod(SYSTEM_CLOCK.monotonic)

    def __init__(self, failures_wanted: int) -> None:
        self.answer = threading.Event()
        self.attempts: list[tuple[float, bool]] = []  # (when, answered)
        self.failed_enough = threading.Event()
        self.taught_enough = threading.Event()
        self.failures_wanted = failures_wanted

    def fixate(self, target=None, reference_pose=None, continues=False) -> FixationRecord:
        answered = self.answer.is_set()
        self.attempts.append((time.monotonic(), answered))
        outcome = FixationOutcome.TAUGHT if answered else FixationOutcome.BUS_DOWN
        detail = "" if answered else "sim-servo-bus(sim:head): no servo state within 1.0 s"
        if not answered and len(self.attempts) >= self.failures_wanted:
            self.failed_enough.set()
        if sum(a for _, a in self.attempts) >= 20:
            self.taught_enough.set()
        return FixationRecord(index=len(self.attempts), kind=FixationKind.EXPLORE, outcome=outcome, detail=detail)


@pytest.fixture
def flaky():
    controller = FlakyController(failures_wanted=7)
    thread = FixationThread(controller, IdleHead(), Interrupt(threading.Event()), LookQueue(), EventHub(),
                            lambda: None)
    thread.start()
    yield controller, thread
    thread.stop(timeout_s=2.0)


def test_attempts_on_a_servo_loop_that_does_not_answer_back_off_to_one_a_second(flaky):
    controller, thread = flaky
    assert controller.failed_enough.wait(10.0), "7 attempts did not come within 10 s"
    times = [t for t, _ in controller.attempts[:7]]
    gaps = [b - a for a, b in zip(times, times[1:])]
    wanted = [min(BACKOFF_FIRST_S * 2 ** i, BACKOFF_MAX_S) for i in range(6)]  # 0.05, 0.1, ... 1.0
    for gap, least in zip(gaps, wanted):  # never sooner (a loaded machine only makes them later)
        assert gap >= 0.95 * least, (gaps, wanted)
    # At most ~1 attempt a second once backed off: seven in 2.5 s at least, not thousands.
    assert times[-1] - times[0] >= 0.95 * sum(wanted)
    # stop() ends a wait of a second at once.
    started = time.monotonic()
    thread.stop(timeout_s=2.0)
    assert not thread.is_alive() and time.monotonic() - started < 0.5


def test_the_first_attempt_after_the_part_answers_works_and_the_back_off_resets(flaky):
    controller, thread = flaky
    assert controller.failed_enough.wait(10.0)
    answered_s = time.monotonic()
    controller.answer.set()
    assert controller.taught_enough.wait(5.0), "no 20 fixations after the servo loop answered"
    taught = [t for t, answered in controller.attempts if answered]
    failed = [t for t, answered in controller.attempts if not answered]
    assert taught[0] - answered_s <= BACKOFF_MAX_S + 0.5  # within the wait in progress, at most a second
    assert len(failed) <= 8  # the first attempt after it answered was already a fixation
    assert taught[19] - taught[0] < 1.0  # back to back again, no back-off left
    assert thread.backoff.failures == 0
