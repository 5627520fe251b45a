"""Frame timing of the simulated cameras: the ideal grid, a free-running pair's phase and
drift, timestamp jitter, lost and late frames, on a manual clock; the config's errors."""
from __future__ import annotations

import threading

import numpy as np
import pytest

from calib_free.sim.head_model import HeadModel
from drivers.cameras.camera import Frame, create_camera
from drivers.cameras.config import CameraConfig, FrameTimingConfig
from drivers.cameras.stereo import StereoPair
from drivers.clock import ManualClock
from drivers.errors import CameraConfigError
from drivers.sim.camera import SimulatedCamera
from drivers.sim.camera_effects.frame_timing import FrameTiming

HEAD = HeadModel.default(160, 120)
REST = {"pan": 0.0, "tilt": 0.0, "left_eye": 2.0, "right_eye": -2.0}
FPS = 30.0


class RecordingPose:
    """A timed pose source that records the times it was asked for."""

    def __init__(self) -> None:
        self.asked: list[float] = []

    def __call__(self) -> dict[str, float]:
        return REST

    def at(self, time_s: float) -> dict[str, float]:
        self.asked.append(time_s)
        return REST


def camera(clock: ManualClock, eye: str, timing: dict, pose: RecordingPose | None = None) -> SimulatedCamera:
    config = CameraConfig.from_mapping({"backend": "sim", "eye": eye, "fps": FPS, "width": 160, "height": 120,
                                        "seed": 5, "history": 64, "timing": timing})
    cam = create_camera(config, clock=clock, head=HEAD, pose_source=pose or RecordingPose(), paced_by_clock=False)
    assert isinstance(cam, SimulatedCamera)
    return cam


def collect(clock: ManualClock, cams: list[SimulatedCamera], until_s: float) -> dict[str, list[tuple[float, Frame]]]:
    """Run the cameras' capture threads to `until_s`, the clock stepped to each frame's
    arrival; (clock at arrival, frame) of each camera. Lost frames never arrive, so each step
    waits for the one frame it expects (late frames here arrive before the next one)."""
    got: dict[str, list[tuple[float, Frame]]] = {c.name: [] for c in cams}
    cond = threading.Condition()

    def listener(name: str):
        def on_frame(frame: Frame | None) -> None:
            if frame is not None:
                with cond:
                    got[name].append((clock.monotonic(), frame))
                    cond.notify_all()
        return on_frame

    for c in cams:
        c.add_listener(listener(c.name))
        c.open()
        c.enable()
    try:
        with cond:  # each camera's first frame: the one exposed by the clock's start
            assert cond.wait_for(lambda: all(got[c.name] for c in cams), timeout=10)
        start_s = clock.monotonic()
        events = []
        for i, c in enumerate(cams):
            index = c.timing.index_at(start_s) + 1
            while c.timing.exposure_start_s(index) <= until_s:
                slot = c.timing.slot(index)
                if not slot.dropped:
                    events.append((slot.delivery_s, i, len(events)))
                index += 1
        counts = [len(got[c.name]) for c in cams]
        for delivery_s, i, _ in sorted(events):
            clock.advance(max(0.0, delivery_s - clock.monotonic()))
            counts[i] += 1
            with cond:
                name = cams[i].name
                assert cond.wait_for(lambda: len(got[name]) >= counts[i], timeout=10), \
                    f"{name}: no frame arrived at t={delivery_s:.6f} s"
    finally:
        for c in cams:
            c.close()
    return got


def index_of(frame: Frame) -> int:
    assert frame.device_time_ns is not None
    return round(frame.device_time_ns * FPS / 1e9)


