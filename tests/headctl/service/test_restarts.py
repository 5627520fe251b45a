"""The one restart policy (`headctl.service.supervision.restarts`) on a manual clock: back-off doubling to
its cap and starting over after a healthy run, a failed restart counted, one window for every
part, giving up past the limit, a part that does not count never giving up; its config keys."""
from __future__ import annotations

import dataclasses

import pytest
import yaml

from drivers.clock import ManualClock
from headctl.config.head import load_config
from headctl.errors import ConfigError
from headctl.service.supervision.restarts import RestartRecord, Restarts, RestartSettings
from tests.support.daemon_proc import SIM


@dataclasses.dataclass
class FakePart:
    name: str
    counts: bool = True
    dead: str | None = None
    refuse: bool = False  # its restart raises
    restarted: int = 0

    def failure(self) -> str | None:
        return self.dead

    def restart(self) -> dict[str, object]:
        if self.refuse:
            raise OSError(f"{self.name}: cannot start")
        self.dead = None
        self.restarted += 1
        return {"run": self.restarted}


def _policy(clock: ManualClock, records: list[RestartRecord] | None = None, **settings: float) -> Restarts:
    values = {"limit": 3, "window_s": 60.0, "backoff_s": 0.5, "backoff_max_s": 4.0, **settings}
    return Restarts(RestartSettings(**values), clock, on_restart=None if records is None else records.append)


def _restart_times(clock: ManualClock, restarts: Restarts, part: FakePart, deaths: int, step_s: float = 0.125,
                   ) -> list[float]:
    """Kill `part` right after each restart, `deaths` times; the delay before each restart."""
    delays = []
    for _ in range(deaths):
        part.dead = "killed"
        restarts.tick()
        died_s = clock.monotonic()
        while part.dead is not None and not restarts.gave_up:
            clock.advance(step_s)
            restarts.tick()
        delays.append(round(clock.monotonic() - died_s, 2))
    return delays


def test_a_dead_part_is_restarted_after_a_backoff_doubling_to_its_cap():
    clock, records = ManualClock(), []
    restarts = _policy(clock, records, limit=100)
    part = FakePart("fixation")
    restarts.watch([part])
    assert _restart_times(clock, restarts, part, 6) == [0.5, 1.0, 2.0, 4.0, 4.0, 4.0]
    assert restarts.restarts() == {"fixation": 6} and not restarts.gave_up
    assert [(r.part, r.cause, r.restarts, dict(r.detail)) for r in records[:1]] == [
        ("fixation", "killed", 1, {"run": 1})]


def test_a_part_that_ran_longer_than_the_cap_starts_from_the_first_backoff_again():
    clock = ManualClock()
    restarts = _policy(clock, limit=100)
    part = FakePart("gaze-adapter")
    restarts.watch([part])
    assert _restart_times(clock, restarts, part, 3) == [0.5, 1.0, 2.0]
    clock.advance(4.0)  # ran as long as the cap since its last restart
    restarts.tick()
    assert _restart_times(clock, restarts, part, 1) == [0.5]


def test_a_restart_that_fails_is_one_more_failure_retried_after_the_next_backoff():
    clock, records = ManualClock(), []
    restarts = _policy(clock, records, limit=10)
    part = FakePart("servo-io", dead="exited (code -9)", refuse=True)
    restarts.watch([part])
    restarts.tick()
    clock.advance(0.5)
    restarts.tick()  # the first attempt fails: the next in 1 s
    assert part.restarted == 0 and restarts.pending("servo-io")
    clock.advance(0.99)
    restarts.tick()
    part.refuse = False
    assert part.restarted == 0
    clock.advance(0.01)
    restarts.tick()
    assert part.restarted == 1 and not restarts.pending("servo-io")
    assert "restart failed: servo-io: cannot start" in records[0].cause


def test_more_failures_than_the_limit_within_the_window_give_up_counting_every_part():
    clock = ManualClock()
    restarts = _policy(clock, limit=3, window_s=60.0)
    servo, fixation = FakePart("servo-io"), FakePart("fixation")
    restarts.watch([servo, fixation])
    _restart_times(clock, restarts, servo, 2)
    _restart_times(clock, restarts, fixation, 1)
    assert not restarts.gave_up  # three failures: the limit
    fixation.dead = "died again"
    restarts.tick()
    assert restarts.gave_up and not restarts.pending("fixation")
    reason = restarts.give_up_reason or ""
    assert "4 failures within 60 s" in reason and "restart_limit: 3" in reason and "fixation: died again" in reason
    restarts.tick()  # nothing is restarted once given up
    assert fixation.restarted == 1


def test_failures_older_than_the_window_are_forgotten():
    clock = ManualClock()
    restarts = _policy(clock, limit=2, window_s=30.0)
    part = FakePart("servo-io")
    restarts.watch([part])
    _restart_times(clock, restarts, part, 2)
    clock.advance(31.0)
    _restart_times(clock, restarts, part, 2)
    assert not restarts.gave_up and part.restarted == 4
    _restart_times(clock, restarts, part, 1)
    assert restarts.gave_up


def test_a_part_that_does_not_count_is_restarted_for_ever():
    clock = ManualClock()
    restarts = _policy(clock, limit=1)
    camera = FakePart("camera-left", counts=False)
    restarts.watch([camera])
    _restart_times(clock, restarts, camera, 20)
    assert camera.restarted == 20 and not restarts.gave_up


def _config_with(tmp_path, **service):
    data = yaml.safe_load(SIM.read_text())
    data["service"].update(service)
    path = tmp_path / "head.yaml"
    path.write_text(yaml.safe_dump(data))
    return load_config(path)


def test_the_restart_keys_have_defaults_and_are_checked(tmp_path):
    service = load_config().service
    assert (service.restart_limit, service.restart_window_s, service.restart_backoff_s,
            service.restart_backoff_max_s) == (5, 300.0, 0.5, 10.0)
    assert RestartSettings.of(service) == RestartSettings(limit=5, window_s=300.0, backoff_s=0.5, backoff_max_s=10.0)
    assert _config_with(tmp_path, restart_limit=2, restart_window_s=60).service.restart_limit == 2
    with pytest.raises(ConfigError, match=r"service\.restart_limit: got 0, expected at least 1"):
        _config_with(tmp_path, restart_limit=0)
    with pytest.raises(ConfigError, match=r"service\.restart_window_s: got -1"):
        _config_with(tmp_path, restart_window_s=-1)
    with pytest.raises(ConfigError, match=r"service\.restart_backoff_max_s: got 0\.1, expected at least "
                                          r"service\.restart_backoff_s \(0\.5 s\)"):
        _config_with(tmp_path, restart_backoff_max_s=0.1)
