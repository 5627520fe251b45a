"""The config's `foxglove:` section: a live view of the head in Foxglove (`headctl.foxglove`).

Off by default. The view is a Foxglove WebSocket server (the `foxglove.websocket.v1`
protocol) at `host`:`port`; the protocol authenticates no one and its data is the eyes'
images, so it listens on loopback unless told otherwise (docs/foxglove.md). The frames it
publishes are made from `ros2.mechanics`, `ros2.frame_prefix` and `ros2.base_frame`, the
description the ROS 2 transforms use, whether or not `ros2.enabled` is set.
"""
from __future__ import annotations

from dataclasses import dataclass

from drivers.config.reader import check_settings, setting
from headctl.config.api import is_host


@dataclass(frozen=True)
class FoxgloveConfig:
    """The `foxglove:` section (docs/foxglove.md, docs/config.md)."""

    enabled: bool = False
    host: str = setting("127.0.0.1", check=is_host, expected="an IP address or a host name")
    # 8766: next to the API's 8765, which is also the Foxglove SDK's own default port
    port: int = setting(8766, lo=0, hi=65535, expected="a TCP port, 0 for an ephemeral one")
    # the eyes' images are sent as JPEG of this quality
    jpeg_quality: int = setting(80, lo=10, hi=100, expected="10 to 100")

    def __post_init__(self) -> None:
        check_settings(self)
