"""The daemon's front end seam: started before the head, its URL published, its death the
`api` fault, stopped after the head."""
from __future__ import annotations

import contextlib
import dataclasses
from collections.abc import Iterator

from headctl.service.control import HeadService
from headctl.service.daemon import Daemon
from headctl.service.parts import ServicePhase
from tests.conftest import sim_head_config, wait_until


@dataclasses.dataclass
class FakeFrontEnd:
    url: str = "http://front.example:1"
    error: BaseException | None = None
    alive: bool = True

    def is_alive(self) -> bool:
        return self.alive


def test_a_front_end_serves_from_before_the_head_starts_until_after_it_stopped(tmp_path):
    config = sim_head_config(tmp_path / "state")
    front = FakeFrontEnd()
    seen: dict[str, object] = {}
    daemon: Daemon

    @contextlib.contextmanager
    def serving(service: HeadService) -> Iterator[FakeFrontEnd]:
        seen.setdefault("service", service)
        seen.setdefault("devices at start", daemon.parts.devices)
        yield front
        running = daemon.parts.running
        seen["fixation alive at stop"] = running is not None and running.fixation.is_alive()
        seen["url file at stop"] = config.api_url_path.exists()

    daemon = Daemon(config, front_end=serving)
    with daemon:
        assert seen == {"service": daemon.control, "devices at start": None}
        assert daemon.front_end is front and daemon.api_url == front.url
        assert config.api_url_path.read_text() == front.url + "\n"
        assert daemon.control.snapshot().faults.get("api") is None
        front.alive, front.error = False, RuntimeError("gone")
        wait_until(lambda: daemon.control.snapshot().faults.get("api"), 5.0, "the api fault")
        assert daemon.control.snapshot().faults["api"] == "control API stopped: RuntimeError('gone')"
        # The supervisor makes it again (test_supervision.py); this fake serves again once made.
        wait_until(lambda: daemon.parts.restarts["api-server"] >= 1, 5.0, "the front end made again")
        front.alive, front.error = True, None
    assert daemon.phase is ServicePhase.STOPPED
    assert seen["fixation alive at stop"] is False and seen["url file at stop"] is False
    assert not config.api_url_path.exists()


def test_without_a_front_end_the_service_runs_alone(tmp_path):
    config = sim_head_config(tmp_path / "state")
    with Daemon(config) as daemon:
        assert daemon.front_end is None and daemon.api_url is None
        assert not config.api_url_path.exists()
