"""Tracking: smooth pursuit of a client's target, run on the fixation thread (one owner of motion).

A track is a job of the look queue (`LookKind.TRACK`), taken by the fixation thread like a
look; `Tracking.run` then follows the target's patch (`calib_free.gaze.pursuit`) one stereo pair
after another until a client stops it, the patch is lost (`lost_after_frames` pairs in a
row), no new pair comes for `frame_timeout_s`, the head faults, or a look or another track is
queued (preempted). Exploration waits meanwhile: the fixation thread is busy.

Each pair is judged from the pose at its exposure time, interpolated in a short history of
the servo loop's states (`ServoPoses`, a named thread reading every state while the track
runs), and each command goes to the bus as a goal within the joint limits. Frames come through
the `Head` (interruptible: a cancelled track stops within one frame slice). Events:
`track_started`, `track_lost`, `track_stopped` (every track ends with one of the last two).
"""
from __future__ import annotations

import collections
import logging
import threading
import time
from dataclasses import dataclass, field
from typing import Callable, Mapping, Protocol, TypedDict

import numpy as np

from calib_free.gaze.fixation import FixationInterrupted, FixationOutcome, HeadTimeoutError
from calib_free.gaze.pursuit import MapReader, PoseHistory, Pursuit, PursuitParams, PursuitStep, TrackOutcome
from drivers.clock import SYSTEM_CLOCK, Backoff, Clock
from drivers.errors import DriverError
from headctl.errors import ServoLoopStoppedError
from headctl.service.head import Head, JointBus, PairTimes
from headctl.service.servo_io.loop import join_thread

log = logging.getLogger(__name__)

class Publish(Protocol):
    """Tells an event (`EventHub.publish`)."""

    def __call__(self, type_: str, **fields: object) -> object: ...


class ExposurePoses(Protocol):
    """The head's pose at a past time (a frame's exposure); a context manager that records
    while the track runs."""

    def __enter__(self) -> "ExposurePoses": ...

    def __exit__(self, *exc: object) -> None: ...

    def at(self, time_s: float) -> np.ndarray | None: ...


class ServoPoses(threading.Thread):
    """`ExposurePoses` from the servo loop: the thread `pose-history` reads every state the loop
    publishes (`read_state`: the first one after the call) into a `PoseHistory`."""

    def __init__(self, bus: JointBus, pose_from: Callable[[Mapping[str, float]], np.ndarray], size: int = 256) -> None:
        super().__init__(name="pose-history", daemon=True)
        self.bus = bus
        self.pose_from = pose_from
        self.history = PoseHistory(size)
        self._stop_event = threading.Event()

    def run(self) -> None:
        backoff = Backoff(0.01, 0.25)
        while not self._stop_event.is_set():
            try:
                state = self.bus.read_state()
            except (DriverError, ServoLoopStoppedError, TimeoutError):
                # The bus down or the loop gone: no pose, so no command (at() gives None).
                self._stop_event.wait(backoff.failed())
                continue
            backoff.reset()
            self.history.add(state.time_s, self.pose_from(state.positions))

    def at(self, time_s: float, wait_s: float = 0.03) -> np.ndarray | None:
        """The pose at `time_s`, once a state read after it has come (up to `wait_s`: three
        servo cycles), so that it is interpolated, not the last one before it held."""
        deadline = time.monotonic() + wait_s
        while self.history.newest_s() < time_s and time.monotonic() < deadline and self.is_alive():
            self._stop_event.wait(0.002)
        return self.history.at(time_s)

    def stop(self, timeout_s: float = 1.0) -> None:
        self._stop_event.set()
        if self.is_alive():
            join_thread(self, timeout_s)

    def __enter__(self) -> "ServoPoses":
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()


class ErrorFigures(TypedDict):
    rms: float | None
    p95: float | None
    last: float | None


class LatencyFigures(TypedDict):
    p50: float | None
    p95: float | None
    count: int


class SkewFigures(TypedDict):
    """The pairs' skew (right minus left timestamp), ms: unsynchronised cameras."""

    mean: float | None
    max_abs: float | None


class TrackFigures(TypedDict):
    """A track's figures as the API and the events show them (`TrackStats.as_dict`)."""

    frames: int
    found: int
    misses: int
    refreshes: int
    no_pose: int
    retinal_error_px: ErrorFigures
    frame_to_command_ms: LatencyFigures
    pair_skew_ms: SkewFigures
    position: list[float] | None  # (x, y, d) of the last match in the left image
    ncc: float | None
    patch_size_px: int


