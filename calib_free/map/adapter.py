"""The adapter thread: the gaze map learns in the background while the head keeps moving.

`MapAdapter` owns a `GazeMap` and a named thread that takes training samples (r*, m, c)
from a bounded queue and adapts the map. Readers (`command`, `with_map`) and the thread
share one lock, held for the milliseconds of a lookup or an adaptation, so the fixation loop
never waits long on learning; `progress` (adaptations, recent retinal errors) is published
after each adaptation and read without the lock, so a status reader never waits at all.
A full queue drops the oldest sample (counted): learning may lag, motion never blocks. An
exception in the thread reaches `on_error` and `error`; the thread stops through an event.
"""
from __future__ import annotations

import logging
import queue
import threading
from dataclasses import dataclass
from typing import Callable, TypeVar

import numpy as np

from calib_free.map.gaze_map import AdaptResult, GazeMap, Vector

log = logging.getLogger(__name__)

T = TypeVar("T")


@dataclass(frozen=True)
class Progress:
    """How far learning is, as of the last adaptation (a latest-value slot, read lock-free)."""

    adaptations: int
    recent_retinal_errors: tuple[float, ...]  # eq. 8, the window of eq. 9

    @classmethod
    def of(cls, gaze_map: GazeMap) -> "Progress":
        return cls(gaze_map.adaptations, tuple(gaze_map.recent_errors))


@dataclass(frozen=True)
class Sample:
    position: np.ndarray  # r* = (x*, y*, d*)
    command: np.ndarray  # the executed relative command
    confidence: float
    tag: int = -1  # the caller's id for it (a fixation index)
    pose: np.ndarray | None = None  # (pan, tilt, vergence), deg, when the pre-fixation pair was taken


class MapAdapter:
    """A GazeMap adapted on its own thread; thread-safe lookups."""

    def __init__(self, gaze_map: GazeMap, queue_size: int = 64,
                 on_adapted: Callable[[Sample, AdaptResult], None] | None = None,
                 on_error: Callable[[BaseException], None] | None = None, name: str = "gaze-adapter") -> None:
        self.map = gaze_map
        self.on_adapted = on_adapted
        self.on_error = on_error
        self.error: BaseException | None = None
        self.dropped = 0
        self.progress = Progress.of(gaze_map)
        self._queue: queue.Queue[Sample] = queue.Queue(maxsize=queue_size)
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)
        self._started = False

    # -- lifecycle ----------------------------------------------------------------------
    def start(self) -> "MapAdapter":
        if not self._started:
            self._started = True
            self._thread.start()
        return self

    def stop(self, timeout_s: float = 5.0) -> None:
        """Stop the thread (samples still queued are not learned). Safe to call twice."""
        self._stop.set()
        if self._started and self._thread.is_alive():
            self._thread.join(timeout_s)
            if self._thread.is_alive():
                log.warning("%s did not stop within %.1f s", self._thread.name, timeout_s)

    def is_alive(self) -> bool:
        return self._thread.is_alive()

    def restart(self) -> "MapAdapter":
        """A new thread in place of one that died (the queue, the map and the counters kept);
        nothing when it runs or was stopped."""
        if self._started and not self._thread.is_alive() and not self._stop.is_set():
            self._thread = threading.Thread(target=self._run, name=self._thread.name, daemon=True)
            self._thread.start()
        return self

    def __enter__(self) -> "MapAdapter":
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    # -- use ----------------------------------------------------------------------------
    def submit(self, sample: Sample) -> None:
        """Queue a sample; never blocks (a full queue loses its oldest sample)."""
        while True:
            try:
                self._queue.put_nowait(sample)
                return
            except queue.Full:
                try:
                    self._queue.get_nowait()
                    self._queue.task_done()
                    self.dropped += 1
                except queue.Empty:
                    pass

    def wait_idle(self, timeout_s: float | None = None) -> bool:
        """Block until every queued sample is learned; True if idle, False on timeout."""
        # Queue's own condition, notified by task_done(): no polling, no helper thread.
        with self._queue.all_tasks_done:
            return self._queue.all_tasks_done.wait_for(lambda: self._queue.unfinished_tasks == 0, timeout_s)

    def command(self, position: Vector, pose: Vector | None = None) -> np.ndarray:
        with self._lock:
            return self.map.command(position, pose=pose)

    def check_position(self, position: Vector) -> str:
        return self.map.check_position(position)  # the map's range never changes: no lock

    def uncertainty(self, position: Vector, pose: Vector | None = None) -> float:
        """The map's predictive variance at `position` (`GazeMap.uncertainty`), under the lock:
        what the teaching exploration prefers."""
        with self._lock:
            return self.map.uncertainty(position, pose=pose)

    def with_map(self, fn: Callable[[GazeMap], T]) -> T:
        """Run `fn(map)` under the lock (saving, evaluating) without racing the adapter."""
        with self._lock:
            return fn(self.map)

    def replace_map(self, gaze_map: GazeMap) -> GazeMap:
        """Learn on `gaze_map` from now on (a loaded or reset map); samples still queued were
        measured for the old one and are dropped. Returns the old map."""
        with self._lock:
            old, self.map = self.map, gaze_map
            self.progress = Progress.of(gaze_map)
            while True:
                try:
                    self._queue.get_nowait()
                except queue.Empty:
                    break
                self._queue.task_done()
        log.info("%s: map replaced (%d adaptations)", self._thread.name, gaze_map.adaptations)
        return old

    # -- the thread -----------------------------------------------------------------------
    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                sample = self._queue.get(timeout=0.05)
            except queue.Empty:
                continue
            try:
                with self._lock:
                    if sample.pose is None:  # as before poses existed (a map class may not take one)
                        result = self.map.adapt(sample.position, sample.command, confidence=sample.confidence)
                    else:
                        result = self.map.adapt(sample.position, sample.command, confidence=sample.confidence,
                                                pose=sample.pose)
                    self.progress = Progress.of(self.map)
                if self.on_adapted is not None:
                    self.on_adapted(sample, result)
            except Exception as err:  # reported, never lost; the thread keeps learning
                self.error = err
                log.exception("%s: adaptation failed", self._thread.name)
                if self.on_error is not None:
                    self.on_error(err)
            finally:
                self._queue.task_done()