def test_the_ideal_preset_is_the_clock_grid_in_both_eyes():
    for eye in (0, 1):
        timing = FrameTiming(FrameTimingConfig(), FPS, seed=9, eye_index=eye)
        for n in (0, 1, 7, 29, 30, 123456):
            slot = timing.slot(n)
            assert slot.exposure_start_s == slot.timestamp_s == n / FPS
            assert not slot.dropped and slot.delivery_delay_s == 0.0
        assert timing.index_at(1.0) == 30 and timing.index_at(1.0 - 1e-9) == 29
        assert timing.device_time_ns(3) is None


def test_a_free_running_pair_is_apart_by_its_phases_and_drifts_by_its_ppm():
    clock = ManualClock(1.0)
    jitter_s = 0.002
    left_cfg = {"model": "free_running", "phase_s": 0.004, "drift_ppm": 400.0, "timestamp_jitter_s": jitter_s,
                "drop_rate": 0.0, "late_rate": 0.0}
    right_cfg = {**left_cfg, "phase_s": 0.019, "drift_ppm": -300.0}
    pose = RecordingPose()
    left, right = camera(clock, "left", left_cfg, pose), camera(clock, "right", right_cfg)
    got = collect(clock, [left, right], 11.0)  # 300 frames an eye
    frames = {name: [f for _, f in items[1:]] for name, items in got.items()}
    assert min(len(f) for f in frames.values()) >= 295
    for name, cfg in (("left", left_cfg), ("right", right_cfg)):
        rate_hz = FPS * (1 + cfg["drift_ppm"] * 1e-6)
        n = np.array([index_of(f) for f in frames[name]])
        stamps = np.array([f.time_s for f in frames[name]])
        true_start = cfg["phase_s"] + n / rate_hz
        lag = stamps - true_start
        # Each stamp is within the jitter after the true start, and spread over it.
        assert lag.min() >= -1e-9 and lag.max() <= jitter_s + 1e-9 and lag.std() > jitter_s / 5
        starts = np.array([f.exposure_start_s for f in frames[name]])
        assert np.all(starts <= true_start + 1e-9)  # never later than the true start
        # The rate of the stamps: the nominal rate off by the configured drift.
        slope = np.polyfit(n, stamps, 1)[0]
        assert (1 / slope / FPS - 1) * 1e6 == pytest.approx(cfg["drift_ppm"], abs=10.0)
    # Frame n of each eye, early on: apart by the phases (within the jitter).
    lefts = {index_of(f): f.time_s for f in frames["left"]}
    rights = {index_of(f): f.time_s for f in frames["right"]}
    common = sorted(set(lefts) & set(rights))
    offsets = np.array([rights[k] - lefts[k] for k in common])
    assert abs(offsets[0] - (0.019 - 0.004)) <= jitter_s
    # And the offset drifts: -700 ppm of relative rate over ~10 s is +7 ms.
    drift_s = np.polyfit(np.array(common) / FPS, offsets, 1)[0] * (common[-1] - common[0]) / FPS
    assert drift_s == pytest.approx(700e-6 * (common[-1] - common[0]) / FPS, rel=0.1)
    # Each frame shows the world at its true exposure start, not at its stamp.
    asked = np.array(pose.asked[1:])
    n = np.array([index_of(f) for f in frames["left"]])
    assert np.allclose(asked[-len(n):], 0.004 + n / (FPS * (1 + 400e-6)), atol=1e-9)


def test_drop_and_late_rates_over_many_frames():
    cfg = FrameTimingConfig(model="free_running", drop_rate=0.05, late_rate=0.2, late_s=0.01)
    timing = FrameTiming(cfg, FPS, seed=2, eye_index=1)
    slots = [timing.slot(n) for n in range(20_000)]
    dropped = np.mean([s.dropped for s in slots])
    delays = np.array([s.delivery_delay_s for s in slots])
    assert dropped == pytest.approx(0.05, abs=0.006)  # 4 sigma of 20,000 draws
    assert np.mean(delays > 0) == pytest.approx(0.2, abs=0.012)
    assert delays.max() <= 0.01 and np.mean(delays[delays > 0]) == pytest.approx(0.005, abs=0.0005)
    lags = np.array([s.timestamp_s - s.exposure_start_s for s in slots])
    assert lags.min() >= 0 and lags.max() <= 0.002 and lags.mean() == pytest.approx(0.001, abs=0.0001)
    # The preset's phase and drift: within a period and tens of ppm, different per eye.
    other = FrameTiming(cfg, FPS, seed=2, eye_index=0)
    for t in (timing, other):
        assert 0 <= t.values.phase_s < 1 / FPS and abs(t.values.drift_ppm) <= 30
    assert timing.values.phase_s != other.values.phase_s
    # The same frame asked again is the same frame.
    assert timing.slot(777) == slots[777]


