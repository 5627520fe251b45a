"""The service with its HTTP control API, as `headctl run` runs it.

The daemon (`headctl.service.daemon.Daemon`) knows its front end only as a factory
(`FrontEndFactory`); `api_front_end` is the one that serves the config's API
(`headctl.api.server.ApiServer`), and `serve` composes the two.
"""
from __future__ import annotations

import contextlib
import logging
from collections.abc import Iterator

from drivers.clock import SYSTEM_CLOCK, Clock
from headctl.config.api import ApiConfig, is_loopback
from headctl.config.head import HeadConfig
from headctl.service.control import HeadService
from headctl.service.daemon import Daemon, FrontEnd, FrontEndFactory

log = logging.getLogger(__name__)


def api_front_end(api: ApiConfig) -> FrontEndFactory | None:
    """The front end that serves `api` (None when `api.enabled` is false)."""
    if not api.enabled:
        return None

    @contextlib.contextmanager
    def serving(service: HeadService) -> Iterator[FrontEnd]:
        from headctl.api.server import ApiServer  # FastAPI and uvicorn: only when the API is on

        with ApiServer(service, api.host, api.port, api.token, api.stream_fps, api.jpeg_quality, api.tls_cert,
                       api.tls_key) as server:
            if not api.tls_cert and not is_loopback(api.host):
                log.warning("api: %s is served without TLS: the token crosses the network in clear text "
                            "(set api.tls_cert and api.tls_key, or reach it through an SSH tunnel)", api.host)
            yield server

    return serving


def serve(config: HeadConfig, clock: Clock = SYSTEM_CLOCK) -> Daemon:
    """The service for `config` with the API it configures (not started)."""
    return Daemon(config, clock, front_end=api_front_end(config.api))
