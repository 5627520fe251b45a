"""Clients' gaze requests ("looks"): what they ask, the jobs that carry them out, their queue.

- `LookRequest`: look at an image target (x, y, d px in the left image), or at joint angles
  (pan, tilt, vergence deg; absolute or relative to the pose when the look starts).
- `LookJob`: a request queued, taken by the fixation thread between two fixations, and ending
  `done`, `failed` (the outcome and detail say why) or `cancelled` (`LookState`). `done` is a
  `threading.Event` to wait on; a running look is cancelled by request (`cancel_requested`):
  the fixation thread stops it at its next bus access or frame wait.
- `LookQueue`: the bounded queue of jobs and the record of the last finished ones.
"""
from __future__ import annotations

import collections
import enum
import itertools
import logging
import threading
import time
from dataclasses import dataclass, field
from typing import Callable, TypedDict

import numpy as np

from headctl.errors import ControlError, NotFoundError, QueueFullError
from headctl.json_types import JSONObject

log = logging.getLogger(__name__)


class LookKind(enum.StrEnum):
    TARGET = "target"  # an image target (x, y, d)
    ANGLES = "angles"  # joint angles (pan, tilt, vergence)
    TRACK = "track"  # pursue the patch at an image target (x, y; d measured) until stopped or lost


class LookState(enum.StrEnum):
    QUEUED = "queued"
    RUNNING = "running"
    DONE = "done"
    FAILED = "failed"
    CANCELLED = "cancelled"

    @property
    def finished(self) -> bool:
        return self in (LookState.DONE, LookState.FAILED, LookState.CANCELLED)


@dataclass(frozen=True)
class LookRequest:
    """Look at an image target (`kind` "target": x, y, d px in the left image) or at joint
    angles (`kind` "angles": pan, tilt, vergence deg, absolute or `relative` to the pose when
    the look starts)."""

    kind: LookKind
    values: tuple[float, float, float]
    relative: bool = False
    # A target's: the pose whose view it was chosen in (the head's when it was queued).
    reference_pose: tuple[float, float, float] | None = None
    # A target sent without d: the NCC of the match that measured it (Daemon.measure_disparity),
    # or None and why d could not be measured (the look then starts at the fixation's depth, d 0).
    d_ncc: float | None = None
    d_reason: str = ""

    @property
    def depth_known(self) -> bool:
        """d is the target's: given, or measured (not the fixation's depth in its stead)."""
        return not self.d_reason

    def angles_goal(self, pose: np.ndarray, low: np.ndarray, high: np.ndarray) -> np.ndarray:
        """An angles look's goal: its values, or, `relative`, its values added to `pose` (the
        pose read) clamped to the limits `low`, `high`. A reading can lie a little beyond them
        (the gears' play and the tilt's sag carry the shaft past a goal at the limit; the
        encoder wobbles by a tick), and a relative look that leaves an axis as it is must not
        be refused for where the reading, not the goal, lies. The goal itself is not clamped."""
        values: np.ndarray = np.asarray(self.values, dtype=float)
        if not self.relative:
            return values
        goal: np.ndarray = np.clip(np.asarray(pose, dtype=float), low, high) + values
        return goal

    def as_dict(self) -> dict[str, object]:
        names = ("pan", "tilt", "vergence") if self.kind is LookKind.ANGLES else ("x", "y", "d")
        out: dict[str, object] = {"kind": self.kind, **dict(zip(names, self.values))}
        if self.kind is LookKind.TRACK:
            out.pop("d")  # measured where the patch is taken
        elif self.kind is LookKind.ANGLES:
            out["relative"] = self.relative
        else:
            if self.reference_pose is not None:
                out["reference_pose"] = list(self.reference_pose)
            out["d_measured"] = self.d_ncc is not None
            if self.d_ncc is not None:
                out["d_ncc"] = round(self.d_ncc, 3)
            if self.d_reason:
                out["d_reason"] = self.d_reason
        return out


class LookAnswer(TypedDict):
    """A look as the API answers it (`LookJob.as_dict`, made `plain` there)."""

    id: int
    request: dict[str, object]  # `LookRequest.as_dict`
    state: LookState
    outcome: str
    detail: str
    result: JSONObject
    created: float
    started: float | None
    finished: float | None
    cancel_requested: bool


