"""Log messages repeated by a fault, limited per kind: the first in full, then one summary line per interval.

A fault that lasts (the servo loop gone, a camera unplugged, the state directory full) makes
the code that meets it log the same message again on every attempt. The limit keeps the log
readable and the journal and the disk from filling, whatever the loops do:

- a kind is the logger's name, the level, the message's format string and those of its
  arguments that are names (a string of at most 32 characters without whitespace: a camera,
  a joint, a port), not the others ("fixation aborted: %s" is one kind whatever the detail,
  "camera %s: reopen failed: %s" one per camera); a format string that is nothing but
  placeholders ("%s", as the servo process's relayed records are) is keyed by the message;
- the first record of a kind passes whole; the next ones within `interval_s` of the last line
  of that kind are counted, not written;
- the first one after the interval is written as a summary: its message and "(repeated 2,314
  times in the last 10 s)", the count of the kind's records since its last line (itself
  included), without a traceback;
- a kind that stopped repeating gets its summary on the next record of any kind once its
  interval has passed, and on `flush()` (logging's shutdown at exit);
- at most `max_kinds` kinds are remembered (the least recently seen is forgotten).

`RepeatLimiter` is the policy, driven by an injectable clock (a test's manual clock);
`RepeatLimitHandler` puts it in front of other handlers (the console or journal and the log
file, `install`); `headctl.service.events.EventLog` (the status's warnings) applies its own.
The top-level package holds it because the command line and the service both use it.
"""
from __future__ import annotations

import collections
import dataclasses
import logging
import re
import threading

from drivers.clock import SYSTEM_CLOCK, Clock

DEFAULT_INTERVAL_S = 10.0
MAX_KINDS = 1024
_PLACEHOLDER = re.compile(r"%(\([^)]*\))?[-#0 +]*(\*|\d+)?(\.(\*|\d+))?[diouxXeEfFgGcrsa%]")

NAME_MAX_CHARS = 32

Kind = tuple[str, int, str, tuple[str, ...]]


@dataclasses.dataclass
class _Seen:
    line_s: float  # when the kind's last line was written
    repeats: int = 0  # records since that line, not written
    last: logging.LogRecord | None = None  # the last of them, as it came (no copy on the hot path)


def kind_of(record: logging.LogRecord) -> Kind:
    """(logger, level, format string, the arguments that are names); the message itself when
    the format is only placeholders."""
    fmt = record.msg if isinstance(record.msg, str) else None
    if fmt is None or not _PLACEHOLDER.sub("", fmt).strip(" :;,.-"):
        return record.name, record.levelno, _message(record), ()
    args = record.args.values() if isinstance(record.args, dict) else record.args or ()
    names = tuple(a for a in args if isinstance(a, str) and len(a) <= NAME_MAX_CHARS and not any(c.isspace() for c in a))
    return record.name, record.levelno, fmt, names


def _message(record: logging.LogRecord) -> str:
    try:
        return record.getMessage()
    except Exception:  # a bad format string must not break logging
        return str(record.msg)


def _summary(record: logging.LogRecord, repeats: int, over_s: float) -> logging.LogRecord:
    """A copy of `record` saying how often its kind repeated; no traceback."""
    copy = logging.makeLogRecord(record.__dict__)
    copy.msg = f"{_message(record)} (repeated {repeats:,} times in the last {over_s:.0f} s)"
    copy.args = None
    copy.exc_info = copy.exc_text = copy.stack_info = None
    return copy


