"""Two cameras read as stereo pairs, synchronised or free-running.

`StereoPair` pairs the frames of a left and a right camera as they arrive (`FrameMatcher`):
each frame with the nearest frame of the other camera whose timestamp lies within a
tolerance, never a frame twice, never two pairs crossing in time. It gives the first pair
whose exposures both began after a given monotonic time, so that frames exposed while the
head moved are never used, and keeps the recent pairs' skew (right minus left timestamp).

Two USB webcams are not synchronised: each runs on its own clock, so their frames are up to
half a frame period apart and the offset drifts (docs/sim-world.md, "Frame timing"). The
default tolerance, 0.6 of the slower camera's period, takes the nearest frame whatever the
phase (at most half a period away) with a margin for the timestamps' jitter.
"""
from __future__ import annotations

import collections
import math
import threading
from dataclasses import dataclass

import numpy as np

from drivers.cameras.camera import Camera, Frame, wait_for
from drivers.errors import CameraConfigError

DEFAULT_TOLERANCE_PERIODS = 0.6  # of the slower camera's frame period
SKEWS_KEPT = 1000  # the last pairs' skews (`skew_stats`)
UNPAIRED_KEPT = 16  # frames per side waiting for a partner


@dataclass(frozen=True)
class StereoFrames:
    left: Frame
    right: Frame

    @property
    def skew_s(self) -> float:
        return abs(self.left.time_s - self.right.time_s)

    @property
    def right_lag_s(self) -> float:
        """The right frame's timestamp minus the left's (signed)."""
        return self.right.time_s - self.left.time_s

    @property
    def exposure_start_s(self) -> float:
        return min(self.left.exposure_start_s, self.right.exposure_start_s)


@dataclass(frozen=True)
class SkewStats:
    """The recent pairs' skew (right minus left timestamp), seconds, and what went unpaired."""

    pairs: int  # pairs made in all
    recent: int  # pairs these figures are over
    mean_s: float | None  # signed mean of right - left
    p50_abs_s: float | None
    p95_abs_s: float | None
    max_abs_s: float | None
    unpaired: dict[str, int]  # frames of each camera never paired (no partner within tolerance)


class FrameMatcher:
    """Pairs two streams of frames one to one by nearest timestamps, as they arrive.

    A new frame takes the nearest unpaired frame of the other side within `tolerance_s`,
    unless that one is older by more than half the other side's period: then the other
    side's next frame is nearer and due, and pairs with it. Unpaired frames older than a
    pair are dropped (pairs never cross in time). Not thread-safe: `StereoPair` locks it."""

    def __init__(self, tolerance_s: float, periods_s: tuple[float, float], keep: int = 8) -> None:
        self.tolerance_s = tolerance_s
        self.periods_s = periods_s
        self.pairs: collections.deque[StereoFrames] = collections.deque(maxlen=keep)
        self.skews_s: collections.deque[float] = collections.deque(maxlen=SKEWS_KEPT)
        self.made = 0
        self.unpaired_counts = [0, 0]
        self._waiting: tuple[collections.deque[Frame], collections.deque[Frame]] = (
            collections.deque(), collections.deque())
        self._newest_paired_s = [-math.inf, -math.inf]

    def _discard(self, side: int, frame: Frame) -> None:
        self.unpaired_counts[side] += 1

    def add(self, side: int, frame: Frame) -> StereoFrames | None:
        """Take a new frame of `side` (0 left, 1 right); the pair it made, if any."""
        if frame.time_s <= self._newest_paired_s[side]:  # older than a pair made: it would cross it
            self._discard(side, frame)
            return None
        other = 1 - side
        candidates = [f for f in self._waiting[other] if abs(f.time_s - frame.time_s) <= self.tolerance_s]
        best = min(candidates, key=lambda f: abs(f.time_s - frame.time_s), default=None)
        if best is None or frame.time_s - best.time_s > self.periods_s[other] / 2:
            waiting = self._waiting[side]
            waiting.append(frame)
            while len(waiting) > UNPAIRED_KEPT:
                self._discard(side, waiting.popleft())
            return None
        pair = StereoFrames(frame, best) if side == 0 else StereoFrames(best, frame)
        self._newest_paired_s = [pair.left.time_s, pair.right.time_s]
        for s in (0, 1):
            waiting = self._waiting[s]
            for f in [f for f in waiting if f.time_s <= self._newest_paired_s[s]]:
                waiting.remove(f)
                if f is not best:
                    self._discard(s, f)
        self.pairs.append(pair)
        self.skews_s.append(pair.right_lag_s)
        self.made += 1
        return pair

    def stats(self, names: tuple[str, str] = ("left", "right")) -> SkewStats:
        skews = np.asarray(self.skews_s, dtype=float)
        unpaired = dict(zip(names, self.unpaired_counts))
        if not len(skews):
            return SkewStats(self.made, 0, None, None, None, None, unpaired)
        magnitude = np.abs(skews)
        return SkewStats(self.made, len(skews), float(skews.mean()), float(np.percentile(magnitude, 50)),
                         float(np.percentile(magnitude, 95)), float(magnitude.max()), unpaired)


