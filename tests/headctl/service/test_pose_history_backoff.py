"""The pose-history thread of a track backs off while the servo loop gives no state, and
reads every state again once it does."""
from __future__ import annotations

import threading
import time

import numpy as np

from drivers.servo.bus import BusState
from headctl.errors import StaleStateError
from headctl.service.tracking import ServoPoses
from tests.conftest import wait_until


class GoneLoop:
    """A servo loop whose process died: every read fails at once, until `back` is set."""

    def __init__(self) -> None:
        self.reads: list[float] = []
        self.back = threading.Event()
        self.enough = threading.Event()

    def read_state(self) -> BusState:
        self.reads.append(time.monotonic())
        if len(self.reads) >= 6:
            self.enough.set()
        if not self.back.is_set():
            raise StaleStateError("sim-servo-bus(sim:head): no servo state within 1.0 s")
        time.sleep(0.01)  # a servo cycle
        return BusState(time_s=time.monotonic(), joints={})


def test_reads_back_off_while_the_loop_is_gone_and_resume_when_it_answers():
    loop = GoneLoop()
    poses = ServoPoses(loop, lambda positions: np.zeros(3))
    poses.start()
    try:
        assert loop.enough.wait(5.0)
        gaps = np.diff(loop.reads[:6])
        assert all(gap >= 0.95 * least for gap, least in zip(gaps, [0.01, 0.02, 0.04, 0.08, 0.16])), gaps
        loop.back.set()
        # At most one back-off step (0.25 s) later, every state read goes into the history.
        wait_until(lambda: len(poses.history) >= 5, 2.0, "poses read after the loop answered")
    finally:
        poses.stop()
