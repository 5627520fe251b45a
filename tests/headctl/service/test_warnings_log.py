"""The status's warnings log is bounded and keeps a repeated fault once per interval, so a
flood cannot push the other warnings out."""
from __future__ import annotations

import logging

from drivers.clock import ManualClock
from headctl.log_limit import RepeatLimiter
from headctl.service.events import EventLog


def test_a_flood_of_one_warning_keeps_the_others_and_counts_every_record():
    clock = ManualClock()
    warnings = EventLog(size=50, limiter=RepeatLimiter(10.0, clock))
    log = logging.getLogger("tests.warnings_log")
    log.propagate = False
    log.addHandler(warnings)
    try:
        log.warning("camera %s: reopen failed", "left")
        for i in range(5000):
            log.warning("fixation aborted: %s", f"no servo state ({i})")
            clock.advance(0.002)  # 10 s in all
        log.info("not a warning")
        log.error("servo loop failed: %s", "exit code -9")
        messages = [entry["message"] for entry in warnings.events]
        assert messages == ["camera left: reopen failed", "fixation aborted: no servo state (0)",
                            "fixation aborted: no servo state (4999) (repeated 4,999 times in the last 10 s)",
                            "servo loop failed: exit code -9"]
        assert warnings.counts == {"WARNING": 5001, "ERROR": 1}
        for i in range(200):  # kinds that do not repeat: the list stays bounded
            log.warning(f"distinct warning {i}")  # each its own format string
        assert len(warnings.events) == 50
    finally:
        log.removeHandler(warnings)


def test_the_daemon_limits_its_warnings_log_at_the_configs_interval(tmp_path):
    import dataclasses

    from headctl.config.head import LoggingConfig
    from headctl.service.daemon import Daemon
    from tests.conftest import sim_head_config

    clock = ManualClock()
    config = sim_head_config(tmp_path / "state")
    config = dataclasses.replace(config, logging=LoggingConfig(repeat_summary_s=3.0))
    limiter = Daemon(config, clock).parts.warnings.limiter
    assert limiter.interval_s == 3.0 and limiter.clock is clock
