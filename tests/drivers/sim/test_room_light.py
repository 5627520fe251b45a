"""The simulated room's light: constant by default; a lamp switched at its times, daylight
drifting at its rate, mains flicker that a whole number of periods averages away and a short
exposure sees; the config's errors name the key."""
from __future__ import annotations

import numpy as np
import pytest

from drivers.cameras.config import SceneConfig, StereoCamerasConfig
from drivers.clock import ManualClock
from drivers.config.reader import read_config
from drivers.errors import CameraConfigError
from drivers.sim.room import room_scene
from drivers.sim.room_light import CONSTANT_LIGHT, LightConfig, RoomLight, room_light
from drivers.sim.scene import Scene, shared_scene


def light(seed: int = 0, start_s: float = 0.0, **keys: object) -> RoomLight:
    made = room_light(read_config(LightConfig, keys, "cameras.scene.light"), seed, start_s)
    assert isinstance(made, RoomLight)
    return made


def numeric_mean(room: RoomLight, start_s: float, exposure_s: float, samples: int = 20001) -> float:
    """The mean of the instantaneous level over the window, by the trapezoidal rule."""
    t = np.linspace(start_s, start_s + exposure_s, samples)
    level = np.array([room.level_at(x) for x in t])
    return float(np.sum((level[1:] + level[:-1]) / 2.0) / (samples - 1))


# --- constant ----------------------------------------------------------------------------
def test_the_constant_light_is_one_over_any_exposure():
    for start_s, exposure_s in ((0.0, 0.0), (-5.0, 1e-5), (123.456, 1 / 30), (1e6, 10.0)):
        assert CONSTANT_LIGHT.mean_over(start_s, exposure_s) == 1.0
    assert Scene(seed=0, colour=False).light is CONSTANT_LIGHT
    assert room_light(LightConfig(), seed=3) is CONSTANT_LIGHT  # the code default: constant
    assert room_light(LightConfig(model="home", flicker_depth=0.0, daylight_drift_per_min=0.0, lamp_step=0.0),
                      seed=3) is CONSTANT_LIGHT


# --- flicker -------------------------------------------------------------------------------
@pytest.mark.parametrize("mains_hz", [50.0, 60.0])
def test_whole_flicker_periods_average_to_the_mean_and_a_short_exposure_sees_the_depth(mains_hz):
    room = light(mains_hz=mains_hz, flicker_depth=0.3, electric_share=1.0, daylight_range=0.0)
    period_s = 1.0 / (2.0 * mains_hz)  # light follows power: twice the mains frequency
    rng = np.random.default_rng(5)
    for start_s in rng.uniform(0.0, 100.0, 20):
        for periods in (1, 2, 3, 10):
            assert room.mean_over(float(start_s), periods * period_s) == pytest.approx(1.0, abs=1e-9)
    # 20 us exposures at 200 starting times across one period: the lamp's modulation itself.
    seen = [room.mean_over(float(s), 20e-6) for s in np.linspace(7.0, 7.0 + period_s, 200, endpoint=False)]
    depth = (max(seen) - min(seen)) / (max(seen) + min(seen))
    assert depth == pytest.approx(0.3, abs=0.002)
    assert np.mean(seen) == pytest.approx(1.0, abs=1e-3)


def test_an_exposure_of_a_fraction_of_a_period_beats_against_the_flicker():
    room = light(mains_hz=50.0, flicker_depth=0.3, electric_share=1.0, daylight_range=0.0)
    # 1/60 s under 100 Hz flicker: 1.67 periods, the last 0.67 unbalanced.
    seen = [room.mean_over(float(s), 1 / 60) for s in np.linspace(3.0, 3.01, 50, endpoint=False)]
    assert 0.005 < max(seen) - 1.0 < 0.1 and 0.005 < 1.0 - min(seen) < 0.1
    for s in (3.0, 3.0031, 3.0077):
        assert room.mean_over(s, 1 / 60) == pytest.approx(numeric_mean(room, s, 1 / 60), abs=1e-6)


def test_the_window_mean_is_the_integral_of_the_level_with_lamp_steps_and_daylight_inside():
    room = light(model="home", lamp_switches_per_hour=3600.0, daylight_drift_per_min=0.5, flicker_depth=0.4)
    times = room.lamp_switch_times_s(60.0)
    assert len(times) > 20
    windows = [(times[3] - 0.004, 0.011), (times[10] - 0.02, 0.05), (0.5, 0.0333), (-0.01, 0.03)]
    for start_s, exposure_s in windows:
        # The trapezoids straddling a step are off by up to step x spacing / window: 3e-5 here.
        assert room.mean_over(start_s, exposure_s) == pytest.approx(numeric_mean(room, start_s, exposure_s), abs=5e-5)


