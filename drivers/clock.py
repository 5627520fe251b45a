"""Clocks for control timing: the real monotonic clock and a manual one for tests.

All control timing uses a monotonic clock (never wall-clock time). Simulated and emulated
backends take a clock so tests can run faster than real time.
"""
from __future__ import annotations

import threading
import time
from typing import Protocol


class Clock(Protocol):
    def monotonic(self) -> float: ...
    def sleep(self, seconds: float) -> None: ...


class MonotonicClock:
    """The host's monotonic clock."""

    def monotonic(self) -> float:
        return time.monotonic()

    def sleep(self, seconds: float) -> None:
        if seconds > 0:
            time.sleep(seconds)


class ManualClock:
    """A clock that only moves when told to (`advance`) or when someone sleeps on it."""

    def __init__(self, start_s: float = 0.0) -> None:
        self._now_s = float(start_s)
        self._lock = threading.Lock()

    def monotonic(self) -> float:
        with self._lock:
            return self._now_s

    def advance(self, seconds: float) -> None:
        if seconds < 0:
            raise ValueError(f"a clock cannot go back ({seconds} s)")
        with self._lock:
            self._now_s += seconds

    def sleep(self, seconds: float) -> None:
        self.advance(max(0.0, seconds))


SYSTEM_CLOCK = MonotonicClock()


class Backoff:
    """Bounded exponential back-off for a loop that waits on a failed part: `failed()` gives
    the wait before the next attempt (`first_s`, then doubling up to `max_s`), `reset()` after
    an attempt that worked. It holds no time itself: the loop waits on its own event (so that
    `stop()` cuts the wait short) or on its clock."""

    def __init__(self, first_s: float, max_s: float, factor: float = 2.0) -> None:
        if not 0.0 < first_s <= max_s:
            raise ValueError(f"back-off: first_s {first_s!r} and max_s {max_s!r} must satisfy 0 < first_s <= max_s")
        if factor < 1.0:
            raise ValueError(f"back-off: factor {factor!r} must be at least 1")
        self.first_s = first_s
        self.max_s = max_s
        self.factor = factor
        self.failures = 0  # since the last reset
        self._next_s = first_s

    @property
    def delay_s(self) -> float:
        """The wait the next failure will get."""
        return self._next_s

    def failed(self) -> float:
        """One more failure: the wait before the next attempt."""
        delay_s = self._next_s
        self.failures += 1
        self._next_s = min(self._next_s * self.factor, self.max_s)
        return delay_s

    def reset(self) -> None:
        self.failures = 0
        self._next_s = self.first_s
