"""What the service tells: events for clients, and the warnings log for the status.

- `EventHub`: saccade onset/done, fixation converged/refused, faults, look started/done, ...
  published by the service's threads to any number of subscribers (the HTTP event stream),
  each a callback that must not block; the last events are kept so that a client that
  reconnects (SSE `Last-Event-ID`) misses none.
- `EventLog`: the last warnings and errors of every module, kept for the status (a bounded
  list, repeats of one kind limited as in the service's log: `headctl.log_limit`).
- `plain`: values made JSON-ready (numpy arrays and scalars, NaN as None).
"""
from __future__ import annotations

import collections
import logging
import math
import threading
import time
from typing import Callable, TypeAlias, TypedDict

import numpy as np

from headctl.json_types import JSON, JSONObject
from headctl.log_limit import RepeatLimiter

log = logging.getLogger(__name__)


# An event: its `seq`, `time` and `type`, then the fields its publisher gave (made `plain`).
Event: TypeAlias = JSONObject
Subscriber = Callable[[Event], None]


class LogEntry(TypedDict):
    """A warning or error logged, as the status lists it."""

    time: float
    level: str
    logger: str
    message: str


class EventHub:
    """Publish events to subscribers (callbacks that must not block); keeps the last `history`."""

    def __init__(self, history: int = 512) -> None:
        self._lock = threading.Lock()
        self._seq = 0
        self._history: collections.deque[Event] = collections.deque(maxlen=history)
        self._subscribers: list[Subscriber] = []
        self.counts: collections.Counter[str] = collections.Counter()

    def publish(self, type_: str, **fields: object) -> Event:
        with self._lock:
            self._seq += 1
            event: Event = {"seq": self._seq, "time": time.time(), "type": type_,
                     **{k: plain(v) for k, v in fields.items()}}
            self._history.append(event)
            self.counts[type_] += 1
            subscribers = list(self._subscribers)
        for deliver in subscribers:
            try:
                deliver(event)
            except Exception:  # one broken subscriber must not stop the publisher (a servo thread)
                log.exception("event subscriber failed on %s", type_)
        return event

    def subscribe(self, deliver: Subscriber, after_seq: int | None = None) -> Callable[[], None]:
        """Call `deliver(event)` for every event from now on (and first for those kept after
        `after_seq`, if given); returns the function that unsubscribes."""
        with self._lock:
            backlog = [e for e in self._history if after_seq is not None and e["seq"] > after_seq]
            self._subscribers.append(deliver)
        for event in backlog:
            deliver(event)

        def unsubscribe() -> None:
            with self._lock:
                if deliver in self._subscribers:
                    self._subscribers.remove(deliver)
        return unsubscribe

    @property
    def seq(self) -> int:
        """The last event's number (stream from here with `after`)."""
        with self._lock:
            return self._seq

    def recent(self, count: int = 50) -> list[Event]:
        with self._lock:
            return list(self._history)[-count:]

    @property
    def subscribers(self) -> int:
        with self._lock:
            return len(self._subscribers)


def plain(value: object, digits: int | None = 4) -> JSON:
    """JSON-ready: numpy arrays and scalars as lists and floats, floats rounded to `digits`
    (None: kept whole), and NaN and infinities as None (JSON has neither)."""
    if isinstance(value, np.ndarray):
        return [plain(v, digits) for v in value.tolist()]
    if isinstance(value, (list, tuple)):
        return [plain(v, digits) for v in value]
    if isinstance(value, dict):
        return {k: plain(v, digits) for k, v in value.items()}
    if isinstance(value, (np.floating, float)):
        f = float(value)
        if not math.isfinite(f):
            return None
        return f if digits is None else round(f, digits)
    if isinstance(value, np.integer):
        return int(value)
    return value


class EventLog(logging.Handler):
    """The last warnings and errors of every module (bus down, hardware errors, reboots, camera
    faults), kept for `headctl status`: what the drivers recover from by themselves is still
    reported. A fault that repeats is kept once, then once per `limiter`'s interval with the
    count (`headctl.log_limit`), so it cannot push every other warning out; `counts` counts
    every record."""

    def __init__(self, size: int = 50, limiter: RepeatLimiter | None = None) -> None:
        super().__init__(level=logging.WARNING)
        self.events: collections.deque[LogEntry] = collections.deque(maxlen=size)
        self.counts: collections.Counter[str] = collections.Counter()
        self.limiter = limiter if limiter is not None else RepeatLimiter()

    def emit(self, record: logging.LogRecord) -> None:
        self.counts[record.levelname] += 1
        for kept in self.limiter.admit(record):
            try:
                message = kept.getMessage()
            except Exception:  # a bad format string must not break logging
                message = str(kept.msg)
            self.events.append({"time": kept.created, "level": kept.levelname, "logger": kept.name,
                                "message": message})
