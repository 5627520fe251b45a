"""Each fixation's inputs as the controller saw them, for whoever records them (a bag to replay).

`TracingController` is the service's `FixationController`: while someone subscribes to its
`FixationTaps` (a recording), every `fixate()` is traced through `TracingHead`, which stands
between the controller and the `Head` and notes, in order, what each `GazeHead` call returned:
the times the head came to rest, the stereo pairs (copied, with their exposure time), the poses
read, the goals of the saccade and of each vergence step, and the error that ended the
fixation early (a timeout, a bus fault). With the `FixationRecord` that is a `FixationTrace`:
everything needed to run the same fixation again on a head that answers from the trace
(`headctl.experiments.relearn`). Without subscribers nothing is traced or copied.
Subscribers are called on the fixation thread and must not block (append to a queue).
"""
from __future__ import annotations

import dataclasses
import enum
import logging
import threading
from typing import Callable, TypeAlias, TypeVar

import numpy as np

from calib_free.gaze.exploration import ExplorationPolicy
from calib_free.gaze.fixation import (FixationController, FixationInterrupted, FixationOutcome, FixationParams,
                                      FixationRecord, HeadTimeoutError, MapReader, PairTimeoutError, SampleSink)
from calib_free.map.gaze_map import Vector
from headctl.service.head import Head

T = TypeVar("T")

log = logging.getLogger(__name__)


class Call(enum.StrEnum):
    """The `GazeHead` calls a trace notes (the values are what a recorded trace names them)."""

    SETTLED = "settled"  # wait_settled: the monotonic time from which the head was at rest
    PAIR = "pair"  # wait_pair: an index into the trace's pairs
    POSE = "pose"  # read_pose: (pan, tilt, vergence)
    MOVE = "move"  # move_to: the goal commanded, as clamped
    VERGE = "verge"  # verge_to: the vergence commanded, as clamped
    RAISE = "raise"  # the call raised: `Raised`


@dataclasses.dataclass(frozen=True)
class Raised:
    """A head call that raised: which call, the exception's class name, its outcome (for a
    `FixationInterrupted`) and its message."""

    call: Call
    error: str  # "HeadTimeoutError", "PairTimeoutError" or "FixationInterrupted"
    outcome: str
    detail: str

    def exception(self) -> Exception:
        """The exception again, as the head raised it."""
        if self.error == "FixationInterrupted":
            return FixationInterrupted(FixationOutcome(self.outcome), self.detail)
        return PairTimeoutError(self.detail) if self.error == "PairTimeoutError" else HeadTimeoutError(self.detail)


CallValue: TypeAlias = float | int | np.ndarray | Raised


@dataclasses.dataclass(frozen=True)
class StereoShot:
    """A pair the fixation used, as the cameras gave it, and when it was exposed (monotonic s)."""

    left: np.ndarray
    right: np.ndarray
    exposure_s: float | None


@dataclasses.dataclass
class FixationTrace:
    """One fixation's record and the head calls it made, in order."""

    record: FixationRecord
    calls: list[tuple[Call, CallValue]]
    pairs: list[StereoShot]
    pose_low: np.ndarray
    pose_high: np.ndarray


TraceSubscriber = Callable[[FixationTrace], None]


