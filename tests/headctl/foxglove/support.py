"""What the Foxglove tests share: foxglove-sdk, or a failure naming the install step."""
from __future__ import annotations

import importlib

import pytest

INSTALL = "pip install -e '.[foxglove,test]'  (./setup.sh installs foxglove-sdk where its wheel exists)"


def need_foxglove() -> None:
    """Fail (never skip) when foxglove-sdk is not installed, naming the install step."""
    try:
        importlib.import_module("foxglove")
    except ImportError as err:
        pytest.fail(f"foxglove-sdk is not installed ({err}): {INSTALL}", pytrace=False)
