"""Each eye's lens as its unit has it (`drivers.sim.camera_effects.lens_error`): a known point lands where the
unit's focal length, principal point and roll put it, while the head model keeps the
nominal lens."""
from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from drivers.sim.camera_effects.lens_error import ErredLens, LensError, draw_lens_error
from drivers.sim.scene import Marker
from drivers.sim.camera_effects.sensor_config import SENSOR_PRESETS
from tests.drivers.sim.test_camera_geometry import marker_centroid
from tests.support.sim_camera import REST, sim_camera, wall_scene

WALL_M = 0.6
MARKERS = [Marker((WALL_M, 0.12, 0.1), 0.02, (0, 0, 255)), Marker((WALL_M, -0.2, -0.1), 0.02, (0, 255, 0)),
           Marker((WALL_M, 0.25, -0.2), 0.02, (255, 0, 0))]


def _where_the_unit_puts(uv_nominal, centre, scale, offset, roll_deg):
    """The definition: the nominal pixel scaled about the principal point, turned by the roll
    (clockwise as seen for a positive angle, image y down), then shifted."""
    a = math.radians(roll_deg)
    dx, dy = uv_nominal[0] - centre[0], uv_nominal[1] - centre[1]
    return (centre[0] + offset[0] + scale * (math.cos(a) * dx - math.sin(a) * dy),
            centre[1] + offset[1] + scale * (math.sin(a) * dx + math.cos(a) * dy))


@pytest.mark.parametrize("eye", ["left", "right"])
def test_a_known_point_lands_where_the_units_lens_puts_it(eye):
    error = {"focal_scale": 1.03, "centre_offset_px": [8.0, -5.0], "roll_deg": 2.0} if eye == "left" else \
            {"focal_scale": 0.975, "centre_offset_px": [-6.0, 9.0], "roll_deg": -1.5}
    scene = wall_scene(WALL_M, colour=True, markers=MARKERS)
    camera = sim_camera(error, eye=eye, size=(320, 240), image="colour", scene=scene)
    with camera:
        image = camera.render(REST, 0.0)
    rotation, centre = camera.head.eye_frames_from_joints(0.0, 0.0, 0.0, 0.0)[camera.eye_index]
    principal = ((320 - 1) / 2, (240 - 1) / 2)
    moved = []
    for marker in MARKERS:
        uv, seen = camera.lens.project((np.array([marker.point]) - centre) @ rotation.T)  # the nominal lens
        assert seen[0]
        found = marker_centroid(image, int(np.argmax(marker.colour_bgr)))
        assert found is not None
        expected = _where_the_unit_puts(uv[0], principal, error["focal_scale"], error["centre_offset_px"],
                                        error["roll_deg"])
        assert np.hypot(found[0] - expected[0], found[1] - expected[1]) < 0.6, (marker.point, found, expected)
        moved.append(np.hypot(found[0] - uv[0, 0], found[1] - uv[0, 1]))
    assert min(moved) > 4.0, moved  # where the nominal lens says it is not


def test_each_eye_draws_its_own_lens_within_the_ranges():
    params = SENSOR_PRESETS["uvc_webcam"]
    left, right = draw_lens_error(params, seed=4, eye=0), draw_lens_error(params, seed=4, eye=1)
    for error in (left, right):
        assert abs(error.focal_scale - 1) <= params.focal_error
        assert max(abs(c) for c in error.centre_offset_px) <= params.centre_error_px
        assert abs(error.roll_deg) <= params.roll_error_deg
    assert left != right
    assert draw_lens_error(params, seed=4, eye=0) == left and draw_lens_error(params, seed=5, eye=0) != left
    draws = [draw_lens_error(params, seed, 0) for seed in range(200)]
    assert max(abs(d.focal_scale - 1) for d in draws) > 0.8 * params.focal_error  # the range is used
    given = draw_lens_error(dataclasses.replace(params, roll_deg=1.25), seed=4, eye=0)
    assert given.roll_deg == 1.25 and given.focal_scale == left.focal_scale
    camera = sim_camera({"model": "uvc_webcam"}, eye="right", seed=4)
    assert isinstance(camera.unit_lens, ErredLens) and camera.unit_lens.error == right


def test_the_units_lens_unprojects_what_it_projects_and_moves_its_image_circle():
    camera = sim_camera({})
    nominal = camera.lens
    lens = ErredLens(nominal, LensError(1.02, (10.0, -4.0), 1.5))
    rng = np.random.default_rng(0)
    points = rng.normal(0.0, 0.4, (200, 3)) + [0.0, 0.0, 1.0]
    uv, seen = lens.project(points)
    rays = lens.unproject(uv[seen])
    directions = points[seen] / np.linalg.norm(points[seen], axis=1, keepdims=True)
    assert seen.sum() > 100 and np.abs(rays - directions).max() < 1e-6
    assert lens.optical_centre == pytest.approx((79.5 + 10.0, 59.5 - 4.0))
    behind, beyond = lens.project(np.array([[0.0, 0.0, -1.0], [1.0, 0.0, 0.02]]))[1]
    assert not behind and not beyond  # behind the camera; 89 deg off the axis, past the lens's field
