"""The fixation thread: clients' looks and tracks first, else exploratory fixations that teach the map.

Each fixation is `calib_free.gaze.fixation.FixationController.fixate()` on the service's `Head`;
taught ones go to the map adapter (the controller submits them). The thread is paused while
the servo bus is down or torque is off, and backs off while fixations keep failing on a part
that has failed (`PART_FAILURES`: the bus gone, a servo faulted, no frames): 0.05 s doubling to
1 s between attempts, reset by the first fixation that got past them, so a dead servo loop
costs about one attempt a second instead of thousands. `Interrupt` is what the head calls before every bus
access and frame wait: it stops the fixation in progress when the service stops (for good)
or when a client cancels the look in progress (that look only). `HeadEvents` turns what the
head tells into events and figures (phase, saccade onset and end, vergence latency).
`exposure` (`headctl.service.exposure.ExposureHold`) holds the cameras' exposure over each
exploratory fixation and each client's look, where the config asks for it.
"""
from __future__ import annotations

import collections
import contextlib
import logging
import threading
from typing import Callable, Iterator, TypedDict

import numpy as np

from calib_free.gaze.look import LookController
from calib_free.gaze.magnification import LearnedMagnification
from calib_free.gaze.fixation import (FixationController, FixationInterrupted, FixationOutcome,
                                 FixationRecord, HeadTimeoutError)
from calib_free.gaze.pursuit import TrackOutcome
from drivers.clock import SYSTEM_CLOCK, Backoff, Clock
from drivers.errors import DriverError
from headctl.service.head import Head
from headctl.service.events import EventHub, plain
from headctl.service.exposure import ExposureHold
from headctl.service.looks import LookJob, LookKind, LookQueue, LookState
from headctl.service.servo_io.loop import join_thread
from headctl.service.tracking import TrackFigures, Tracking

log = logging.getLogger(__name__)


class Interrupt:
    """Why the head's work in progress must stop: the service stopping (for good), or a client
    cancelling the look in progress. Called by the head before every bus access and every
    slice of waiting for frames, so a fixation stops within one servo cycle or one frame
    slice; the motion already sent is completed, no further saccade or vergence step is sent."""

    def __init__(self, stop: threading.Event) -> None:
        self.stop = stop
        self._look: LookJob | None = None

    def __call__(self) -> None:
        if self.stop.is_set():
            raise FixationInterrupted(FixationOutcome.SHUTDOWN, "the service is stopping")
        look = self._look
        if look is not None and look.cancel_requested.is_set():
            raise FixationInterrupted(FixationOutcome.CANCELLED, f"look {look.id} stopped: {look.cancel_detail}")

    @contextlib.contextmanager
    def during(self, job: LookJob) -> Iterator[None]:
        """Cancelling `job` interrupts what runs inside this block."""
        self._look = job
        try:
            yield
        finally:
            self._look = None


class HeadEvents:
    """A `headctl.service.head.HeadObserver` publishing saccade onset and end, and keeping the phase and
    the vergence steps' frame-to-command latencies for the status."""

    def __init__(self, hub: EventHub) -> None:
        self.hub = hub
        self.current_phase = "starting"
        self.vergence_latency_s: collections.deque[float] = collections.deque(maxlen=2000)

    def phase(self, phase: str) -> None:
        self.current_phase = phase

    def saccade_onset(self, pose_before: np.ndarray, goal: np.ndarray) -> None:
        self.hub.publish("saccade_onset", pose_before=pose_before, goal=goal)

    def saccade_done(self, pose: np.ndarray, goal: np.ndarray, duration_s: float) -> None:
        self.hub.publish("saccade_done", pose=pose, goal=goal, duration_s=duration_s)

    def vergence_commanded(self, frame_to_command_s: float) -> None:
        self.vergence_latency_s.append(frame_to_command_s)


