"""The ROS 2 interface as a front end of the daemon (`headctl.service.daemon.FrontEnd`).

`Ros2Interface` opens the node (`headctl.ros2.node`), makes the streams' writers
(`headctl.ros2.streams`), the command readers when `ros2.commands` is true
(`headctl.ros2.commands`) and `/head/gaze_state`, announces the node, and starts the threads;
leaving its context stops them and deletes the participant. It is entered before the head
starts (the daemon's front ends serve from before the head runs until after it stopped), so
every stream copes with a service not yet, or no longer, running.

`ros2_front_end` is the factory the daemon takes; it needs `cyclonedds` (the `ros2` extra),
imported only when the section is enabled: `headctl check` names the install step when it is
missing (`missing_dependency`).
"""
from __future__ import annotations

import contextlib
import importlib.util
import logging
from collections.abc import Iterator
from typing import TYPE_CHECKING

from drivers.clock import SYSTEM_CLOCK, Clock
from headctl.config.head import HeadConfig
from headctl.service.control import HeadService

if TYPE_CHECKING:
    from headctl.ros2.commands import CommandThread
    from headctl.ros2.node import Ros2Node
    from headctl.ros2.streams import Streams
    from headctl.service.daemon import FrontEnd, FrontEndFactory

log = logging.getLogger(__name__)

INSTALL_HINT = ("pip install 'headctl[ros2]' (cyclonedds: wheels for x86_64; on ARM build it against Debian's "
                "cyclonedds-dev, docs/ros2.md)")


def missing_dependency() -> str | None:
    """Why the ROS 2 interface cannot run here (cyclonedds missing), or None."""
    if importlib.util.find_spec("cyclonedds") is None:
        return f"ros2.enabled is true but cyclonedds is not installed: {INSTALL_HINT}"
    return None


class Ros2Interface:
    """The node, its streams and commands over one service; see the module docstring."""

    def __init__(self, service: HeadService, config: HeadConfig, clock: Clock = SYSTEM_CLOCK) -> None:
        self.service = service
        self.config = config.ros2
        self.servo_rate_hz = config.service.servo_rate_hz
        self.clock = clock
        self.node: Ros2Node | None = None
        self.streams: Streams | None = None
        self.commands: CommandThread | None = None
        self._stack = contextlib.ExitStack()

    @property
    def url(self) -> str:
        cfg = self.config
        return f"ros2://domain/{cfg.domain_id}{cfg.namespace}/{cfg.node_name}"

    @property
    def error(self) -> BaseException | None:
        if self.commands is not None and self.commands.error is not None:
            return self.commands.error
        return None

    def is_alive(self) -> bool:
        threads = [*(self.streams.threads if self.streams else ()), *([self.commands] if self.commands else [])]
        return bool(threads) and all(t.is_alive() for t in threads)

    def __enter__(self) -> "Ros2Interface":
        try:
            self._start()
        except BaseException:
            self._stack.close()
            raise
        return self

    def __exit__(self, *exc: object) -> None:
        self._stack.close()

    def _start(self) -> None:
        from headctl.ros2.commands import GAZE_STATE, CommandThread, GazeState
        from headctl.ros2.node import Ros2Node
        from headctl.ros2.streams import Streams

        cfg = self.config
        node = self.node = self._stack.enter_context(Ros2Node(cfg))
        streams = self.streams = Streams(node, self.service, cfg, self.servo_rate_hz, self.clock)
        gaze = GazeState(node.writer(GAZE_STATE), cfg.frame_prefix)
        commands = None
        if cfg.commands:
            commands = self.commands = CommandThread(node, self.service, gaze, streams.frames.optical["left"])
        node.announce()
        self._stack.callback(self.service.events.subscribe(gaze.on_event))
        streams.start()
        self._stack.callback(streams.stop)
        if commands is not None:
            commands.start()
            self._stack.callback(commands.stop)
        log.info("ros2: publishing on %s%s", self.url,
                 ", commands accepted (ros2.commands: true)" if commands else ", commands off")


def ros2_front_end(config: HeadConfig, clock: Clock = SYSTEM_CLOCK) -> "FrontEndFactory | None":
    """The front end serving `config.ros2` (None when it is off)."""
    if not config.ros2.enabled:
        return None

    @contextlib.contextmanager
    def serving(service: HeadService) -> Iterator["FrontEnd"]:
        missing = missing_dependency()
        if missing is not None:
            from headctl.errors import HeadctlError

            raise HeadctlError(missing)
        with Ros2Interface(service, config, clock) as interface:
            yield interface

    return serving
