"""Stereo pairing of free-running cameras (`FrameMatcher`): the nearest frames within the
tolerance, one to one, in time order, whatever the phase, drift, jitter and lost frames."""
from __future__ import annotations

import numpy as np
import pytest

from drivers.cameras.camera import Frame
from drivers.cameras.config import FrameTimingConfig
from drivers.cameras.stereo import DEFAULT_TOLERANCE_PERIODS, FrameMatcher
from drivers.sim.camera_effects.frame_timing import FrameTiming

FPS = 30.0
PERIOD_S = 1 / FPS
IMAGE = np.zeros((2, 2), np.uint8)


def stream(side: int, phase_s: float, drift_ppm: float, frames: int, drop_rate: float = 0.01,
           jitter_s: float = 0.002) -> list[tuple[float, int, Frame]]:
    """(arrival, side, frame) of one free-running camera."""
    timing = FrameTiming(FrameTimingConfig(model="free_running", phase_s=phase_s, drift_ppm=drift_ppm,
                                           timestamp_jitter_s=jitter_s, drop_rate=drop_rate, late_rate=0.05,
                                           late_s=0.01), FPS, seed=4, eye_index=side)
    out = []
    for n in range(frames):
        slot = timing.slot(n)
        if not slot.dropped:
            frame = Frame(("left", "right")[side], n, IMAGE, slot.timestamp_s, slot.timestamp_s - jitter_s)
            out.append((slot.delivery_s, side, frame))
    return out


@pytest.mark.parametrize("phase_s", [0.0, 0.005, 0.0166, 0.025])
def test_pairs_are_nearest_one_to_one_and_in_order(phase_s):
    # A large drift difference sweeps the offset through a whole period in 40,000 frames.
    events = sorted(stream(0, 0.0, 400.0, 40_000) + stream(1, phase_s, -400.0, 40_000), key=lambda e: e[0])
    matcher = FrameMatcher(DEFAULT_TOLERANCE_PERIODS * PERIOD_S, (PERIOD_S, PERIOD_S), keep=10)
    pairs = [p for _, side, frame in events if (p := matcher.add(side, frame)) is not None]
    lefts = [p.left.counter for p in pairs]
    rights = [p.right.counter for p in pairs]
    # Never a frame twice, never two pairs crossing.
    assert len(set(lefts)) == len(lefts) and len(set(rights)) == len(rights)
    assert lefts == sorted(lefts) and rights == sorted(rights)
    skews = np.array([p.right_lag_s for p in pairs])
    assert np.all(np.abs(skews) <= matcher.tolerance_s)
    # The nearest frame: at most half a period away, give or take the jitter of both stamps.
    assert np.abs(skews).max() <= PERIOD_S / 2 + 0.002 + 1e-9
    # Almost every frame is paired: the lost ones' partners (1 % each) and a few at the turn.
    assert len(pairs) >= 0.975 * min(sum(1 for e in events if e[1] == s) for s in (0, 1))
    stats = matcher.stats()
    assert stats.pairs == len(pairs) and stats.recent == min(len(pairs), 1000)
    assert stats.max_abs_s == pytest.approx(float(np.abs(skews[-1000:]).max()))
    assert sum(stats.unpaired.values()) > 0


def test_a_frame_outside_the_tolerance_is_not_paired():
    matcher = FrameMatcher(0.005, (PERIOD_S, PERIOD_S))
    left = Frame("left", 1, IMAGE, 1.0, 1.0)
    assert matcher.add(0, left) is None
    assert matcher.add(1, Frame("right", 1, IMAGE, 1.006, 1.006)) is None
    pair = matcher.add(0, Frame("left", 2, IMAGE, 1.007, 1.007))
    assert pair is not None and pair.left.counter == 2 and pair.right_lag_s == pytest.approx(-0.001)
    # The first left, older than that pair, can never be paired now.
    assert matcher.add(1, Frame("right", 2, IMAGE, 1.0005, 1.0005)) is None
    assert matcher.stats().unpaired == {"left": 1, "right": 1}