# Fixations that ended on a part that failed rather than on what the eyes saw: the next
# attempt waits (`FixationThread.backoff`), since it would most likely fail the same way.
PART_FAILURES = frozenset({FixationOutcome.BUS_DOWN, FixationOutcome.SERVO_FAULT, FixationOutcome.NO_FRAMES})
BACKOFF_FIRST_S = 0.05
BACKOFF_MAX_S = 1.0  # a part that answers again is used at most this late
WAIT_SLICE_S = 0.05  # how soon a wait notices stop() (a look wakes it at once)


class FixationCounts(TypedDict):
    done: int
    taught: int
    refused: dict[str, int]  # by outcome


class FixationThread(threading.Thread):
    """Clients' looks first, else exploratory fixations (back to back or at `rate_hz`) while
    exploration is on; paused while `paused_reason()` says why."""

    def __init__(self, controller: FixationController, head: Head, interrupt: Interrupt, looks: LookQueue,
                 events: EventHub, paused_reason: Callable[[], str | None], *, explore: bool = True,
                 rate_hz: float = 0.0, clock: Clock = SYSTEM_CLOCK, tracking: Tracking | None = None,
                 exposure: ExposureHold | None = None, magnification: LearnedMagnification | None = None) -> None:
        super().__init__(name="fixation", daemon=True)
        self.controller = controller
        self.head = head
        self.interrupt = interrupt
        self.abort = interrupt.stop
        self.looks = looks
        self.events = events
        self.paused_reason = paused_reason
        self.explore = explore
        self.min_interval_s = 1.0 / rate_hz if rate_hz > 0 else 0.0
        self.clock = clock
        self.done = 0
        self.taught = 0
        self.refused: collections.Counter[str] = collections.Counter()
        self.last: FixationRecord | None = None
        self.landing_errors_px: collections.deque[float] = collections.deque(maxlen=200)  # target looks'
        self.error: BaseException | None = None
        self._lock = threading.Lock()
        # Clients' target looks, closed-loop; each of their fixations counted and told as it ends.
        # The lens's magnification they learn outlives this thread (the daemon's, kept on disk).
        self.looker = LookController(controller, on_fixation=self._count, magnification=magnification)
        # Smooth pursuit (`headctl.service.tracking`); without it, a track fails saying so.
        self.tracking = tracking
        self.backoff = Backoff(BACKOFF_FIRST_S, BACKOFF_MAX_S)
        self.exposure = exposure if exposure is not None else ExposureHold()

    def stop(self, timeout_s: float = 2.0) -> None:
        self.abort.set()
        join_thread(self, timeout_s)

    def carry_over(self, old: "FixationThread") -> None:
        """Take the counts of `old`, the thread this one replaces (not started yet)."""
        with old._lock:
            self.done, self.taught, self.refused, self.last = old.done, old.taught, old.refused.copy(), old.last
        self.landing_errors_px.extend(old.landing_errors_px)

    def tracking_status(self) -> TrackFigures | None:
        """The running track's figures (the patch's position, errors, latency), or None."""
        return self.tracking.status() if self.tracking is not None else None

    def counts(self) -> FixationCounts:
        with self._lock:
            return {"done": self.done, "taught": self.taught, "refused": dict(self.refused)}

    def run(self) -> None:
        next_explore_s = 0.0
        try:
            while not self.abort.is_set():
                job = self.looks.take()
                if job is not None:
                    self._look(job)
                    continue
                paused = self.paused_reason()
                now = self.clock.monotonic()
                if paused is not None or not self.explore or now < next_explore_s:
                    self.head.set_phase(f"paused ({paused})" if paused else
                                        "idle" if self.explore else "idle (exploration off)")
                    wait_s = 0.05 if paused or self.explore else 0.2
                    if self.explore and not paused:
                        wait_s = min(wait_s, next_explore_s - now)
                    self.looks.wait_for_work(max(wait_s, 0.001))  # a look wakes it at once
                    continue
                record = self._fixate(None)
                next_explore_s = now + self.min_interval_s
                if record.outcome in PART_FAILURES:
                    self._wait(self.backoff.failed())
                else:
                    self.backoff.reset()
        except Exception as err:  # reported through the status, never lost
            self.error = err
            log.exception("%s: the fixation controller failed", self.name)
        finally:
            self.head.set_phase("stopped")
            self.looks.cancel_all("the fixation controller stopped")

    def _wait(self, wait_s: float) -> None:
        """Wait `wait_s` before the next exploratory fixation; a look or stop() ends it sooner."""
        deadline_s = self.clock.monotonic() + wait_s
        while not self.abort.is_set():
            remaining_s = deadline_s - self.clock.monotonic()
            if remaining_s <= 0 or self.looks.wait_for_work(min(remaining_s, WAIT_SLICE_S)):
                return

    def _fixate(self, target: np.ndarray | None, reference_pose: np.ndarray | None = None) -> FixationRecord:
        """One fixation, taught or refused (an interrupted one is refused with the reason)."""
        self.head.set_phase("choosing target")
        try:
            with self.exposure.held():
                record = self.controller.fixate(target, reference_pose)
        finally:
            self.head.set_phase("idle")
        if record.outcome is FixationOutcome.SERVO_FAULT:
            log.warning("fixation aborted: %s", record.detail)
        elif record.outcome in (FixationOutcome.BUS_DOWN, FixationOutcome.CANCELLED):
            log.info("fixation aborted: %s", record.detail)
        self._count(record)
        return record

    def _look(self, job: LookJob) -> None:
        request = job.request
        if request.kind is LookKind.TRACK:
            self._track(job)
            return
        self.events.publish("look_started", id=job.id, **request.as_dict())
        paused = self.paused_reason()
        try:
            if paused is not None:
                self.looks.finish(job, LookState.FAILED, paused, f"cannot look: {paused}")
            else:
                with self.interrupt.during(job):
                    if request.kind is LookKind.TARGET:
                        self._look_at_target(job)
                    else:
                        self._look_at_angles(job)
        except BaseException as err:  # a client waiting on it hears of it before the thread reports it
            if not job.done.is_set():
                self.looks.finish(job, LookState.FAILED, "internal error", repr(err))
            raise
        finally:
            self.events.publish("look_done", id=job.id, state=job.state, outcome=job.outcome, detail=job.detail)

    def _look_at_target(self, job: LookJob) -> None:
        """A closed-loop look (`calib_free.gaze.look`): `done` only with the target within the
        tolerance of the left fovea; every figure of the result from an accepted measurement."""
        target = np.asarray(job.request.values, dtype=float)
        reference = job.request.reference_pose
        self.head.set_phase("look at target")
        try:
            with self.exposure.held():  # one exposure for the look: its fixations find its first image's target
                look = self.looker.look(target, None if reference is None else np.asarray(reference),
                                         depth_known=job.request.depth_known)
        finally:
            self.head.set_phase("idle")
        fixations = look.fixations
        first, last = (fixations[0], fixations[-1]) if fixations else (None, None)
        sighting = look.sightings[-1] if look.sightings and len(look.sightings) == len(fixations) else None
        accepted = first is not None and first.taught  # its correspondence (position, confidence) was accepted
        result: dict[str, object] = {
            "on_target": look.on_target, "final_error_px": look.final_error_px,
            "tolerance_px": self.looker.params.tolerance_px, "corrective_steps": look.corrective_steps,
            "attempts": look.attempts,
            "landing_error_px": look.landing_error_px,
            "target_px": None if sighting is None else [sighting.x, sighting.y],
            "target_ncc": None if sighting is None else sighting.ncc,
            "converged": last is not None and last.converged, "taught": sum(f.taught for f in fixations),
            "vergence_steps": sum(f.vergence_steps for f in fixations), "duration_s": look.duration_s,
            "pose_before": None if first is None else first.pose_before,
            "pose_after": None if last is None else last.pose_after,
            "planned": None if first is None else first.planned,
            "position": first.position if accepted and first is not None else None,
            "confidence": first.confidence if accepted and first is not None else None,
            "head_moved_deg": look.view_restored_deg,
            "fixations": [{"outcome": str(f.outcome), "detail": f.detail, "converged": f.converged,
                           "taught": f.taught, "vergence_steps": f.vergence_steps} for f in fixations]}
        if look.landing_error_px is not None:
            self.landing_errors_px.append(look.landing_error_px)
        if look.outcome is FixationOutcome.CANCELLED:
            self.looks.finish(job, LookState.CANCELLED, job.cancel_outcome, job.cancel_detail, plain(result))
        else:
            self.looks.finish(job, LookState.DONE if look.on_target else LookState.FAILED, str(look.outcome),
                              look.detail, plain(result))

    def _track(self, job: LookJob) -> None:
        """Pursue the target until the track is stopped, lost or preempted (any look or track
        queued meanwhile); the job ends `done` when a client stopped it, else `failed`."""
        tracking = self.tracking
        paused = self.paused_reason()
        try:
            if tracking is None or paused is not None:
                why = paused or "tracking is not set up"
                self.looks.finish(job, LookState.FAILED, "cannot track", why)
                self.events.publish("track_stopped", id=job.id, outcome="cannot track", detail=why)
                return
            x, y, _ = job.request.values
            with self.interrupt.during(job):
                end = tracking.run(job.id, (x, y), lambda: self.looks.pending() > 0)
        except BaseException as err:
            if not job.done.is_set():
                self.looks.finish(job, LookState.FAILED, "internal error", repr(err))
            raise
        result = plain({"stats": end.stats.as_dict()})
        if end.outcome is TrackOutcome.STOPPED and job.cancel_outcome != "replaced":
            self.looks.finish(job, LookState.DONE, "stopped", job.cancel_detail or end.detail, result)
        elif end.outcome in (TrackOutcome.STOPPED, TrackOutcome.PREEMPTED):
            self.looks.finish(job, LookState.CANCELLED, "preempted", job.cancel_detail or end.detail, result)
        else:
            self.looks.finish(job, LookState.FAILED, str(end.outcome), end.detail, result)

    def _look_at_angles(self, job: LookJob) -> None:
        request = job.request
        self.head.set_phase("look at angles")
        try:
            before = self.head.read_pose()
            goal = request.angles_goal(before, self.head.pose_low, self.head.pose_high)
            outside = [f"{name} {value:.2f} outside [{lo:g}, {hi:g}]" for name, value, lo, hi in
                       zip(("pan", "tilt", "vergence"), goal, self.head.pose_low, self.head.pose_high)
                       if not lo - 1e-9 <= value <= hi + 1e-9]
            if outside:  # never clamped silently: the client asked for somewhere the head cannot go
                self.looks.finish(job, LookState.FAILED, "outside the joint limits", "; ".join(outside))
                return
            self.head.move_to(goal)
            self.head.wait_settled(self.controller.params.settle_timeout_s)
            after = self.head.read_pose()
        except FixationInterrupted as err:
            if err.outcome is FixationOutcome.CANCELLED:
                self.looks.finish(job, LookState.CANCELLED, job.cancel_outcome, job.cancel_detail)
            else:
                self.looks.finish(job, LookState.FAILED, str(err.outcome), str(err))
            return
        except (DriverError, HeadTimeoutError) as err:
            self.looks.finish(job, LookState.FAILED, type(err).__name__, str(err))
            return
        finally:
            self.head.set_phase("idle")
        self.looks.finish(job, LookState.DONE, "reached", "", plain({"pose_before": before, "pose_after": after,
                                                                       "goal": goal}))

    def _count(self, record: FixationRecord) -> None:
        with self._lock:
            self.done += 1
            if record.taught:
                self.taught += 1
            else:
                self.refused[str(record.outcome)] += 1
            self.last = record
        # One event a fixation: converged (taught, or refused after converging: the outcome
        # says why), or refused before converging.
        kind = str(record.kind)
        if record.converged:
            self.events.publish("fixation_converged", index=record.index, kind=kind, taught=record.taught,
                                outcome=str(record.outcome), detail=record.detail, confidence=record.confidence,
                                position=record.position)
        else:
            self.events.publish("fixation_refused", index=record.index, kind=kind, reason=str(record.outcome),
                                detail=record.detail)

