"""Fixtures every test folder shares: the simulated head's config, a service running in this
process, a service in a subprocess (`headctl run`), a manual clock, and waiting with a deadline.

The test folders mirror the packages (`tests/drivers`, `tests/calib_free`, `tests/headctl`,
`tests/headctl/service`); helpers that are not fixtures live in `tests/support`.
"""
from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any, TypeVar

import pytest

from drivers.clock import ManualClock
from headctl.config.head import HeadConfig, load_config
from headctl.api.compose import serve
from headctl.service.daemon import Daemon
from tests.support import SIM_IDEAL
from tests.support.daemon_proc import DaemonProcess

T = TypeVar("T")


def wait_until(predicate: Callable[[], T], timeout_s: float = 5.0, what: str = "condition",
               poll_s: float = 0.005) -> T:
    """Poll `predicate` until it returns something true (returned); fail naming `what` after
    `timeout_s`. For conditions of another thread or process that no event announces."""
    deadline = time.monotonic() + timeout_s
    while True:
        value = predicate()
        if value:
            return value
        if time.monotonic() >= deadline:
            raise AssertionError(f"timed out after {timeout_s} s waiting for {what}")
        time.sleep(poll_s)


def sim_head_config(state_dir: Path, *, frame_timeout_s: float | None = None, realistic: bool = False,
                    **api: Any) -> HeadConfig:
    """The kind simulated head's config (configs/sim-ideal.yaml; `realistic`: the packaged
    configs/sim.yaml) with its state in `state_dir` and the API on an ephemeral port (`api`
    overrides other api keys)."""
    config = load_config(None if realistic else SIM_IDEAL).with_state_dir(state_dir).with_api(port=0, **api)
    if frame_timeout_s is not None:
        fixation = config.fixation
        params = dataclasses.replace(fixation.params, frame_timeout_s=frame_timeout_s)
        config = dataclasses.replace(config, fixation=dataclasses.replace(fixation, params=params))
    return config


@pytest.fixture
def sim_config(tmp_path: Path) -> HeadConfig:
    """The simulated head, its state in this test's temporary directory."""
    return sim_head_config(tmp_path / "state")


@pytest.fixture
def manual_clock() -> ManualClock:
    return ManualClock()


@pytest.fixture(name="wait_until")
def wait_until_fixture() -> Callable[..., Any]:
    return wait_until


@pytest.fixture
def start_service() -> Iterator[Callable[[HeadConfig], Daemon]]:
    """Start a service with its HTTP API in this process (`start_service(config)`: running when it returns);
    every one started is stopped at the end of the test."""
    started: list[Daemon] = []

    def start(config: HeadConfig) -> Daemon:
        daemon = serve(config).start()
        started.append(daemon)
        return daemon

    yield start
    for daemon in reversed(started):
        daemon.stop()


@pytest.fixture
def service_process() -> Iterator[Callable[..., DaemonProcess]]:
    """Start `headctl run` in a subprocess (`service_process(state_dir, config, *args)`);
    every one started is killed at the end of the test if still running."""
    started: list[DaemonProcess] = []

    def start(state_dir: Path, *args: Any, **kwargs: Any) -> DaemonProcess:
        process = DaemonProcess(state_dir, *args, **kwargs)
        started.append(process)
        return process

    yield start
    for process in started:
        process.kill()