class RepeatLimiter:
    """Which records to write (see the module docstring); `interval_s` 0 writes every one."""

    def __init__(self, interval_s: float = DEFAULT_INTERVAL_S, clock: Clock = SYSTEM_CLOCK,
                 max_kinds: int = MAX_KINDS) -> None:
        self.clock = clock
        self.max_kinds = max_kinds
        self.interval_s = interval_s
        self.suppressed = 0  # records not written, in all
        self._lock = threading.Lock()
        self._kinds: collections.OrderedDict[Kind, _Seen] = collections.OrderedDict()
        self._swept_s = clock.monotonic()

    @property
    def interval_s(self) -> float:
        return self._interval_s

    @interval_s.setter
    def interval_s(self, interval_s: float) -> None:
        if not interval_s >= 0.0:
            raise ValueError(f"repeat summary interval: got {interval_s!r}, expected a time of at least 0 s")
        self._interval_s = float(interval_s)

    def admit(self, record: logging.LogRecord) -> list[logging.LogRecord]:
        """What to write for `record`: summaries of kinds that stopped repeating (due now), then
        the record itself, its summary, or nothing."""
        if self._interval_s == 0.0:
            return [record]
        kind = kind_of(record)
        with self._lock:
            now = self.clock.monotonic()
            out = self._sweep(now, kind)
            seen = self._kinds.get(kind)
            if seen is None:
                self._kinds[kind] = _Seen(now)
                if len(self._kinds) > self.max_kinds:
                    self._kinds.popitem(last=False)
                out.append(record)
                return out
            self._kinds.move_to_end(kind)
            if now - seen.line_s < self._interval_s:
                seen.repeats += 1
                seen.last = record
                self.suppressed += 1
                return out
            repeats, over_s = seen.repeats, now - seen.line_s
            seen.line_s, seen.repeats, seen.last = now, 0, None
            out.append(record if repeats == 0 else _summary(record, repeats + 1, over_s))
            return out

    def flush(self) -> list[logging.LogRecord]:
        """The summaries of every kind with records not yet told, due or not."""
        with self._lock:
            return self._sweep(self.clock.monotonic(), None, due_only=False)

    def _sweep(self, now: float, current: Kind | None, due_only: bool = True) -> list[logging.LogRecord]:
        """Summaries of kinds (other than `current`) whose interval passed with records untold;
        looked for at most once an interval."""
        if due_only and now - self._swept_s < self._interval_s:
            return []
        self._swept_s = now
        out = []
        for kind, seen in self._kinds.items():
            if seen.last is None or (due_only and (kind == current or now - seen.line_s < self._interval_s)):
                continue
            out.append(_summary(seen.last, seen.repeats, now - seen.line_s))
            seen.line_s, seen.repeats, seen.last = now, 0, None
        return out


class RepeatLimitHandler(logging.Handler):
    """Writes to its `targets` (the console, the log file) what its `limiter` lets through."""

    def __init__(self, limiter: RepeatLimiter, targets: list[logging.Handler] | None = None) -> None:
        super().__init__(level=logging.NOTSET)
        self.limiter = limiter
        self.targets: list[logging.Handler] = list(targets or [])

    def emit(self, record: logging.LogRecord) -> None:
        self._write(self.limiter.admit(record))

    def _write(self, records: list[logging.LogRecord]) -> None:
        for record in records:
            for target in list(self.targets):
                if record.levelno >= target.level:
                    target.handle(record)

    def flush(self) -> None:
        self._write(self.limiter.flush())
        for target in list(self.targets):
            target.flush()

    def close(self) -> None:
        try:
            self.flush()
            for target in self.targets:
                target.close()
        finally:
            super().close()


def install(handler: logging.Handler, interval_s: float | None = None,
            logger: logging.Logger | None = None) -> RepeatLimitHandler:
    """Write to `handler` through the repeat limit of `logger` (the root logger): one
    `RepeatLimitHandler` on it, made at the first call; `interval_s` sets its interval."""
    logger = logger or logging.getLogger()
    limit = configure(interval_s, logger) if interval_s is not None else _installed(logger)
    if limit is None:
        limit = RepeatLimitHandler(RepeatLimiter(DEFAULT_INTERVAL_S if interval_s is None else interval_s))
        logger.addHandler(limit)
    if handler not in limit.targets:
        limit.targets.append(handler)
    return limit


def configure(interval_s: float, logger: logging.Logger | None = None) -> RepeatLimitHandler | None:
    """Set the interval of `logger`'s (the root logger's) repeat limit, if it has one."""
    limit = _installed(logger or logging.getLogger())
    if limit is not None:
        limit.limiter.interval_s = interval_s
    return limit


def _installed(logger: logging.Logger) -> RepeatLimitHandler | None:
    return next((h for h in logger.handlers if isinstance(h, RepeatLimitHandler)), None)
