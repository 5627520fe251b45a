"""The service with its HTTP control API, its ROS 2 interface and its Foxglove view, as
`headctl run` runs it.

The daemon (`headctl.service.daemon.Daemon`) knows its front end only as a factory
(`FrontEndFactory`); `api_front_end` is the one that serves the config's API
(`headctl.api.server.ApiServer`), `headctl.ros2.interface.ros2_front_end` the ROS 2 topics,
`headctl.foxglove.view.foxglove_front_end` the live view in Foxglove; `front_ends` makes one
of those the config enables (`Composite`), and `serve` gives it to the daemon.
"""
from __future__ import annotations

import contextlib
import importlib.util
import logging
from collections.abc import Iterator, Sequence

from drivers.clock import SYSTEM_CLOCK, Clock
from headctl.config.api import ApiConfig, is_loopback
from headctl.config.head import HeadConfig
from headctl.foxglove.view import foxglove_front_end
from headctl.ros2.interface import ros2_front_end
from headctl.service.control import HeadService
from headctl.service.daemon import Daemon, FrontEnd, FrontEndFactory

log = logging.getLogger(__name__)


def api_front_end(api: ApiConfig, config: HeadConfig | None = None,
                  clock: Clock = SYSTEM_CLOCK) -> FrontEndFactory | None:
    """The front end that serves `api` (None when `api.enabled` is false), with the
    recordings of `config` (`headctl.ros2.recorder`) when it is given and rosbags is installed."""
    if not api.enabled:
        return None

    @contextlib.contextmanager
    def serving(service: HeadService) -> Iterator[FrontEnd]:
        from headctl.api.server import ApiServer  # FastAPI and uvicorn: only when the API is on

        with contextlib.ExitStack() as stack:
            recordings = None
            if config is not None and importlib.util.find_spec("rosbags") is not None:
                from headctl.ros2.recorder import Recordings

                recordings = stack.enter_context(Recordings(service, config, clock))
            server = stack.enter_context(ApiServer(service, api.host, api.port, api.token, api.stream_fps,
                                                   api.jpeg_quality, api.tls_cert, api.tls_key,
                                                   recordings=recordings))
            if not api.tls_cert and not is_loopback(api.host):
                log.warning("api: %s is served without TLS: the token crosses the network in clear text "
                            "(set api.tls_cert and api.tls_key, or reach it through an SSH tunnel)", api.host)
            yield server

    return serving


class Composite:
    """Several front ends as one: the first's URL (the API's, which clients find in
    `api.url`; '' when there is no API), the first error of any, alive while all are."""

    def __init__(self, parts: Sequence[FrontEnd], has_api: bool) -> None:
        self.parts = tuple(parts)
        self.has_api = has_api

    @property
    def url(self) -> str:
        return self.parts[0].url if self.has_api else ""

    @property
    def error(self) -> BaseException | None:
        return next((p.error for p in self.parts if p.error is not None), None)

    def is_alive(self) -> bool:
        return all(p.is_alive() for p in self.parts)


def front_ends(config: HeadConfig, clock: Clock = SYSTEM_CLOCK) -> FrontEndFactory | None:
    """The front end of what `config` enables: the API, the ROS 2 interface, the Foxglove view,
    any of them or none. The API alone is given to the daemon as it is."""
    api = api_front_end(config.api, config, clock)
    others = [f for f in (ros2_front_end(config, clock), foxglove_front_end(config, clock)) if f is not None]
    if not others:
        return api
    makers = [f for f in (api, *others) if f is not None]

    @contextlib.contextmanager
    def serving(service: HeadService) -> Iterator[FrontEnd]:
        with contextlib.ExitStack() as stack:
            yield Composite([stack.enter_context(make(service)) for make in makers], has_api=api is not None)

    return serving


def serve(config: HeadConfig, clock: Clock = SYSTEM_CLOCK) -> Daemon:
    """The service for `config` with the front ends it configures (not started)."""
    return Daemon(config, clock, front_end=front_ends(config, clock))