@dataclass
class TrackStats:
    """A track's figures so far (read by the API while it runs)."""

    frames: int = 0
    found: int = 0
    misses: int = 0
    refreshes: int = 0
    no_pose: int = 0  # pairs skipped: the pose at their exposure was not known
    retinal_error_px: collections.deque[float] = field(default_factory=lambda: collections.deque(maxlen=3000))
    frame_to_command_s: collections.deque[float] = field(default_factory=lambda: collections.deque(maxlen=3000))
    skew_s: collections.deque[float] = field(default_factory=lambda: collections.deque(maxlen=3000))  # right - left
    last_match: tuple[float, float, float] | None = None  # (x, y, d) in the left image
    last_ncc: float | None = None
    patch_size_px: int = 0

    def as_dict(self) -> TrackFigures:
        errors = np.asarray(self.retinal_error_px, dtype=float)
        latency = np.asarray(self.frame_to_command_s, dtype=float) * 1e3
        skew = np.asarray(self.skew_s, dtype=float) * 1e3

        def q(values: np.ndarray, p: float) -> float | None:
            return float(np.percentile(values, p)) if len(values) else None

        return {"frames": self.frames, "found": self.found, "misses": self.misses, "refreshes": self.refreshes,
                "no_pose": self.no_pose,
                "retinal_error_px": {"rms": float(np.sqrt(np.mean(errors ** 2))) if len(errors) else None,
                                     "p95": q(errors, 95), "last": float(errors[-1]) if len(errors) else None},
                "frame_to_command_ms": {"p50": q(latency, 50), "p95": q(latency, 95), "count": len(latency)},
                "pair_skew_ms": {"mean": float(skew.mean()) if len(skew) else None,
                                 "max_abs": float(np.abs(skew).max()) if len(skew) else None},
                "position": list(self.last_match) if self.last_match is not None else None,
                "ncc": self.last_ncc, "patch_size_px": self.patch_size_px}


@dataclass
class TrackEnd:
    outcome: TrackOutcome
    detail: str
    stats: TrackStats