# --- the lamp ------------------------------------------------------------------------------
def test_the_lamp_steps_the_light_at_its_scheduled_times():
    room = light(start_s=100.0, lamp_step=0.3, lamp_switch_times_s=[10.0, 25.0])  # clock 110 s and 125 s
    assert room.level_at(109.999) == pytest.approx(1.0)
    assert room.level_at(110.001) == pytest.approx(1.3)
    assert room.level_at(124.999) == pytest.approx(1.3)
    assert room.level_at(125.001) == pytest.approx(1.0)
    # An exposure of 40 ms with the switch a quarter of the way in: lit for three quarters of it.
    assert room.mean_over(109.99, 0.04) == pytest.approx(1.0 + 0.75 * 0.3)
    assert room.lamp_switch_times_s(200.0) == [110.0, 125.0]


def test_random_switches_come_at_the_rate_from_the_seed_and_step_the_light():
    room = light(seed=4, lamp_step=0.3, lamp_switches_per_hour=6.0)
    times = room.lamp_switch_times_s(36_000.0)
    assert 30 <= len(times) <= 90  # 60 expected in 10 hours, a Poisson count (sd 7.7)
    assert times == light(seed=4, lamp_step=0.3, lamp_switches_per_hour=6.0).lamp_switch_times_s(36_000.0)
    assert times != light(seed=5, lamp_step=0.3, lamp_switches_per_hour=6.0).lamp_switch_times_s(36_000.0)
    on = False
    for t in times[:10]:
        before, after = room.level_at(t - 1e-3), room.level_at(t + 1e-3)
        assert before == pytest.approx(1.3 if on else 1.0) and after == pytest.approx(1.0 if on else 1.3)
        on = not on


# --- daylight ------------------------------------------------------------------------------
def test_daylight_drifts_at_its_rate_within_its_range():
    room = light(seed=2, daylight_drift_per_min=0.03, daylight_range=0.1)
    level = np.array([room.level_at(float(t)) for t in np.arange(0.0, 7200.0, 1.0)])
    per_s = np.abs(np.diff(level))
    assert per_s.max() <= 0.03 / 60 + 1e-12
    assert np.mean(np.isclose(per_s, 0.03 / 60, rtol=1e-6)) > 0.95  # but where it turns
    assert level.min() >= 0.9 - 1e-9 and level.max() <= 1.1 + 1e-9
    assert np.any(np.diff(np.sign(np.diff(level))) != 0)  # it turns within two hours
    before = [room.level_at(t) for t in (-100.0, -1.0, 0.0)]  # before the start: held
    assert before == [1.0, 1.0, 1.0]


def test_the_light_is_deterministic_per_seed():
    windows = [(float(t), 0.004) for t in np.linspace(0.0, 3600.0, 50)]
    first = [light(seed=9, model="home").mean_over(*w) for w in windows]
    again = light(seed=9, model="home")
    assert [again.mean_over(*w) for w in reversed(windows)][::-1] == first  # whatever the order asked
    assert [light(seed=10, model="home").mean_over(*w) for w in windows] != first


def test_the_room_of_a_config_carries_its_light_from_the_clock_s_now():
    clock = ManualClock(50.0)
    config = read_config(SceneConfig, {"light": {"lamp_step": 0.5, "lamp_switch_times_s": [2.0]}}, "cameras.scene")
    scene = room_scene(config, seed=0, colour=False, clock=clock)
    assert scene.light.mean_over(51.9, 0.0) == pytest.approx(1.0)
    assert scene.light.mean_over(52.1, 0.0) == pytest.approx(1.5)
    shared = shared_scene(0, False)
    assert scene is not shared and shared.light is CONSTANT_LIGHT  # the cached room stays unlit
    assert scene.atlas is shared.atlas
    assert room_scene(SceneConfig(), seed=0, colour=False, clock=clock) is shared


# --- config errors -------------------------------------------------------------------------
@pytest.mark.parametrize(("light_keys", "key"), [
    ({"model": "office"}, "model"),
    ({"flicker_depth": 1.5}, "flicker_depth"),
    ({"mains_hz": 55}, "mains_hz"),
    ({"lamp_step": -0.1}, "lamp_step"),
    ({"lamp_switch_times_s": [5.0, -1.0]}, "lamp_switch_times_s"),
    ({"electric_share": 0.9}, "daylight_range"),  # 0.2 of daylight drift with 0.1 of daylight
    ({"daylight_drift_per_min": 0.02, "daylight_range": 0.0}, "daylight_range"),
    ({"flicker": 0.3}, "light"),  # an unknown key
])
def test_a_bad_light_names_its_key(light_keys, key):
    cameras = {"left": {"backend": "sim", "eye": "left"}, "right": {"backend": "sim", "eye": "right"},
               "scene": {"light": light_keys}}
    with pytest.raises(CameraConfigError) as caught:
        StereoCamerasConfig.from_mapping(cameras)
    assert caught.value.key_path.startswith(f"cameras.scene.light{'' if key == 'light' else '.' + key}")


def test_a_light_needs_simulated_cameras():
    cameras = {"left": {"backend": "opencv", "device": 0}, "right": {"backend": "opencv", "device": 1},
               "scene": {"light": {"model": "home"}}}
    with pytest.raises(CameraConfigError, match="cameras.scene"):
        StereoCamerasConfig.from_mapping(cameras)