class StereoPair:
    """Left and right cameras read as pairs (see the module docstring).

    A pair is two frames whose `time_s` differ by at most `tolerance_s` (None: 0.6 of the
    slower camera's frame period). `wait_pair(after_s)` gives the FIRST pair whose exposures
    both began at or after `after_s`, so a caller that passes the time the head came to rest
    never gets a frame exposed while it moved.
    """

    def __init__(self, left: Camera, right: Camera, tolerance_s: float | None = None) -> None:
        periods_s = (1.0 / (left.config.fps or 30.0), 1.0 / (right.config.fps or 30.0))
        if tolerance_s is None:
            tolerance_s = DEFAULT_TOLERANCE_PERIODS * max(periods_s)
        if tolerance_s < 0:
            raise CameraConfigError(f"stereo pair tolerance_s {tolerance_s}: expected >= 0")
        self.left, self.right, self.tolerance_s = left, right, tolerance_s
        self._cond = threading.Condition()
        self._closed = False
        self._matcher = FrameMatcher(tolerance_s, periods_s, keep=max(left.config.history, right.config.history))
        with self._cond:
            # Frames already held, in the order of their timestamps, as if they arrived now.
            held = sorted([(f.time_s, 0, f) for f in left.history()] + [(f.time_s, 1, f) for f in right.history()],
                          key=lambda item: (item[0], item[1]))
            for _, side, frame in held:
                self._matcher.add(side, frame)
        left.add_listener(self._on_left)
        right.add_listener(self._on_right)

    def _on_left(self, frame: Frame | None) -> None:
        self._on_frame(0, frame)

    def _on_right(self, frame: Frame | None) -> None:
        self._on_frame(1, frame)

    def _on_frame(self, side: int, frame: Frame | None) -> None:
        with self._cond:
            if frame is not None:
                self._matcher.add(side, frame)
            self._cond.notify_all()

    def _pairs(self, after_s: float | None) -> list[StereoFrames]:
        """The pairs held, oldest first; with `after_s`, those exposed entirely after it."""
        with self._cond:
            pairs = list(self._matcher.pairs)
        if after_s is not None:
            pairs = [p for p in pairs if p.exposure_start_s >= after_s]
        return pairs

    def latest(self) -> StereoFrames | None:
        """The newest pair held, or None."""
        pairs = self._pairs(None)
        return pairs[-1] if pairs else None

    def skew_stats(self) -> SkewStats:
        """The last pairs' skew (right minus left timestamp) and the frames left unpaired."""
        with self._cond:
            return self._matcher.stats((self.left.name, self.right.name))

    def wait_pair(self, after_s: float | None = None, timeout_s: float = 2.0) -> StereoFrames:
        """The first pair exposed entirely at or after `after_s` (None: a pair newer than now held)."""
        if after_s is None:
            held = self.latest()
            baseline = (held.left.counter, held.right.counter) if held else (0, 0)

        def find() -> StereoFrames | None:
            pairs = self._pairs(after_s)
            if after_s is None:
                pairs = [p for p in pairs if p.left.counter > baseline[0] and p.right.counter > baseline[1]]
            return pairs[0] if pairs else None

        def check() -> None:
            for camera in (self.left, self.right):
                camera.raise_if_failed()

        def timeout_message() -> str:
            what = f"pair exposed after t={after_s:.6f} s" if after_s is not None else "new pair"
            return (f"stereo {self.left.name}/{self.right.name}: no {what} within {timeout_s} s "
                    f"with timestamps within {self.tolerance_s * 1e3:.1f} ms")

        with self._cond:
            return wait_for(self._cond, find, check, timeout_s, timeout_message)

    def close(self) -> None:
        """Stop listening to the cameras (they stay open: their owner closes them). Idempotent."""
        if self._closed:
            return
        self._closed = True
        self.left.remove_listener(self._on_left)
        self.right.remove_listener(self._on_right)

    def __enter__(self) -> "StereoPair":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
