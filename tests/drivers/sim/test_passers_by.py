"""People walking through the simulated room: a slab appears in the rendered images at its
crossing's time, crosses the view at the configured speed, is gone between crossings, and
all of it is the same for a seed; the config's errors name the key."""
from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pytest

from calib_free.sim.head_model import HeadModel
from drivers.cameras.config import SceneConfig, StereoCamerasConfig
from drivers.clock import ManualClock
from drivers.config.reader import read_config
from drivers.errors import CameraConfigError
from drivers.sim.motion import MovingObject, SceneMotion
from drivers.sim.passers_by import Crossing, Crowd, PasserBy
from drivers.sim.room import room_scene
from drivers.sim.scene import Scene, StereoRenderer, shared_scene
from drivers.sim.truth import first_surface

HEAD = HeadModel.default(160, 120)
AHEAD = {"pan": 0.0, "tilt": 0.0, "left_eye": 0.0, "right_eye": 0.0}  # both optical axes along +x


def walking_room(seed: int = 0, **keys: object) -> Scene:
    config = read_config(SceneConfig, {"passers_by": {"rate_per_min": 4.0, **keys}}, "cameras.scene")
    return room_scene(config, seed=seed, colour=False, clock=ManualClock(0.0))


def crowd_of(scene: Scene) -> Crowd:
    assert isinstance(scene.motion, SceneMotion)
    walkers = [mover for _, mover in scene.motion.objects if isinstance(mover, PasserBy)]
    assert walkers
    return walkers[0].crowd


def first_alone(crowd: Crowd) -> Crossing:
    """A crossing no other overlaps (so that only one slab is in the view)."""
    found = crowd.crossings(600.0)
    for i, c in enumerate(found):
        others = [o for o in found if o is not c and abs(o.start_s - c.start_s) < c.duration_s + 0.5]
        if not others and i > 0:
            return c
    raise AssertionError("no lone crossing in ten minutes")


def covered(renderer: StereoRenderer, empty: tuple[np.ndarray, np.ndarray], t_s: float) -> tuple[bool, bool]:
    """Whether something new covers each eye's centre pixel: it differs from the empty room."""
    images = renderer.render(AHEAD, t_s)
    cy, cx = HEAD.lens_left.height // 2, HEAD.lens_left.width // 2
    return tuple(abs(float(img[cy, cx]) - float(ref[cy, cx])) > 1.0 for img, ref in zip(images, empty))  # type: ignore[return-value]


def edge_time(cover: Callable[[float], bool], lo: float, hi: float) -> float:
    """When `cover` turns from cover(lo) to not cover(lo), bisected to 0.1 ms."""
    first = cover(lo)
    assert cover(hi) != first
    while hi - lo > 1e-4:
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if cover(mid) == first else (lo, mid)
    return 0.5 * (lo + hi)


def test_a_passer_by_appears_at_its_time_and_crosses_the_view_at_the_configured_speed():
    speed, width = 1.5, 0.5
    scene = walking_room(seed=1, speed_m_s=speed, width_m=width)
    crossing = first_alone(crowd_of(scene))
    empty_room = shared_scene(1, False)
    with StereoRenderer(HEAD, empty_room) as plain:
        empty = plain.render(AHEAD)
    with StereoRenderer(HEAD, scene) as renderer:
        before = renderer.render(AHEAD, crossing.start_s - 0.05)
        for img, ref in zip(before, empty):  # nobody there yet: the room as it is without them
            assert np.abs(img.astype(float) - ref).max() <= 1.0
        # Scan the crossing every 10 ms for when each eye's centre pixel is covered, then find
        # when its leading and trailing edges pass that pixel's ray.
        times = np.arange(crossing.start_s, crossing.start_s + crossing.duration_s, 0.01)
        seen = np.array([covered(renderer, empty, float(t)) for t in times])
        edges = []
        for eye in (0, 1):
            inside = np.flatnonzero(seen[:, eye])
            assert inside.size > 0.8 * (width / speed) / 0.01  # a texel may match the wall now and then
            enter = edge_time(lambda t: covered(renderer, empty, t)[eye], times[inside[0] - 1], times[inside[0]])
            leave = edge_time(lambda t: covered(renderer, empty, t)[eye], times[inside[-1]], times[inside[-1] + 1])
            edges.append((enter, leave))
            assert leave - enter == pytest.approx(width / speed, abs=1e-3)  # its width passes at its speed
    # The eyes sit a baseline apart across its path: it reaches the second eye's axis later.
    (_, left_centre), (_, right_centre) = HEAD.eye_frames_from_joints(**AHEAD)
    baseline_m = abs(float(left_centre[1] - right_centre[1]))
    first, second = (1, 0) if crossing.direction > 0 else (0, 1)  # +1 walks from the right eye to the left
    lag_s = edges[second][0] - edges[first][0]
    assert baseline_m / lag_s == pytest.approx(speed, rel=0.05)
    # It entered through the side wall at its crossing's start: its leading edge walked from
    # the wall to the first eye's axis (the centre pixel's ray is within 0.3 deg of it).
    room = scene.boxes[0]
    eye_y = float((left_centre, right_centre)[first][1])
    walked_m = eye_y - room.lo[1] if crossing.direction > 0 else room.hi[1] - eye_y
    assert edges[first][0] == pytest.approx(crossing.start_s + walked_m / speed, abs=0.01)


