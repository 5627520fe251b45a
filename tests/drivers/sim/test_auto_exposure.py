"""The simulated camera's auto exposure and gain (`drivers.sim.camera_effects.auto_exposure`): the lag after a
change of brightness, locked across a saccade, manual, and what the camera declares."""
from __future__ import annotations

import math

import numpy as np
import pytest

from drivers.cameras.camera import ExposureMode
from drivers.sim.camera import SimulatedCamera
from drivers.sim.scene import Marker
from tests.support.sim_camera import REST, sim_camera, wall_scene

FPS = 30.0
TARGET = 0.45
SPEED = 0.3
# The ideal camera but for its auto exposure: its mean level is the light it gathers.
AE = {"auto_exposure": True, "ae_target": TARGET, "ae_speed": SPEED, "ae_max_step_ev": 1.0, "max_gain_db": 12.0}


class StepLight:
    """The room's light, `after` times brighter for exposures starting from `at_s`."""

    def __init__(self, at_s: float, after: float) -> None:
        self.at_s, self.after = at_s, after

    def mean_over(self, start_s: float, exposure_s: float) -> float:
        return self.after if start_s >= self.at_s else 1.0


def _frames(camera: SimulatedCamera, first: int, count: int, joints=REST) -> list[float]:
    """Mean levels (fractions of full scale) of frames first..first+count-1, one after another."""
    return [float(camera.render(joints, n / FPS).mean()) / 255.0 for n in range(first, first + count)]


def _settled_after(error_stops: float) -> int:
    """Frames the controller needs to bring an error of `error_stops` within 5 %: it corrects
    SPEED of the remaining error (in stops) each frame."""
    return math.ceil(math.log(math.log2(1.05) / abs(error_stops)) / math.log(1.0 - SPEED))


def test_auto_exposure_settles_a_few_frames_after_the_light_doubles():
    scene = wall_scene()
    scene.light = StepLight(at_s=40 / FPS, after=2.0)
    with sim_camera(AE, scene=scene, fps=FPS) as camera:
        before = _frames(camera, 0, 40)
        settled = camera.exposure_state
        after = _frames(camera, 40, 20)
    assert before[-1] == pytest.approx(TARGET, rel=0.01)
    assert after[0] == pytest.approx(2 * TARGET, rel=0.02)  # the frame the light changed in: not yet
    for n, level in enumerate(after):  # the error in stops falls by (1 - SPEED) a frame
        assert math.log2(level / TARGET) == pytest.approx((1 - SPEED) ** n, abs=0.02), n
    lag = _settled_after(1.0)
    assert abs(after[lag - 1] / TARGET - 1) > 0.05 and abs(after[lag] / TARGET - 1) < 0.05
    assert camera.exposure_state.exposure_us == pytest.approx(settled.exposure_us / 2, rel=0.02)


def test_in_the_dark_exposure_goes_to_its_longest_then_gain_rises():
    scene = wall_scene()
    scene.light = StepLight(at_s=0.0, after=0.1)
    with sim_camera(AE, scene=scene, fps=FPS) as camera:
        levels = _frames(camera, 0, 60)
        state = camera.exposure_state
    assert levels[-1] == pytest.approx(TARGET, rel=0.02)
    assert state.exposure_us == pytest.approx(33_000.0)  # max_exposure_us, within the 33.3 ms frame period
    needed = TARGET / (levels[0] / 1.0)  # light to gather, relative to the first frame's (reference) exposure
    assert state.gain == pytest.approx(needed * 10_000.0 / 33_000.0, rel=0.03) and state.gain_db < 12.0


def _saccade_scene():
    """Straight ahead a dark wall (grey 90); behind the head (pan 180) a bright one (about 160)."""
    return wall_scene(markers=[Marker((0.4, 0.0, 0.0), 3.0, (90, 90, 90))])


def test_a_locked_exposure_holds_across_a_saccade_to_a_brighter_place_then_settles_after_unlock():
    behind = {**REST, "pan": 180.0}
    with sim_camera(AE, scene=_saccade_scene(), fps=FPS) as camera:
        ahead = _frames(camera, 0, 40)
        assert ahead[-1] == pytest.approx(TARGET, rel=0.01)
        camera._lock_exposure()
        held = camera.exposure_state
        assert held.mode is ExposureMode.LOCKED
        locked = _frames(camera, 40, 30, behind)
        assert camera.exposure_state == held
        camera._unlock_exposure()
        assert camera.exposure_state.mode is ExposureMode.AUTO
        free = _frames(camera, 70, 20, behind)
    assert locked[0] > 1.5 * TARGET  # the brighter place, at the dark place's exposure
    assert max(locked) - min(locked) < 0.002  # held: no frame adapts
    first_error = math.log2(locked[-1] / TARGET)
    lag = _settled_after(first_error)
    # The frame after the unlock is already one step on (from the last locked frame's metering).
    assert abs(free[0] / TARGET - 1) > 0.3
    assert abs(free[lag - 2] / TARGET - 1) > 0.05 and abs(free[lag - 1] / TARGET - 1) < 0.05


def test_a_manual_exposure_and_gain_hold_and_scale_the_signal():
    scene = wall_scene()
    with sim_camera(AE, scene=scene, fps=FPS) as camera, sim_camera({}, scene=scene, fps=FPS) as ideal:
        reference = float(ideal.render(REST, 0.0).mean())
        camera._set_exposure_us(5000.0)
        camera._set_gain_db(20 * math.log10(1.5))
        levels = [float(camera.render(REST, n / FPS).mean()) for n in range(10)]
        assert camera.exposure_state.mode is ExposureMode.MANUAL
        assert camera.exposure_state.exposure_us == 5000.0
        camera._set_exposure_us(1.0)  # within the frame period: taken as it is
        assert camera.exposure_state.exposure_us == 1.0
        camera._set_exposure_us(1e6)  # longer than the 33 ms frame period: the period
        assert camera.exposure_state.exposure_us == pytest.approx(1e6 / FPS)
    assert np.allclose(levels, reference * 0.5 * 1.5, atol=0.6)


def test_frames_not_rendered_ran_the_auto_exposure_on_the_view_rendered():
    """The synchronous renders of the online experiments skip frames: the auto exposure runs
    on through them (as if they saw the view now rendered), so a frame after a long gap is
    settled and one right after a change is not."""
    behind = {**REST, "pan": 180.0}
    with sim_camera(AE, scene=_saccade_scene(), fps=FPS) as camera:
        ahead = _frames(camera, 0, 40)
        late = _frames(camera, 60, 1, behind)[0]  # 20 frames later, looking elsewhere
        soon = _frames(camera, 61, 1, REST)[0]  # the next frame, looking back
    assert ahead[-1] == pytest.approx(TARGET, rel=0.01)
    assert late == pytest.approx(TARGET, rel=0.05)
    assert soon < 0.8 * TARGET


def test_the_simulated_camera_declares_its_exposure_controls():
    capabilities = SimulatedCamera.capabilities
    assert capabilities.exposure and capabilities.gain and capabilities.exposure_lock
    with sim_camera({}) as ideal:  # the ideal camera's exposure never moves by itself
        levels = {round(float(ideal.render({**REST, "pan": pan}, n / FPS).mean()), 3)
                  for n, pan in enumerate((0, 180, 0, 180))}
        assert ideal.exposure_state.exposure_us == 10_000.0 and ideal.exposure_state.gain_db == 0.0
    assert len(levels) == 2
