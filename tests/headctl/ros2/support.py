"""What the ROS 2 tests share: cyclonedds and rosbags, or a failure naming the install step."""
from __future__ import annotations

import importlib

import pytest

INSTALL = "pip install -e '.[ros2,test]'  (cyclonedds has wheels for x86_64 only: docs/ros2.md, on ARM)"


def need(module: str) -> None:
    """Fail (never skip) when `module` is not installed, naming the install step."""
    try:
        importlib.import_module(module)
    except ImportError as err:
        pytest.fail(f"{module} is not installed ({err}): {INSTALL}", pytrace=False)