def test_between_crossings_a_slab_is_out_of_the_world():
    scene = walking_room(seed=2, max_at_once=3, rate_per_min=30.0)
    crowd = crowd_of(scene)
    assert isinstance(scene.motion, SceneMotion)
    found = crowd.crossings(300.0)
    for t in np.arange(0.0, 300.0, 0.25):
        walking = [c for c in found if c.start_s <= t < c.start_s + c.duration_s]
        assert len(walking) <= 3 and len({c.slot for c in walking}) == len(walking)
        offsets = scene.motion.box_offsets(float(t))
        assert offsets is not None
        gone = np.isnan(offsets).any(axis=1)
        assert int((~gone[-3:]).sum()) == len(walking)  # the three slabs, last in the scene
    # At rest (where truth looks up surfaces) the slabs are outside the room: no ray meets them.
    base = shared_scene(2, False)
    rng = np.random.default_rng(0)
    for direction in rng.normal(size=(200, 3)):
        direction /= np.linalg.norm(direction)
        origin = np.array([0.0, 0.0, 0.06])
        np.testing.assert_allclose(first_surface(scene, origin, direction), first_surface(base, origin, direction))


def test_passers_by_are_the_same_for_a_seed():
    crossings = crowd_of(walking_room(seed=7)).crossings(600.0)
    assert crossings == crowd_of(walking_room(seed=7)).crossings(600.0)
    assert crossings != crowd_of(walking_room(seed=8)).crossings(600.0)
    assert 15 <= len(crossings) <= 70  # 40 expected in ten minutes at 4 a minute, less those no slab was free for
    one, two = walking_room(seed=7), walking_room(seed=7)
    t = crossings[0].start_s + 0.5 * crossings[0].duration_s
    with StereoRenderer(HEAD, one) as a, StereoRenderer(HEAD, two) as b:
        for x, y in zip(a.render(AHEAD, t), b.render(AHEAD, t)):
            np.testing.assert_array_equal(x, y)


def test_passers_by_walk_among_the_moving_objects():
    cube = MovingObject()
    config = read_config(SceneConfig, {"passers_by": {"model": "home"}}, "cameras.scene")
    scene = room_scene(config, seed=0, colour=False, objects=[cube], clock=ManualClock(0.0))
    assert isinstance(scene.motion, SceneMotion)
    assert [type(m) for _, m in scene.motion.objects] == [MovingObject, PasserBy, PasserBy]
    np.testing.assert_allclose(scene.motion.offset_of(cube.name, 1.0), cube.centre(1.0) - cube.centre(0.0))


def test_no_passers_by_by_default():
    assert SceneConfig().passers_by.params.rate_per_min == 0
    scene = room_scene(SceneConfig(), seed=0, colour=False, clock=ManualClock(0.0))
    assert scene is shared_scene(0, False) and scene.motion is None


@pytest.mark.parametrize(("keys", "key"), [
    ({"model": "crowd"}, "model"),
    ({"speed_m_s": 0.0}, "speed_m_s"),
    ({"rate_per_min": -1.0}, "rate_per_min"),
    ({"distance_m": [2.0, 1.0]}, "distance_m"),
    ({"max_at_once": 0}, "max_at_once"),
    ({"texture": "fur"}, "texture"),
])
def test_a_bad_passers_by_setting_names_its_key(keys, key):
    cameras = {"left": {"backend": "sim", "eye": "left"}, "right": {"backend": "sim", "eye": "right"},
               "scene": {"passers_by": keys}}
    with pytest.raises(CameraConfigError) as caught:
        StereoCamerasConfig.from_mapping(cameras)
    assert caught.value.key_path == f"cameras.scene.passers_by.{key}"


class _Gone:
    """A motion that takes box 1 out of the world and leaves the rest where they stand."""

    def box_offsets(self, time_s: float | None = None) -> np.ndarray:
        offsets = np.zeros((2, 3), np.float32)
        offsets[1] = np.nan
        return offsets


def test_the_renderer_skips_a_box_out_of_the_world():
    room = shared_scene(0, False).boxes[0]
    in_view = Scene([room, Scene(seed=0).boxes[2]], seed=0, colour=False)  # the crate, in front of the head
    without = Scene([room], seed=0, colour=False)
    with StereoRenderer(HEAD, in_view) as renderer, StereoRenderer(HEAD, without) as bare:
        pose = {"pan": 20.0, "tilt": -10.0, "left_eye": 0.0, "right_eye": 0.0}
        shown = renderer.render(pose)
        assert np.abs(shown[0].astype(float) - bare.render(pose)[0]).mean() > 5.0  # the crate is seen
        in_view.motion = _Gone()
        for image, empty in zip(renderer.render(pose), bare.render(pose)):
            assert np.abs(image.astype(float) - empty).max() <= 1.0
