"""The simulated cameras render what `calib_free.sim.head_model.HeadModel` projects: a marker painted at
a known world point lands, in both rendered eyes, where the model projects that point (1 px),
in the generated room and in the photo room alike."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from calib_free.sim.head_model import HeadModel
from drivers.errors import ConfigError
from drivers.sim.scene import Box, Marker, Scene, StereoRenderer, default_boxes, photo_boxes, shared_scene
from drivers.sim.textures import folder_photos

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
    """Centroid of the pixels where `channel` dominates the other two (the marker's colour) by
    more than any photograph of the photo room can (`drivers.sim.textures.SATURATION`)."""
    others = np.delete(image.astype(np.float32), channel, axis=2).max(axis=2)
    weight = np.clip(image[:, :, channel].astype(np.float32) - others - 130.0, 0.0, None)
    if weight.sum() < 500:
        return None
    yy, xx = np.indices(weight.shape)
    return float((xx * weight).sum() / weight.sum()), float((yy * weight).sum() / weight.sum())


ROOMS = {"generated": default_boxes, "photos": photo_boxes}


@pytest.mark.parametrize("size, parallel, room", [
    ((320, 240), True, "generated"), ((640, 480), False, "generated"), ((320, 240), False, "photos")])
def test_markers_land_where_the_model_projects_them(size, parallel, room):
    head = HeadModel.default(*size)
    scene = Scene(ROOMS[room](), seed=5, colour=True, markers=MARKERS)
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
    from drivers.sim.scene import EyeRenderer

    head = HeadModel.default(160, 120)
    scene = Scene(seed=0, colour=False)
    culled = EyeRenderer(head.lens_left, scene)
    everywhere = EyeRenderer(head.lens_left, scene)
    whole = [(slice(0, 120), slice(0, 160))] * (len(scene.boxes) - 1)
    everywhere._footprints = lambda rotation, centre, shift=None: whole
    rng = np.random.default_rng(0)
    for pan, tilt, verg in rng.uniform([-40, -25, -10], [40, 25, 25], (60, 3)):
        (rotation, centre), _ = head.eye_frames_from_joints(pan, tilt, verg / 2, -verg / 2)
        assert np.array_equal(culled.render(rotation, centre), everywhere.render(rotation, centre)), (pan, tilt, verg)


def test_the_photo_room_is_deterministic_for_a_seed_and_papered_with_photographs():
    head = HeadModel.default(160, 120)
    joints = POSES[2]
    # shared_scene keeps the room of seed 0 for the process (other tests build it too).
    with StereoRenderer(head, shared_scene(0, False, "photos")) as a, \
            StereoRenderer(head, Scene(photo_boxes(), seed=0, colour=False)) as b, \
            StereoRenderer(head, shared_scene(0, False)) as generated:
        left_a, right_a = a.render(joints)
        left_b, right_b = b.render(joints)
        assert np.array_equal(left_a, left_b) and np.array_equal(right_a, right_b)
        assert not np.array_equal(left_a, generated.render(joints)[0])
    assert all(box.texture == "photo" for box in photo_boxes())
    small = [Box("room", (-1.0, -1.0, -0.7), (1.0, 1.0, 0.7), "photo", 100.0, inside=True)]
    assert not np.array_equal(Scene(small, seed=4, colour=False).atlas, Scene(small, seed=6, colour=False).atlas)
    assert shared_scene(0, False, "photos") is shared_scene(0, False, "photos")
    with pytest.raises(ValueError, match="room 'attic'"):
        shared_scene(0, False, "attic")


def test_a_folder_of_photographs_papers_the_room(tmp_path):
    rng = np.random.default_rng(1)
    for name in ("a.png", "b.JPG"):
        photo = cv2.GaussianBlur(rng.integers(0, 255, (60, 90, 3), dtype=np.uint8), (0, 0), 2)
        cv2.imwrite(str(tmp_path / name), photo)
    (tmp_path / "notes.txt").write_text("not a photograph")
    photos = folder_photos(tmp_path)
    assert len(photos.pictures) == 2 and photos.source == str(tmp_path)
    head = HeadModel.default(160, 120)
    room = [Box("room", (-1.0, -1.0, -0.7), (3.0, 1.4, 1.1), "photo", 150.0, inside=True)]
    with StereoRenderer(head, Scene(room, seed=0, colour=True, photos=photos)) as renderer:
        left, _ = renderer.render(POSES[0])
    assert left.shape == (120, 160, 3) and left.std() > 10


@pytest.mark.parametrize("make", ["missing", "empty"])
def test_a_folder_without_photographs_is_named_with_its_key(tmp_path, make):
    folder = tmp_path / "photos"
    if make == "empty":
        folder.mkdir()
        (folder / "readme.txt").write_text("no photographs here")
    with pytest.raises(ConfigError) as err:
        folder_photos(folder)
    assert "cameras.scene.textures" in str(err.value) and str(folder) in str(err.value)