class Tracking:
    """Runs tracks on a head (see the module docstring). `poses()` makes the pose source of one
    track (default: `ServoPoses` over the head's bus); `publish` tells events."""

    def __init__(self, head: Head, gaze_map: MapReader, disparity_range: tuple[float, float],
                 params: PursuitParams | None = None, *, frame_period_s: float = 1 / 30,
                 publish: Publish | None = None, poses: Callable[[], ExposurePoses] | None = None,
                 clock: Clock = SYSTEM_CLOCK) -> None:
        self.head = head
        self.map = gaze_map
        self.disparity_range = disparity_range
        self.params = params or PursuitParams()
        self.frame_period_s = frame_period_s
        self.publish = publish
        self.poses = poses or (lambda: ServoPoses(head.bus, head.pose_from))
        self.clock = clock
        self.current: TrackStats | None = None  # the running track's, for the API and the eyes' images
        self.latency_s: collections.deque[float] = collections.deque(maxlen=2000)  # of every track

    def _tell(self, type_: str, **fields: object) -> None:
        if self.publish is not None:
            self.publish(type_, **fields)

    def _command(self, goal: np.ndarray) -> None:
        """The goal within the joint and vergence limits, on the bus (interruptible), less the
        droop and with the play taken up (`Head.follow_to`)."""
        self.head.follow_to(goal)

    def _pair(self, after_s: float) -> tuple[np.ndarray, np.ndarray, float, float]:
        """The first pair exposed after `after_s`: its images, the left image's exposure time,
        and the right's timestamp minus the left's (0 from a source that does not tell both)."""
        left, right = self.head.wait_pair(after_s, self.params.frame_timeout_s)
        pairs = self.head.pairs
        times = pairs.last_pair_times_s if isinstance(pairs, PairTimes) else None
        if times is not None:
            return left, right, times[0], times[1] - times[0]
        exposure_s = pairs.last_exposure_s
        return left, right, self.clock.monotonic() if exposure_s is None else exposure_s, 0.0

    def run(self, track_id: int, target: tuple[float, float] | None, preempted: Callable[[], bool],
            on_step: Callable[[PursuitStep], None] | None = None) -> TrackEnd:
        """Follow the patch at `target` (x, y px in the left image; None: the fovea) until the
        track ends; returns how. Raises nothing the head raises but `FixationInterrupted` for
        the service stopping or the track cancelled (the caller knows which)."""
        stats = TrackStats(patch_size_px=self.params.patch_size_px)
        self.current = stats
        self.head.set_phase("tracking")
        try:
            with self.poses() as poses:
                return self._follow(track_id, target, preempted, stats, poses, on_step)
        finally:
            self.current = None
            self.head.set_phase("idle")

    def _follow(self, track_id: int, target: tuple[float, float] | None, preempted: Callable[[], bool],
                stats: TrackStats, poses: ExposurePoses, on_step: Callable[[PursuitStep], None] | None) -> TrackEnd:
        p = self.params
        period = self.frame_period_s
        try:
            left, right, exposure_s, lag_s = self._pair(self.clock.monotonic())
            pose = self._pose_at(poses, exposure_s)
            height, width = left.shape[:2]
            x, y = target if target is not None else ((width - 1) / 2.0, (height - 1) / 2.0)
            pursuit = Pursuit(self.map, (width, height), self.disparity_range, p)
            step = None if pose is None else pursuit.start(left, right, exposure_s, pose, x, y, right_lag_s=lag_s,
                                                           right_pose=self._right_pose(poses, exposure_s, lag_s, pose))
            if step is None:
                why = ("no servo state around the frame's exposure" if pose is None else
                       f"no patch to follow at ({x:.1f}, {y:.1f}): too near the border, no texture there, or "
                       "no match in the right image")
                return self._ended(track_id, TrackOutcome.NOT_FOUND, why, stats)
            assert step.match is not None and step.goal is not None
            self._tell("track_started", id=track_id, x=x, y=y, d=step.match.d)
            self._record(stats, step, pursuit)
            self._command(step.goal)
            while True:
                if preempted():
                    return self._ended(track_id, TrackOutcome.PREEMPTED, "a look or a newer track was queued", stats)
                # The newest pair: the first exposed after the last one, or within the last
                # period (and the pair's own skew: unsynchronised cameras).
                now = self.clock.monotonic()
                first_s = exposure_s + min(0.0, lag_s)  # the last pair's earlier exposure
                after_s = max(first_s + 0.5 * period, now - 0.9 * period - abs(lag_s))
                left, right, exposure_s, lag_s = self._pair(after_s)
                stats.frames += 1
                pose = self._pose_at(poses, exposure_s)
                if pose is None:  # the servo loop's states stopped: no command on a stale pose
                    stats.no_pose += 1
                    continue
                stats.skew_s.append(lag_s)
                step = pursuit.step(left, right, exposure_s, pose, self.clock.monotonic(), right_lag_s=lag_s,
                                    right_pose=self._right_pose(poses, exposure_s, lag_s, pose))
                if on_step is not None:
                    on_step(step)
                if step.lost:
                    stats.misses += 1
                    detail = f"the patch was not found in {step.misses} pairs in a row"
                    self._tell("track_lost", id=track_id, detail=detail, stats=stats.as_dict())
                    return TrackEnd(TrackOutcome.LOST, detail, stats)
                if step.goal is None:
                    stats.misses += 1
                    continue
                self._record(stats, step, pursuit)
                self._command(step.goal)
                latency = self.clock.monotonic() - exposure_s
                stats.frame_to_command_s.append(latency)
                self.latency_s.append(latency)
        except HeadTimeoutError as err:  # no pair in time
            return self._ended(track_id, TrackOutcome.NO_FRAMES, str(err), stats)
        except FixationInterrupted as err:
            if err.outcome is FixationOutcome.CANCELLED:
                return self._ended(track_id, TrackOutcome.STOPPED, str(err), stats)
            if err.outcome is FixationOutcome.SHUTDOWN:
                return self._ended(track_id, TrackOutcome.SHUTDOWN, str(err), stats)
            return self._ended(track_id, TrackOutcome.HEAD_FAULT, f"{err.outcome}: {err}", stats)
        except (DriverError, ServoLoopStoppedError, TimeoutError) as err:
            return self._ended(track_id, TrackOutcome.HEAD_FAULT, str(err), stats)

    def _pose_at(self, poses: ExposurePoses, exposure_s: float) -> np.ndarray | None:
        return poses.at(exposure_s)

    def _right_pose(self, poses: ExposurePoses, exposure_s: float, lag_s: float,
                    pose: np.ndarray) -> np.ndarray | None:
        """The head's pose at the right image's exposure (`lag_s` after the left's)."""
        return pose if lag_s == 0.0 else poses.at(exposure_s + lag_s)

    def _record(self, stats: TrackStats, step: PursuitStep, pursuit: Pursuit) -> None:
        assert step.match is not None
        stats.found += 1
        stats.refreshes = pursuit.tracker.refreshes
        stats.last_match = (step.match.x, step.match.y, step.match.d)
        stats.last_ncc = step.match.ncc
        if step.retinal_error_px is not None:
            stats.retinal_error_px.append(step.retinal_error_px)

    def _ended(self, track_id: int, outcome: TrackOutcome, detail: str, stats: TrackStats) -> TrackEnd:
        self._tell("track_stopped", id=track_id, outcome=str(outcome), detail=detail, stats=stats.as_dict())
        return TrackEnd(outcome, detail, stats)

    def status(self) -> TrackFigures | None:
        """The running track's figures, or None."""
        stats = self.current
        return None if stats is None else stats.as_dict()
