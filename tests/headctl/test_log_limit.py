"""Log messages repeated by a fault: the first in full, then one summary line per interval
with the right count; kinds told apart by logger, level and format string."""
from __future__ import annotations

import logging
import re
import sys

import pytest

from drivers.clock import ManualClock
from headctl.log_limit import RepeatLimiter, RepeatLimitHandler, install, kind_of

SUMMARY = re.compile(r"\(repeated ([\d,]+) times in the last (\d+) s\)$")


class Lines(logging.Handler):
    """What a console or file handler would have written: (time, message) per line."""

    def __init__(self, clock: ManualClock) -> None:
        super().__init__()
        self.clock = clock
        self.lines: list[tuple[float, str]] = []

    def emit(self, record: logging.LogRecord) -> None:
        self.lines.append((self.clock.monotonic(), record.getMessage()))


def limited_logger(name: str, interval_s: float, clock: ManualClock) -> tuple[logging.Logger, Lines]:
    logger = logging.getLogger(f"tests.log_limit.{name}")
    logger.propagate = False
    logger.handlers.clear()
    logger.setLevel(logging.DEBUG)
    lines = Lines(clock)
    logger.addHandler(RepeatLimitHandler(RepeatLimiter(interval_s, clock), [lines]))
    return logger, lines


def repeated_count(message: str) -> int:
    match = SUMMARY.search(message)
    assert match is not None, message
    return int(match.group(1).replace(",", ""))


@pytest.mark.parametrize("interval_s", [1.0, 10.0])
def test_a_fault_repeated_for_30_s_writes_one_line_then_a_summary_per_interval(interval_s):
    clock = ManualClock(1000.0)
    log, lines = limited_logger(f"fault{interval_s:g}", interval_s, clock)
    records = 0
    for i in range(30_000):  # 30 s at 1 kHz, each with its own detail
        log.info("fixation aborted: %s", f"servo-bus: no servo state within 1.0 s (attempt {i})")
        records += 1
        clock.advance(0.001)
    first_s, first = lines.lines[0]
    assert first == "fixation aborted: servo-bus: no servo state within 1.0 s (attempt 0)"
    summaries = lines.lines[1:]
    assert len(summaries) <= 30 / interval_s  # at most one a second after the first, here one an interval
    assert len(summaries) >= 30 / interval_s - 1
    for (before_s, _), (at_s, message) in zip(lines.lines, summaries):
        assert at_s - before_s >= interval_s
        assert message.startswith("fixation aborted: servo-bus: no servo state within 1.0 s (attempt ")
        assert SUMMARY.search(message).group(2) == f"{interval_s:.0f}"
    # The rest, told when the handler is flushed (at exit); every record is counted once.
    log.handlers[0].flush()
    told = 1 + sum(repeated_count(message) for _, message in lines.lines[1:])
    assert told == records


def test_other_kinds_pass_while_one_is_limited_and_a_quiet_kind_gets_its_summary_later():
    clock = ManualClock()
    log, lines = limited_logger("kinds", 10.0, clock)
    for i in range(5):
        log.warning("camera %s: no frame (%s)", "left", f"waited {i} s")
        log.warning("camera %s: no frame (%s)", "right", f"waited {i} s")  # a name among the arguments
        log.error("camera %s: no frame (%s)", "left", f"waited {i} s")  # another level: another kind
        log.warning("%s", "servo process: bus reopened")  # only placeholders: keyed by the message
        log.warning("%s", "servo process: read failed")
        clock.advance(0.1)
    assert [m for _, m in lines.lines] == ["camera left: no frame (waited 0 s)", "camera right: no frame (waited 0 s)",
                                           "camera left: no frame (waited 0 s)",
                                           "servo process: bus reopened", "servo process: read failed"]
    clock.advance(10.0)
    log.warning("state directory %s is full", "/var/lib/headctl")  # any record: quiet kinds are told
    told = [m for _, m in lines.lines[5:]]
    assert told[-1] == "state directory /var/lib/headctl is full"
    assert sorted(told[:-1]) == sorted([
        "camera left: no frame (waited 4 s) (repeated 4 times in the last 10 s)",
        "camera right: no frame (waited 4 s) (repeated 4 times in the last 10 s)",
        "camera left: no frame (waited 4 s) (repeated 4 times in the last 10 s)",
        "servo process: bus reopened (repeated 4 times in the last 10 s)",
        "servo process: read failed (repeated 4 times in the last 10 s)"])


def test_a_summary_carries_no_traceback_and_interval_0_writes_every_record():
    clock = ManualClock()
    limiter = RepeatLimiter(1.0, clock)
    try:
        raise OSError(28, "No space left on device")
    except OSError:
        record = logging.getLogger("t").makeRecord("t", logging.ERROR, __file__, 1, "checkpoint failed: %s",
                                                   ("ENOSPC",), sys.exc_info())
    assert limiter.admit(record) == [record]
    assert limiter.admit(record) == []
    clock.advance(1.0)
    [summary] = limiter.admit(record)
    assert summary.exc_info is None and summary.getMessage() == "checkpoint failed: ENOSPC (repeated 2 times in the last 1 s)"
    assert record.exc_info is not None  # the record itself is left as it came
    limiter.interval_s = 0.0
    assert all(limiter.admit(record) == [record] for _ in range(3))
    with pytest.raises(ValueError, match="repeat summary interval: got -1"):
        limiter.interval_s = -1


def test_kinds_remembered_are_bounded():
    clock = ManualClock()
    limiter = RepeatLimiter(10.0, clock, max_kinds=8)
    for i in range(100):
        limiter.admit(logging.makeLogRecord({"name": "t", "levelno": logging.INFO, "msg": f"message {i} %s",
                                             "args": (i,)}))
    assert len(limiter._kinds) == 8
    assert kind_of(logging.makeLogRecord({"name": "t", "levelno": 20, "msg": "%s on %s: %s",
                                          "args": (1, "/dev/ttyUSB0", "no reply from id 3")})) == (
        "t", 20, "%s on %s: %s", ("/dev/ttyUSB0",))


def test_install_puts_handlers_behind_one_limit_on_the_logger():
    logger = logging.getLogger("tests.log_limit.install")
    logger.handlers.clear()
    first, second = logging.NullHandler(), logging.NullHandler()
    limit = install(first, logger=logger)
    assert install(second, 2.5, logger=logger) is limit
    assert logger.handlers == [limit] and limit.targets == [first, second] and limit.limiter.interval_s == 2.5
    logger.handlers.clear()
