"""Fixtures of the driver tests."""
from __future__ import annotations

from collections.abc import Callable, Iterator
from typing import Any

import pytest

from tests.support.servo_rigs import EmulatorRig, make_rig


@pytest.fixture
def make(request: pytest.FixtureRequest, tmp_path: Any) -> Iterator[Callable[..., Any]]:
    """make(**config) -> an unopened servo-bus rig of the backend the test is parametrised with
    (`@pytest.mark.parametrize("make", [...], indirect=True)`), closed afterwards."""
    rigs = []

    def factory(**config: Any) -> Any:
        rig = make_rig(request.param, tmp_path, **config)
        rigs.append(rig)
        return rig

    yield factory
    for rig in rigs:
        rig.close()


@pytest.fixture
def rig(tmp_path: Any) -> Iterator[Callable[..., EmulatorRig]]:
    """rig(**config) -> an unopened Dynamixel rig on the emulator (Protocol 2.0 unless the
    config says otherwise), closed afterwards."""
    made: list[EmulatorRig] = []

    def factory(**config: Any) -> EmulatorRig:
        r = EmulatorRig(tmp_path, **config)
        made.append(r)
        return r

    yield factory
    for r in made:
        r.close()
