"""The simulated cameras render what `calib_free.sim.HeadModel` projects: a marker painted at
a known world point lands, in both rendered eyes, where the model projects that point (1 px)."""
from __future__ import annotations

import numpy as np
import pytest

from calib_free.sim import HeadModel
from drivers.sim_scene import Marker, Scene, StereoRenderer

# (point on a face of the default scene, radius): far wall, crate front, cabinet front, floor.
MARKERS = [
    Marker((3.0, 0.35, 0.45), 0.05, (0, 0, 255)),
    Marker((0.8, 0.31, -0.16), 0.015, (0, 255, 0)),
    Marker((1.4, -0.33, -0.05), 0.025, (255, 0, 0)),
]
POSES = [
    {"pan": 0.0, "tilt": 0.0, "left_eye": 0.0, "right_eye": 0.0},
    {"pan": 6.0, "tilt": -4.0, "left_eye": 4.0, "right_eye": -4.0},
    {"pan": -8.0, "tilt": 7.0, "left_eye": 1.5, "right_eye": -6.0},
    {"pan": 15.0, "tilt": -10.0, "left_eye": -10.0, "right_eye": -14.0},
]


def marker_centroid(image: np.ndarray, channel: int) -> tuple[float, float] | None:
    """Centroid of the pixels where `channel` dominates the other two (the marker's colour)."""
    others = np.delete(image.astype(np.float32), channel, axis=2).max(axis=2)
    weight = np.clip(image[:, :, channel].astype(np.float32) - others - 60.0, 0.0, None)
    if weight.sum() < 500:
        return None
    yy, xx = np.indices(weight.shape)
    return float((xx * weight).sum() / weight.sum()), float((yy * weight).sum() / weight.sum())


@pytest.mark.parametrize("size, parallel", [((320, 240), True), ((640, 480), False)])
def test_markers_land_where_the_model_projects_them(size, parallel):
    head = HeadModel.default(*size)
    scene = Scene(seed=5, colour=True, markers=MARKERS)
    checked = 0
    with StereoRenderer(head, scene, parallel=parallel) as renderer:
        for joints in POSES:
            images = renderer.render(joints)
            frames = head.eye_frames_from_joints(joints["pan"], joints["tilt"], joints["left_eye"], joints["right_eye"])
            for image, (rotation, centre), lens in zip(images, frames, (head.lens_left, head.lens_right)):
                for marker in MARKERS:
                    uv, seen = lens.project((np.array([marker.point]) - centre) @ rotation.T)
                    channel = int(np.argmax(marker.colour_bgr))
                    found = marker_centroid(image, channel)
                    if not seen[0]:
                        continue
                    assert found is not None, f"marker {marker.point} projected to {uv[0]} but not drawn ({joints})"
                    error = np.hypot(found[0] - uv[0, 0], found[1] - uv[0, 1])
                    assert error < 1.0, f"marker {marker.point} at {found}, model says {uv[0]} ({error:.2f} px, {joints})"
                    checked += 1
    assert checked >= 16, f"only {checked} marker views checked: the poses must show the markers"


def test_rendering_is_deterministic_for_a_seed():
    head = HeadModel.default(160, 120)
    joints = POSES[1]
    with StereoRenderer(head, Scene(seed=11, colour=False)) as a, StereoRenderer(head, Scene(seed=11, colour=False)) as b:
        left_a, right_a = a.render(joints)
        left_b, right_b = b.render(joints)
    assert np.array_equal(left_a, left_b) and np.array_equal(right_a, right_b)
    with StereoRenderer(head, Scene(seed=12, colour=False)) as c:
        left_c, _ = c.render(joints)
    assert not np.array_equal(left_a, left_c)
    assert left_a.shape == (120, 160) and left_a.dtype == np.uint8


def test_scene_has_rich_and_nearly_uniform_areas():
    """Correspondence must be able to fail (paper fig. 4): some patches nearly uniform."""
    head = HeadModel.default(320, 240)
    with StereoRenderer(head, Scene(seed=0, colour=False)) as renderer:
        left, _ = renderer.render({"pan": -20.0, "tilt": -5.0, "left_eye": 0.0, "right_eye": 0.0})
    patches = [left[y:y + 16, x:x + 16].astype(float).std() for y in range(0, 224, 16) for x in range(0, 304, 16)]
    assert min(patches) < 2.0, f"no nearly uniform 16x16 patch (least std {min(patches):.1f})"
    assert max(patches) > 25.0, f"no richly textured patch (most std {max(patches):.1f})"


def test_marker_off_every_face_is_refused():
    with pytest.raises(ValueError, match="lies on no face"):
        Scene(seed=0, markers=[Marker((1.0, 0.0, 0.0), 0.01)])


def test_footprint_culling_never_changes_the_image():
    """Boxes are only ray-tested inside the image rectangle their edges project to; over many
    poses (near objects, edges of the view) that must give the image a full test gives."""
    from drivers.sim_scene import EyeRenderer

    head = HeadModel.default(160, 120)
    scene = Scene(seed=0, colour=False)
    culled = EyeRenderer(head.lens_left, scene)
    everywhere = EyeRenderer(head.lens_left, scene)
    everywhere._footprints = lambda rotation, centre: [(slice(0, 120), slice(0, 160))] * (len(scene.boxes) - 1)
    rng = np.random.default_rng(0)
    for pan, tilt, verg in rng.uniform([-40, -25, -10], [40, 25, 25], (60, 3)):
        (rotation, centre), _ = head.eye_frames_from_joints(pan, tilt, verg / 2, -verg / 2)
        assert np.array_equal(culled.render(rotation, centre), everywhere.render(rotation, centre)), (pan, tilt, verg)
