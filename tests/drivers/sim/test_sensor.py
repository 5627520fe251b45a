"""The simulated camera's photometry (`drivers.sim.camera_effects.sensor`) and its `sensor:` config: each
effect at the size configured, none in the ideal camera."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from scipy.optimize import curve_fit

from calib_free.sim.head_model import HeadModel
from drivers.backends import check_camera_config
from drivers.cameras.camera import create_camera
from drivers.cameras.config import CameraConfig
from drivers.cameras.opencv import OpenCVCamera
from drivers.clock import ManualClock
from drivers.errors import CameraConfigError
from drivers.sim.camera import SimulatedCamera
from drivers.sim.scene import EyeRenderer, Scene
from drivers.sim.camera_effects.sensor import SensorPipeline
from drivers.sim.camera_effects.sensor_config import SENSOR_PRESETS, SensorParams
from tests.support.sim_camera import REST, sim_camera, wall_scene

LENS = HeadModel.default(160, 120).lens_left


# --- config --------------------------------------------------------------------------------
def test_the_ideal_preset_is_the_default_and_a_model_takes_overrides():
    plain = CameraConfig.from_mapping({"backend": "sim", "eye": "left"})
    assert plain.sensor.params() == SensorParams() and not plain.sensor.params().exposure_moves
    webcam = CameraConfig.from_mapping({"backend": "sim", "eye": "left",
                                        "sensor": {"model": "uvc_webcam", "jpeg_quality": 60, "roll_deg": -1.5}})
    expected = dataclasses.replace(SENSOR_PRESETS["uvc_webcam"], jpeg_quality=60, roll_deg=-1.5)
    assert webcam.sensor.params() == expected
    assert webcam.sensor.params().auto_exposure and webcam.sensor.params().full_well_e is not None


@pytest.mark.parametrize("sensor, key, words", [
    ({"vignetting": 1.5}, "cameras.left.sensor.vignetting", "0.95"),
    ({"model": "dslr"}, "cameras.left.sensor.model", "uvc_webcam"),
    ({"read_noise_e": 3.0}, "cameras.left.sensor.read_noise_e", "full_well_e"),
    ({"centre_offset_px": [3, 500]}, "cameras.left.sensor.centre_offset_px", "200"),
    ({"blur": True}, "cameras.left.sensor.blur", "motion_blur"),
])
def test_a_bad_sensor_value_names_its_key(sensor, key, words):
    with pytest.raises(CameraConfigError) as caught:
        CameraConfig.from_mapping({"backend": "sim", "eye": "left", "sensor": sensor}, key_path="cameras.left")
    assert caught.value.key_path == key and words in str(caught.value)


def test_only_the_simulated_camera_takes_a_sensor_section():
    config = CameraConfig.from_mapping({"backend": "opencv", "device": 0, "sensor": {"model": "ideal"}})
    with pytest.raises(CameraConfigError, match="sensor"):
        check_camera_config(config, OpenCVCamera)
    assert "sensor" not in CameraConfig.from_mapping({"backend": "opencv", "device": 0}).set_keys()


# --- vignetting ----------------------------------------------------------------------------
def test_a_flat_wall_darkens_toward_the_corners_by_the_fraction_configured():
    scene = wall_scene()
    images = {}
    for name, sensor in (("ideal", {}), ("vignetted", {"vignetting": 0.4})):
        with sim_camera(sensor, scene=scene) as camera:
            images[name] = camera.render(REST, 0.0).astype(float)
    flat, dark = images["ideal"], images["vignetted"]
    assert flat.std() < 2.0 and flat.mean() > 100  # the wall fills the view, evenly lit
    ratio = dark / flat
    h, w = ratio.shape
    for y, x in ((0, 0), (0, w - 2), (h - 2, 0), (h - 2, w - 2)):
        assert ratio[y:y + 2, x:x + 2].mean() == pytest.approx(0.6, abs=0.015), (y, x)
    assert ratio[h // 2 - 2:h // 2 + 2, w // 2 - 2:w // 2 + 2].mean() == pytest.approx(1.0, abs=0.01)
    diagonal = [ratio[int(f * (h - 1)), int(f * (w - 1))] for f in (0.5, 0.35, 0.2, 0.1, 0.0)]
    assert all(a > b for a, b in zip(diagonal, diagonal[1:])), diagonal


# --- this unit's response --------------------------------------------------------------------
def _response(x, gain, offset, gamma):
    return offset + 255.0 * np.clip(gain * x / 255.0, 0.0, 1.0) ** gamma


def test_each_eye_has_its_own_gain_offset_and_gamma_within_the_spreads():
    params = SensorParams(gain_spread=0.06, offset_spread=4.0, gamma_spread=0.08)
    ramp = np.tile(np.linspace(8.0, 200.0, 160, dtype=np.float32), (4, 1))
    fitted = []
    for eye in (0, 1):
        image, _ = SensorPipeline(params, LENS, LENS, seed=7, eye=eye).expose(ramp, 1.0, 1.0, index=0)
        (gain, offset, gamma), _ = curve_fit(_response, ramp[0], image.mean(axis=0), p0=(1.0, 0.0, 1.0))
        assert abs(gain - 1) <= 0.06 + 0.01 and abs(offset) <= 4.0 + 0.6 and abs(gamma - 1) <= 0.08 + 0.01
        fitted.append(np.array([gain, offset, gamma]))
    assert np.abs(fitted[0] - fitted[1]).max() > 0.5 or np.abs(fitted[0] - fitted[1])[[0, 2]].max() > 0.01
    again, _ = SensorPipeline(params, LENS, LENS, seed=7, eye=1).expose(ramp, 1.0, 1.0, index=0)
    other, _ = SensorPipeline(params, LENS, LENS, seed=8, eye=1).expose(ramp, 1.0, 1.0, index=0)
    first, _ = SensorPipeline(params, LENS, LENS, seed=7, eye=1).expose(ramp, 1.0, 1.0, index=0)
    assert np.array_equal(again, first) and not np.array_equal(other, first)


def test_the_two_cameras_of_a_webcam_head_render_one_wall_differently():
    scene = wall_scene()
    sensor = {"gain_spread": 0.05, "offset_spread": 3.0, "gamma_spread": 0.05}
    means = []
    for eye in ("left", "right"):
        with sim_camera(sensor, eye=eye, scene=scene) as camera, sim_camera({}, eye=eye, scene=scene) as ideal:
            means.append(camera.render(REST, 0.0).mean() - ideal.render(REST, 0.0).mean())
    assert abs(means[0] - means[1]) > 1.0, means


# --- noise ---------------------------------------------------------------------------------
@pytest.mark.parametrize("level", [10.0, 60.0, 150.0, 230.0])
def test_shot_and_read_noise_have_the_variance_of_their_electrons(level):
    full_well, read = 4000.0, 8.0
    pipeline = SensorPipeline(SensorParams(full_well_e=full_well, read_noise_e=read), LENS, LENS, seed=0, eye=0)
    flat = np.full((240, 320), level, np.float32)
    image, _ = pipeline.expose(flat, 1.0, 1.0, index=3)
    electrons = level / 255.0 * full_well
    expected_std = np.sqrt(electrons + read ** 2) * 255.0 / full_well
    assert image.mean() == pytest.approx(level, abs=0.1)
    assert image.astype(float).std() == pytest.approx(np.sqrt(expected_std ** 2 + 1 / 12), rel=0.05)
    same, _ = pipeline.expose(flat, 1.0, 1.0, index=3)
    later, _ = pipeline.expose(flat, 1.0, 1.0, index=4)
    assert np.array_equal(same, image) and not np.array_equal(later, image)


def test_the_noise_of_two_frames_or_two_eyes_is_uncorrelated_where_a_matcher_looks():
    """Two frames' (and two eyes') noise, compared pixel for pixel and at every shift a 21 x 21
    match might test (up to +-10 px), correlates no more than independent noise does."""
    params = SensorParams(full_well_e=4000.0, read_noise_e=8.0)
    flat = np.full((240, 320), 100.0, np.float32)
    left, right = (SensorPipeline(params, LENS, LENS, seed=0, eye=eye) for eye in (0, 1))
    noise = [left.expose(flat, 1.0, 1.0, index=i)[0].astype(np.float32) - 100.0 for i in (0, 1, 7)]
    noise.append(right.expose(flat, 1.0, 1.0, index=0)[0].astype(np.float32) - 100.0)
    worst = 0.0
    for a, b in ((0, 1), (0, 2), (0, 3)):  # frames 0 and 1, frames 0 and 7, the two eyes
        for dy in range(-10, 11):
            for dx in range(-10, 11):
                u = noise[a][20:220, 20:300]
                v = noise[b][20 + dy:220 + dy, 20 + dx:300 + dx]
                worst = max(worst, abs(float(np.corrcoef(u.ravel(), v.ravel())[0, 1])))
    # 56,000 pixels: independent noise's correlation has a standard deviation of 0.004; the
    # largest of 1,323 such is about 0.014.
    assert worst < 0.025


def test_gain_amplifies_the_noise_and_a_short_exposure_darkens():
    pipeline = SensorPipeline(SensorParams(full_well_e=4000.0, read_noise_e=8.0), LENS, LENS, seed=0, eye=0)
    flat = np.full((240, 320), 100.0, np.float32)
    base, _ = pipeline.expose(flat, 1.0, 1.0, index=0)
    half, _ = pipeline.expose(flat, 0.5, 1.0, index=0)
    boosted, _ = pipeline.expose(flat, 0.5, 2.0, index=0)
    assert half.mean() == pytest.approx(50.0, abs=0.2) and boosted.mean() == pytest.approx(100.0, abs=0.3)
    assert boosted.std() > 1.3 * base.std()  # the same level from half the electrons


# --- MJPEG ---------------------------------------------------------------------------------
def test_mjpeg_artefacts_grow_as_the_quality_drops():
    scene = Scene(seed=3, colour=False)
    joints = {"pan": 5.0, "tilt": -3.0, "left_eye": 2.0, "right_eye": -2.0}
    with sim_camera({}, scene=scene) as ideal:
        raw = ideal.render(joints, 0.0).astype(float)
    errors = []
    for quality in (95, 75, 40, 10):
        with sim_camera({"jpeg_quality": quality}, scene=scene) as camera:
            decoded = camera.render(joints, 0.0).astype(float)
        errors.append(float(np.sqrt(np.mean((decoded - raw) ** 2))))
    assert errors[0] > 0.3 and all(a < b for a, b in zip(errors, errors[1:])), errors
    # At low quality the 8 x 8 blocks show: the image jumps across their edges, smooth within.
    steps = np.abs(np.diff(decoded, axis=1))
    assert steps[:, 7::8].mean() > 1.3 * np.delete(steps, np.s_[7::8], axis=1).mean()


def test_the_ideal_camera_shows_the_render_as_it_is():
    scene = Scene(seed=3, colour=False)
    joints = {"pan": 5.0, "tilt": -3.0, "left_eye": 2.0, "right_eye": -2.0}
    camera = sim_camera({}, scene=scene)
    with camera:
        image = camera.render(joints, 0.0)
        assert camera.unit_lens is camera.lens
    config = CameraConfig.from_mapping({"backend": "sim", "eye": "left", "width": 160, "height": 120})
    plain = create_camera(config, head=HeadModel.default(160, 120), pose_source=lambda: REST, scene=scene)
    assert isinstance(plain, SimulatedCamera)
    with plain:
        rotation, centre = plain.head.eye_frames_from_joints(5.0, -3.0, 2.0, -2.0)[0]
        assert np.array_equal(image, EyeRenderer(plain.lens, scene).render(rotation, centre, 0.0))


def test_the_capture_thread_and_render_make_the_same_webcam_frame():
    """Both paths go through one image pipeline: a streamed frame is what `render()` gives for
    its time, lens, vignetting, noise, MJPEG and all."""
    scene = Scene(seed=3, colour=False)
    joints = {"pan": 5.0, "tilt": -3.0, "left_eye": 2.0, "right_eye": -2.0}
    streamed = sim_camera({"model": "uvc_webcam"}, scene=scene, pose=lambda: joints, clock=ManualClock(1.0))
    rendered = sim_camera({"model": "uvc_webcam"}, scene=scene, pose=lambda: joints)
    with streamed, rendered:
        streamed.enable()
        frame = streamed.wait_frame(after_s=0.0, timeout_s=5.0)  # however early it came
        image = rendered.render(joints, frame.exposure_start_s)
    with sim_camera({}, scene=scene) as ideal:
        plain = ideal.render(joints, frame.exposure_start_s)
    assert frame.exposure_start_s == 1.0 and np.array_equal(frame.image, image)
    assert np.abs(image.astype(float) - plain).mean() > 2.0  # and it is not the ideal camera's
