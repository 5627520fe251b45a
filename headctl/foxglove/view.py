"""The live view in Foxglove as a front end of the daemon (`headctl.service.daemon.FrontEnd`).

`foxglove_front_end` is the factory the daemon takes (None while `foxglove.enabled` is false).
It needs foxglove-sdk (the `foxglove` extra), imported only when the view starts, so the
service installs and runs without it; `headctl check` and `headctl run` name the install step
when the section is on and the package is missing (`missing_dependency`). The view is entered
before the head starts and left after it stopped, like every front end, so its thread copes
with a service not yet, or no longer, running.
"""
from __future__ import annotations

import contextlib
import importlib.util
import logging
from collections.abc import Iterator
from typing import TYPE_CHECKING

from drivers.clock import SYSTEM_CLOCK, Clock
from headctl.config.api import is_loopback
from headctl.config.head import HeadConfig
from headctl.errors import HeadctlError
from headctl.service.control import HeadService

if TYPE_CHECKING:
    from headctl.foxglove.server import Publisher
    from headctl.service.daemon import FrontEnd, FrontEndFactory

log = logging.getLogger(__name__)

INSTALL_HINT = "pip install 'headctl[foxglove]' (foxglove-sdk; ./setup.sh installs it where its wheel exists)"


def missing_dependency() -> str | None:
    """Why the view cannot run here (foxglove-sdk missing), or None."""
    if importlib.util.find_spec("foxglove") is None:
        return f"foxglove.enabled is true but foxglove-sdk is not installed: {INSTALL_HINT}"
    return None


class FoxgloveView:
    """The Foxglove WebSocket server of one service while its context is entered."""

    def __init__(self, service: HeadService, config: HeadConfig, clock: Clock = SYSTEM_CLOCK) -> None:
        self.service = service
        self.config = config
        self.clock = clock
        self.publisher: Publisher | None = None

    @property
    def url(self) -> str:
        cfg = self.config.foxglove
        port = self.publisher.port if self.publisher is not None else cfg.port
        host = f"[{cfg.host}]" if ":" in cfg.host else cfg.host
        return f"ws://{host}:{port}"

    @property
    def error(self) -> BaseException | None:
        return None

    def is_alive(self) -> bool:
        return self.publisher is not None and self.publisher.thread.is_alive()

    def __enter__(self) -> "FoxgloveView":
        missing = missing_dependency()
        if missing is not None:
            raise HeadctlError(missing)
        from headctl.foxglove.server import Publisher

        self.publisher = Publisher(self.service, self.config, self.clock)
        self.publisher.start()
        cfg = self.config.foxglove
        if not is_loopback(cfg.host):
            log.warning("foxglove: %s serves the eyes' images to anyone who reaches it (the Foxglove WebSocket "
                        "protocol authenticates no one): keep it on loopback and use an SSH tunnel", cfg.host)
        log.info("foxglove: live view on %s (docs/foxglove.md)", self.url)
        return self

    def __exit__(self, *exc: object) -> None:
        if self.publisher is not None:
            self.publisher.stop()


def foxglove_front_end(config: HeadConfig, clock: Clock = SYSTEM_CLOCK) -> "FrontEndFactory | None":
    """The front end serving `config.foxglove` (None when it is off)."""
    if not config.foxglove.enabled:
        return None

    @contextlib.contextmanager
    def serving(service: HeadService) -> Iterator["FrontEnd"]:
        with FoxgloveView(service, config, clock) as view:
            yield view

    return serving
