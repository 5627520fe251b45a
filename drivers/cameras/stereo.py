"""Two cameras read as synchronised stereo pairs.

`StereoPair` pairs the frames of a left and a right camera whose timestamps agree within a
tolerance, and gives the first pair whose exposures both began after a given monotonic time,
so that frames exposed while the head moved are never used.
"""
from __future__ import annotations

import threading
from dataclasses import dataclass

from drivers.cameras.camera import Camera, Frame, wait_for
from drivers.errors import CameraConfigError


@dataclass(frozen=True)
class StereoFrames:
    left: Frame
    right: Frame

    @property
    def skew_s(self) -> float:
        return abs(self.left.time_s - self.right.time_s)

    @property
    def exposure_start_s(self) -> float:
        return min(self.left.exposure_start_s, self.right.exposure_start_s)


class StereoPair:
    """Left and right cameras read as synchronised pairs.

    A pair is two frames whose `time_s` differ by at most `tolerance_s`. `wait_pair(after_s)`
    gives the FIRST pair whose exposures both began at or after `after_s`, so a caller that
    passes the time the head came to rest never gets a frame exposed while it moved.
    """

    def __init__(self, left: Camera, right: Camera, tolerance_s: float | None = None) -> None:
        if tolerance_s is None:
            fps = min(c.config.fps or 30.0 for c in (left, right))
            tolerance_s = 0.5 / fps
        if tolerance_s < 0:
            raise CameraConfigError(f"stereo pair tolerance_s {tolerance_s}: expected >= 0")
        self.left, self.right, self.tolerance_s = left, right, tolerance_s
        self._cond = threading.Condition()
        self._closed = False
        left.add_listener(self._on_frame)
        right.add_listener(self._on_frame)

    def _on_frame(self, frame: Frame | None) -> None:
        with self._cond:
            self._cond.notify_all()

    def _pairs(self, after_s: float | None) -> list[StereoFrames]:
        """Matching pairs in the histories, oldest first; each left frame at most once."""
        lefts = self.left.history()
        rights = self.right.history()
        if after_s is not None:
            lefts = [f for f in lefts if f.exposure_start_s >= after_s]
            rights = [f for f in rights if f.exposure_start_s >= after_s]
        pairs = []
        for lf in lefts:
            if not rights:
                break
            best = min(rights, key=lambda rf: abs(rf.time_s - lf.time_s))
            if abs(best.time_s - lf.time_s) <= self.tolerance_s:
                pairs.append(StereoFrames(lf, best))
        return pairs

    def latest(self) -> StereoFrames | None:
        """The newest synchronised pair held, or None."""
        pairs = self._pairs(None)
        return pairs[-1] if pairs else None

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
        self.left.remove_listener(self._on_frame)
        self.right.remove_listener(self._on_frame)

    def __enter__(self) -> "StereoPair":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
