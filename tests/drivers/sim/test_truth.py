"""What the simulated world tells benchmarks (drivers/sim/truth.py): the point on an eye's
image centre, through the nominal lens and through a unit's lens off it."""
from __future__ import annotations

import numpy as np

from calib_free.sim.head_model import HeadModel
from drivers.sim.camera_effects.lens_error import ErredLens, LensError
from drivers.sim.scene import shared_scene
from drivers.sim.truth import axis_point, centre_point

MODEL = HeadModel.default(320, 240)
SCENE = shared_scene(0, False, "generated")
FRAME = MODEL.eye_frames_from_joints(5.0, -3.0, 2.0, -2.0)[0]
CENTRE_PX = np.array([159.5, 119.5])


def test_through_the_nominal_lens_the_image_centre_sees_the_optical_axis():
    assert np.allclose(centre_point(SCENE, MODEL.lens_left, *FRAME), axis_point(SCENE, *FRAME), atol=1e-9)


def test_through_a_units_lens_the_point_is_seen_at_the_image_centre_not_on_the_axis():
    lens = ErredLens(MODEL.lens_left, LensError(1.03, (8.0, -6.0), 2.0))
    rotation, centre = FRAME
    point = centre_point(SCENE, lens, rotation, centre)
    uv, seen = lens.project(((point - centre) @ rotation.T)[None, :])
    assert seen[0] and np.allclose(uv[0], CENTRE_PX, atol=1e-6)
    on_axis, _ = lens.project(((axis_point(SCENE, rotation, centre) - centre) @ rotation.T)[None, :])
    assert np.hypot(*(on_axis[0] - CENTRE_PX)) > 5.0  # the unit's axis is 10 px off the centre