def test_a_camera_loses_its_dropped_frames_and_hands_late_ones_over_late():
    clock = ManualClock(2.0)
    cfg = {"model": "free_running", "drop_rate": 0.1, "late_rate": 0.3, "late_s": 0.02, "timestamp_jitter_s": 0.0}
    cam = camera(clock, "left", cfg)
    got = collect(clock, [cam], 12.0)["left"][1:]
    indices = [index_of(f) for _, f in got]
    expected = range(indices[0], indices[-1] + 1)
    lost = 1 - len(indices) / len(expected)
    assert lost == pytest.approx(0.1, abs=0.05)  # 300 frames: 3 sigma
    assert indices == sorted(indices)
    waits = np.array([arrival - f.time_s for arrival, f in got])  # no jitter: time_s is the exposure start
    assert waits.min() >= 0 and waits.max() <= 0.02
    assert np.mean(waits > 1e-9) == pytest.approx(0.3, abs=0.1)


def test_timing_config_errors_name_the_key():
    with pytest.raises(CameraConfigError, match=r"camera\.timing\.model: got 'synchronised', expected "
                                                 r"'ideal' or 'free_running'"):
        CameraConfig.from_mapping({"eye": "left", "timing": {"model": "synchronised"}})
    with pytest.raises(CameraConfigError, match=r"camera\.timing\.drop_rate: got 0\.9"):
        CameraConfig.from_mapping({"eye": "left", "timing": {"drop_rate": 0.9}})
    with pytest.raises(CameraConfigError, match=r"timing\.timestamp_jitter_s: got 0\.02, expected less than half "
                                                 r"a frame period"):
        FrameTiming(FrameTimingConfig(timestamp_jitter_s=0.02), 30.0)
    # Only the simulated camera takes timing; the default section is no key given.
    with pytest.raises(CameraConfigError, match=r"camera\.timing: .*not used by the 'opencv' backend"):
        create_camera(CameraConfig.from_mapping({"backend": "opencv", "device": 0, "timing": {}}))
    assert "timing" not in CameraConfig.from_mapping({"backend": "opencv", "device": 0}).set_keys()


def test_a_free_running_stereo_pair_reports_its_skew():
    clock = ManualClock(1.0)
    cfg = {"model": "free_running", "phase_s": 0.002, "drift_ppm": 0.0, "drop_rate": 0.0, "late_rate": 0.0}
    left, right = camera(clock, "left", cfg), camera(clock, "right", {**cfg, "phase_s": 0.014})
    pair = StereoPair(left, right)  # the default tolerance: 0.6 of a frame period
    assert pair.tolerance_s == pytest.approx(0.02)
    with pair:
        collect(clock, [left, right], 4.0)
        stats = pair.skew_stats()
        # ~90 frames an eye, 12 ms apart (+- the 2 ms jitter of each stamp).
        assert stats.pairs >= 85 and stats.recent == stats.pairs
        assert stats.mean_s == pytest.approx(0.012, abs=0.001)
        assert stats.max_abs_s is not None and 0.010 <= stats.max_abs_s <= 0.014
        got = pair.wait_pair(after_s=3.5, timeout_s=1.0)
        assert got.right_lag_s == pytest.approx(0.012, abs=0.002) and got.exposure_start_s >= 3.5