@dataclass
class LookJob:
    id: int
    request: LookRequest
    state: LookState = LookState.QUEUED
    outcome: str = ""  # the fixation's outcome ("taught" or why it did not teach), or why it failed
    detail: str = ""
    result: JSONObject = field(default_factory=dict)  # the look's figures, made `plain`
    created_s: float = field(default_factory=time.time)
    started_s: float | None = None
    finished_s: float | None = None
    done: threading.Event = field(default_factory=threading.Event, repr=False)
    # Set to stop a running look; the fixation thread finishes it `cancelled` with this outcome.
    cancel_requested: threading.Event = field(default_factory=threading.Event, repr=False)
    cancel_outcome: str = ""
    cancel_detail: str = ""
    _callbacks: list[Callable[["LookJob"], None]] = field(default_factory=list, repr=False)
    _lock: threading.Lock = field(default_factory=threading.Lock, repr=False)

    def add_done_callback(self, fn: Callable[["LookJob"], None]) -> None:
        """Call `fn(job)` when the job finishes (at once if it has); from the finishing thread."""
        with self._lock:
            if not self.done.is_set():
                self._callbacks.append(fn)
                return
        fn(self)

    def _set_done(self) -> None:
        with self._lock:
            self.done.set()
            callbacks, self._callbacks = self._callbacks, []
        for fn in callbacks:
            try:
                fn(self)
            except Exception:  # a client's callback must not break the fixation thread
                log.exception("look %d: a done callback failed", self.id)

    def request_cancel(self, outcome: str, detail: str) -> None:
        if not self.cancel_requested.is_set():
            self.cancel_outcome, self.cancel_detail = outcome, detail
            self.cancel_requested.set()

    def as_dict(self) -> LookAnswer:
        return {"id": self.id, "request": self.request.as_dict(), "state": self.state, "outcome": self.outcome,
                "detail": self.detail, "result": self.result, "created": self.created_s,
                "started": self.started_s, "finished": self.finished_s,
                "cancel_requested": self.cancel_requested.is_set()}


class LookQueue:
    """Looks waiting for the fixation thread (at most `size`), and the last finished ones."""

    def __init__(self, size: int = 16, keep_finished: int = 256) -> None:
        self.size = size
        self._cond = threading.Condition()
        self._queued: collections.deque[LookJob] = collections.deque()
        self._running: LookJob | None = None
        self._jobs: collections.OrderedDict[int, LookJob] = collections.OrderedDict()
        self._keep = keep_finished
        self._ids = itertools.count(1)

    def submit(self, request: LookRequest, replace: bool = False) -> LookJob:
        """Queue a look; with `replace`, the looks still queued are cancelled and the running one
        is stopped first (a tracker's newest target wins). QueueFullError when `size` are waiting."""
        with self._cond:
            if replace:
                while self._queued:
                    self._finish_locked(self._queued.popleft(), LookState.CANCELLED, "replaced", "a newer look replaced it")
                if self._running is not None:
                    self._running.request_cancel("replaced", "a newer look replaced it")
            if len(self._queued) >= self.size:
                raise QueueFullError(f"{len(self._queued)} looks already queued (the limit, api.max_queued_looks); "
                                     "wait for one, or send replace: true")
            job = LookJob(next(self._ids), request)
            self._queued.append(job)
            self._jobs[job.id] = job
            self._trim_locked()
            self._cond.notify_all()
            return job

    def take(self, timeout_s: float = 0.0) -> LookJob | None:
        """The oldest queued look, now running; None if none came within `timeout_s`."""
        with self._cond:
            if not self._queued and timeout_s > 0:
                self._cond.wait(timeout_s)
            if not self._queued:
                return None
            job = self._queued.popleft()
            job.state, job.started_s = LookState.RUNNING, time.time()
            self._running = job
            return job

    def wait_for_work(self, timeout_s: float) -> bool:
        """Block until a look is queued (True) or `timeout_s` passed (False)."""
        with self._cond:
            return bool(self._queued) or self._cond.wait_for(lambda: bool(self._queued), timeout_s)

    def finish(self, job: LookJob, state: LookState, outcome: str, detail: str = "",
               result: JSONObject | None = None) -> None:
        with self._cond:
            self._finish_locked(job, state, outcome, detail, result)

    def cancel(self, job_id: int) -> LookJob:
        """A queued look ends `cancelled` at once; a running one is asked to stop (it ends
        `cancelled` once the fixation thread has stopped it: wait on `done`)."""
        with self._cond:
            job = self.get(job_id)
            if job.state is LookState.RUNNING:
                job.request_cancel("cancelled", "cancelled by a client")
                return job
            if job.state is not LookState.QUEUED:
                raise ControlError(f"look {job_id} is {job.state} already: there is nothing to cancel", "id")
            self._queued.remove(job)
            self._finish_locked(job, LookState.CANCELLED, "cancelled", "cancelled by a client")
            return job

    def cancel_all(self, reason: str) -> None:
        with self._cond:
            while self._queued:
                self._finish_locked(self._queued.popleft(), LookState.CANCELLED, "cancelled", reason)

    def get(self, job_id: int) -> LookJob:
        with self._cond:
            job = self._jobs.get(job_id)
        if job is None:
            raise NotFoundError(f"no look with id {job_id} (the last {self._keep} are kept)", "id")
        return job

    def pending(self) -> int:
        with self._cond:
            return len(self._queued)

    def _finish_locked(self, job: LookJob, state: LookState, outcome: str, detail: str = "",
                       result: JSONObject | None = None) -> None:
        job.state, job.outcome, job.detail = state, outcome, detail
        job.result = result or {}
        job.finished_s = time.time()
        if self._running is job:
            self._running = None
        job._set_done()

    def _trim_locked(self) -> None:
        while len(self._jobs) > self._keep + self.size:
            oldest_id, oldest = next(iter(self._jobs.items()))
            if not oldest.state.finished:
                break
            del self._jobs[oldest_id]