class FixationTaps:
    """The subscribers to fixation traces (callbacks that must not block)."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._subscribers: list[TraceSubscriber] = []

    @property
    def active(self) -> bool:
        with self._lock:
            return bool(self._subscribers)

    def subscribe(self, deliver: TraceSubscriber) -> Callable[[], None]:
        """Call `deliver(trace)` after every fixation from now on; returns the unsubscribe function."""
        with self._lock:
            self._subscribers.append(deliver)

        def unsubscribe() -> None:
            with self._lock:
                if deliver in self._subscribers:
                    self._subscribers.remove(deliver)
        return unsubscribe

    def deliver(self, trace: FixationTrace) -> None:
        with self._lock:
            subscribers = list(self._subscribers)
        for deliver in subscribers:
            try:
                deliver(trace)
            except Exception:  # a broken subscriber must not stop the fixation thread
                log.exception("fixation trace subscriber failed")


class TracingHead:
    """A `GazeHead` over `head` that notes each call's answer while a trace is open."""

    def __init__(self, head: Head) -> None:
        self.head = head
        self.pose_low, self.pose_high = head.pose_low, head.pose_high  # fixed when the head is built
        self.calls: list[tuple[Call, CallValue]] | None = None  # None: not tracing
        self.pairs: list[StereoShot] = []

    def begin(self) -> None:
        self.calls, self.pairs = [], []

    def end(self) -> tuple[list[tuple[Call, CallValue]], list[StereoShot]] | None:
        calls, pairs = self.calls, self.pairs
        self.calls, self.pairs = None, []
        return None if calls is None else (calls, pairs)

    def _note(self, call: Call, value: CallValue) -> None:
        if self.calls is not None:
            self.calls.append((call, value))

    def _traced(self, call: Call, fn: Callable[[], T]) -> T:
        try:
            return fn()
        except (HeadTimeoutError, FixationInterrupted) as err:
            outcome = str(err.outcome) if isinstance(err, FixationInterrupted) else ""
            self._note(Call.RAISE, Raised(call, type(err).__name__, outcome, str(err)))
            raise

    def read_pose(self) -> np.ndarray:
        pose = np.asarray(self._traced(Call.POSE, self.head.read_pose), dtype=float)
        self._note(Call.POSE, pose.copy())
        return pose

    def move_to(self, pose: np.ndarray) -> np.ndarray:
        goal = np.asarray(self._traced(Call.MOVE, lambda: self.head.move_to(pose)), dtype=float)
        self._note(Call.MOVE, goal.copy())
        return goal

    def verge_to(self, vergence: float) -> float:
        v = float(self._traced(Call.VERGE, lambda: self.head.verge_to(vergence)))
        self._note(Call.VERGE, v)
        return v

    def wait_settled(self, timeout_s: float, same_rest: bool = False) -> float:
        rest_s = float(self._traced(Call.SETTLED, lambda: self.head.wait_settled(timeout_s, same_rest)))
        self._note(Call.SETTLED, rest_s)
        return rest_s

    def wait_pair(self, after_s: float, timeout_s: float) -> tuple[np.ndarray, np.ndarray]:
        left, right = self._traced(Call.PAIR, lambda: self.head.wait_pair(after_s, timeout_s))
        if self.calls is not None:
            self.pairs.append(StereoShot(np.array(left, copy=True), np.array(right, copy=True),
                                         self.head.pairs.last_exposure_s))
            self._note(Call.PAIR, len(self.pairs) - 1)
        return left, right


class TracingController(FixationController):
    """The service's fixation controller: `FixationController` over a `TracingHead`, each
    fixation traced and given to `taps` while they have subscribers."""

    head: TracingHead

    def __init__(self, head: Head, gaze_map: MapReader, taps: FixationTaps, params: FixationParams | None = None,
                 *, seed: int | None = None, clock: Callable[[], float], learner: SampleSink | None = None,
                 exploration: ExplorationPolicy | None = None) -> None:
        super().__init__(TracingHead(head), gaze_map, params, seed=seed, clock=clock, learner=learner,
                         exploration=exploration)
        self.taps = taps

    def fixate(self, target: Vector | None = None, reference_pose: Vector | None = None,
               continues: bool = False, target_check: Callable[[np.ndarray], str] | None = None) -> FixationRecord:
        tracing = self.taps.active
        if tracing:
            self.head.begin()
        try:
            record = super().fixate(target, reference_pose, continues, target_check)
        finally:
            traced = self.head.end()
        if tracing and traced is not None:
            calls, pairs = traced
            self.taps.deliver(FixationTrace(record, calls, pairs, self.head.pose_low.copy(),
                                            self.head.pose_high.copy()))
        return record
