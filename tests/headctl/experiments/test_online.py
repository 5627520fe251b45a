"""The online experiments' measurement: the room's surfaces, the landing targets in them, and
runs with and without the head's pose."""
from __future__ import annotations

import numpy as np

from calib_free.sim.experiments import landing_targets
from drivers.sim.scene import shared_scene
from drivers.sim.truth import first_surface
from headctl.experiments import online
from headctl.experiments.online import OnlineSpec, RoomSurfaces, run_online, sim_config
from headctl.service.build import sim_head_model


def test_room_surfaces_meet_rays_where_the_test_ray_caster_does():
    scene = shared_scene(0, False)
    room = RoomSurfaces(scene)
    rng = np.random.default_rng(1)
    for _ in range(100):
        origin = rng.uniform(-0.1, 0.1, 3)
        direction = rng.normal(size=3)
        direction /= np.linalg.norm(direction)
        np.testing.assert_allclose(room.first_surface(origin, direction), first_surface(scene, origin, direction),
                                   atol=1e-6)


def on_a_box_face(scene, point: np.ndarray, tolerance_m: float = 1e-6) -> bool:
    lo, hi = scene.lo.astype(float), scene.hi.astype(float)
    within = np.all((point >= lo - tolerance_m) & (point <= hi + tolerance_m), axis=1)
    on_face = np.any((np.abs(point - lo) < tolerance_m) | (np.abs(point - hi) < tolerance_m), axis=1)
    return bool(np.any(within & on_face))


def test_room_landing_targets_lie_on_the_room_and_are_seen_from_poses_fixating_it():
    config = sim_config()
    model = sim_head_model(config.cameras.left, config.fixation.vergence_range)
    scene = shared_scene(0, False)
    targets = landing_targets(model, 60, (-60.0, 60.0), seed=3, surroundings=RoomSurfaces(scene))
    for t in targets:
        after = t.pose_before + t.command
        np.testing.assert_allclose(t.target, model.fixation_point(after), atol=1e-9)
        for pose in (t.pose_before, after):
            assert model.limits.contains(pose)
            assert on_a_box_face(scene, model.fixation_point(pose))
    # the room is 0.5 to 3 m deep: vergence of a few degrees, never the joints' 20
    assert max(t.pose_before[2] for t in targets) < 8.0


def test_an_online_run_without_the_pose_teaches_without_it_and_lands_on_both_target_sets(monkeypatch):
    poses = []

    class RecordingAdapter(online.MapAdapter):
        def submit(self, sample):
            poses.append(sample.pose)
            super().submit(sample)

    monkeypatch.setattr(online, "MapAdapter", RecordingAdapter)
    result = run_online(OnlineSpec("short", 8), seed=0, landing_every=4, landing_count=20, use_pose=False)
    assert len(result.landing) == len(result.landing_joint_range) == 2
    assert poses and all(p is None for p in poses)


def test_the_realistic_world_teaches_from_a_random_map_as_the_ideal_one_does():
    """configs/sim.yaml's world: webcams with lens differences, auto exposure held per
    fixation, MJPEG, a free-running pair, XM430 play and droop, a room whose light changes.
    Fixations from a random map still converge and teach, only when converged and confident."""
    from calib_free.gaze.fixation import FixationParams
    from headctl.config.head import load_config
    from headctl.config.world import WorldKind, simulated_world

    config = load_config()
    world = simulated_world(config)
    assert world is not None and world.kind is WorldKind.REALISTIC
    result = run_online(OnlineSpec("online", 60, (), "realistic"), seed=0, landing_every=0, config=config)
    taught = [r for r in result.records if r.taught]
    assert len(taught) >= 30, result.outcomes()
    floor = FixationParams().confidence_floor
    assert all(r.converged and r.confidence >= floor for r in taught)
    assert result.config_path == str(config.path)


def test_the_eyes_rendered_on_two_threads_give_the_same_fixations_as_in_turn():
    """`parallel_eyes` only moves the right eye's render to a thread of its own: the realistic
    world's frames (each eye's exposure, noise and timing its own) and so the fixations are the
    ones the eyes rendered in turn give."""
    import threading

    from calib_free.gaze.fixation import FixationController
    from calib_free.map.adapter import MapAdapter
    from calib_free.map.gaze_map import GazeMap
    from headctl.config.head import load_config
    from headctl.experiments.online import SimulatedHeadRig

    def fixations(parallel_eyes: bool) -> tuple[list[tuple], set[str]]:
        with (SimulatedHeadRig(seed=0, config=load_config(), parallel_eyes=parallel_eyes) as rig,
              MapAdapter(GazeMap.for_image(320, 240, seed=0)) as adapter):
            controller = FixationController(rig.head, adapter, rig.fixation, seed=1, clock=rig.clock.monotonic)
            records = [controller.fixate() for _ in range(4)]
            names = {t.name for t in threading.enumerate()}
        return [(r.outcome, None if r.position is None else tuple(r.position), tuple(r.executed)) for r in records], names

    in_turn, names_in_turn = fixations(False)
    on_two, names_on_two = fixations(True)
    assert on_two == in_turn
    assert not any(n.startswith("sim-render-right") for n in names_in_turn)
    assert any(n.startswith("sim-render-right") for n in names_on_two)
    assert not any(t.name.startswith("sim-render-right") for t in threading.enumerate())  # closed with the rig
