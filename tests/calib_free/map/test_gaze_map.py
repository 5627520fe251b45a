"""The gaze map: the update rule (eqs. 8-11) by hand, bad inputs, persistence, learning."""
from __future__ import annotations

import copy

import math
import os
import signal
import subprocess
import sys
import textwrap

import numpy as np
import pytest

from calib_free.errors import MapFileError, OutOfRangeError

from calib_free.map.file import read_map, write_map
from calib_free.map.gaze_map import GazeMap
from calib_free.map.params import GazeMapParams
from calib_free.map.adapter import MapAdapter, Sample
from calib_free.sim.experiments import landing_errors_px, landing_targets, map_predictor
from calib_free.sim.head_model import FixationSampler, HeadModel, JointLimits, with_perturbation


def tiny_paper_map(**overrides) -> GazeMap:
    """A 3 x 3 x 3 paper-profile map on a 21 x 21 image, disparity -10..10, all nodes zero.

    Nodes sit at x, y in {-0.5, 10, 20.5} and d in {-10, 0, 10}. With slope s = 0 the
    sigmoid of eq. 9 is 1/2 whatever the error, so sigma = 0.5 * sigma_max; sigma_max =
    0.5 * (3 - 1) = 1 cell, hence sigma = 0.5 cells on every axis.
    """
    params = GazeMapParams.profile_values(
        "paper", image_size=(21, 21), disparity_range=(-10.0, 10.0), grid_shape=(3, 3, 3),
        sigma_max_fraction=0.5, adaptation_slope=0.0, adaptation_rate=0.6, **overrides)
    return GazeMap(params, grid=np.zeros((3, 3, 3, 3)))


def test_update_rule_matches_eqs_10_11_by_hand():
    gm = tiny_paper_map()
    m = np.array([1.0, 2.0, 3.0])
    st = gm.adapt((10.0, 10.0, 0.0), m, confidence=0.5)  # exactly on the centre node
    assert st.accepted
    np.testing.assert_allclose(st.sigma_cells, [0.5, 0.5, 0.5])
    # eq. 11 at the peak: |dW| = c |W - m| = 0.5 * (1, 2, 3)
    np.testing.assert_allclose(st.output_error, [0.5, 1.0, 1.5])
    values = gm.node_values()
    for i in range(3):
        for j in range(3):
            for k in range(3):
                dist2 = (i - 1) ** 2 + (j - 1) ** 2 + (k - 1) ** 2
                gauss = math.exp(-0.5 * dist2 / 0.5 ** 2)
                # eqs. 10-11: W += alpha * c * G * (m - W), W = 0 before
                expected = 0.6 * 0.5 * gauss * m
                np.testing.assert_allclose(values[i, j, k], expected, rtol=1e-9, atol=1e-12)


def test_second_update_moves_towards_the_command_from_the_current_value():
    gm = tiny_paper_map()
    m = np.array([1.0, 2.0, 3.0])
    gm.adapt((10.0, 10.0, 0.0), m, confidence=1.0)
    gm.adapt((10.0, 10.0, 0.0), m, confidence=1.0)
    # centre node: 0 -> 0.6 m -> 0.6 m + 0.6 (m - 0.6 m) = 0.84 m
    np.testing.assert_allclose(gm.node_values()[1, 1, 1], 0.84 * m)


def test_retinal_error_is_eq_8():
    gm = GazeMap.for_image(320, 240, disparity_range=(-60, 60), seed=0)
    # E_max = half of each dimension: 160 px, 120 px, 60 px
    e = gm.retinal_error((100.0, 50.0, 10.0), (116.0, 50.0, 4.0))
    assert e == pytest.approx(math.sqrt((16 / 160) ** 2 + (6 / 60) ** 2))


def test_sigma_follows_eq_9():
    gm = GazeMap.for_image(320, 240, seed=0, profile="paper")
    sigma_max = 0.2 * (np.array([100, 75, 21]) - 1)  # Table I: 20 % of each input dimension
    for mean_error in (0.0, 0.2, 0.6):
        expected = sigma_max / (1 + math.exp(-5 * (mean_error - 0.2)))  # s = 5, t = 0.2
        np.testing.assert_allclose(gm.sigma_cells(mean_error), expected)
    np.testing.assert_allclose(gm.sigma_cells(0.2), sigma_max / 2)


@pytest.mark.parametrize("profile", ["default", "paper"])
def test_inverse_lookup_finds_the_position_of_a_command(profile):
    gm = GazeMap.for_image(320, 240, seed=1, profile=profile)
    sampler = FixationSampler(HeadModel.default(), seed=2)
    for _ in range(800):
        s = sampler.draw()
        gm.adapt(s.position, s.command)
    errors = []
    for _ in range(100):
        r = sampler.draw().position
        errors.append(gm.retinal_error(r, gm.inverse(gm.command(r))))
    # nearest node (paper) is within about a node spacing; the refined lookup far closer
    limit = 0.06 if profile == "paper" else 0.01
    assert np.median(errors) < limit


def test_command_rejects_positions_outside_the_map():
    gm = GazeMap.for_image(320, 240, disparity_range=(-60, 60), seed=0)
    with pytest.raises(OutOfRangeError, match=r"x=400 is outside the image"):
        gm.command((400, 100, 0))
    with pytest.raises(OutOfRangeError, match=r"d=-61 is outside the disparity range"):
        gm.command((100, 100, -61))
    with pytest.raises(OutOfRangeError, match="3 finite numbers"):
        gm.command((100, float("nan"), 0))
    with pytest.raises(ValueError):  # OutOfRangeError is also a ValueError
        gm.command((100, 100))


@pytest.mark.parametrize("position, command, confidence, reason", [
    ((-1.0, 10.0, 0.0), (1, 1, 1), 1.0, "outside the image"),
    ((10.0, 10.0, 99.0), (1, 1, 1), 1.0, "outside the disparity range"),
    ((10.0, 10.0, 0.0), (1, float("inf"), 1), 1.0, "command must be 3 finite numbers"),
    ((10.0, 10.0, 0.0), (1, 1, 1), 1.5, "confidence must be in"),
    ((10.0, 10.0, 0.0), (1, 1, 1), 0.0, "confidence must be in"),
])
def test_adapt_refuses_bad_samples_and_learns_nothing(position, command, confidence, reason):
    gm = GazeMap.for_image(320, 240, seed=0)
    before = gm.node_values()
    st = gm.adapt(position, command, confidence=confidence)
    assert not st.accepted
    assert reason in st.reason
    assert gm.adaptations == 0
    np.testing.assert_array_equal(gm.node_values(), before)


def test_bad_parameters_are_named():
    with pytest.raises(ValueError, match="unknown gaze map profile 'fast'"):
        GazeMap.for_image(320, 240, profile="fast")
    with pytest.raises(ValueError, match="disparity_range"):
        GazeMap.for_image(320, 240, disparity_range=(10, -10))
    with pytest.raises(ValueError, match="adaptation_rate"):
        GazeMap.for_image(320, 240, adaptation_rate=0.0)


def trained(profile: str, n: int = 300, seed: int = 0) -> tuple[GazeMap, FixationSampler]:
    gm = GazeMap.for_image(320, 240, seed=seed, profile=profile)
    sampler = FixationSampler(HeadModel.default(), seed=seed + 10)
    for _ in range(n):
        s = sampler.draw()
        gm.adapt(s.position, s.command, confidence=0.9)
    return gm, sampler


@pytest.mark.parametrize("profile", ["default", "paper"])
def test_save_load_round_trips_exactly_and_learning_continues_identically(tmp_path, profile):
    gm, sampler = trained(profile)
    path = tmp_path / "map.npz"
    write_map(gm, path)
    loaded = read_map(path)
    assert loaded.params == gm.params
    assert loaded.adaptations == gm.adaptations
    np.testing.assert_array_equal(loaded.grid, gm.grid)
    assert list(loaded.recent_errors) == list(gm.recent_errors)
    for _ in range(50):
        s = sampler.draw()
        a = gm.adapt(s.position, s.command, 0.8)
        b = loaded.adapt(s.position, s.command, 0.8)
        assert a.retinal_error == b.retinal_error
        np.testing.assert_array_equal(gm.command(s.position), loaded.command(s.position))


@pytest.mark.parametrize("profile", ["default", "paper"])
def test_warm_up_leaves_the_map_exactly_as_it_was(profile):
    gm, sampler = trained(profile, n=30)
    twin = copy.deepcopy(gm)
    assert gm.warm_up() >= 0.0
    assert gm.adaptations == twin.adaptations and list(gm.recent_errors) == list(twin.recent_errors)
    np.testing.assert_array_equal(gm.grid, twin.grid)
    s = sampler.draw()  # and it goes on learning exactly as the untouched twin does
    assert gm.adapt(s.position, s.command, 0.8).retinal_error == twin.adapt(s.position, s.command, 0.8).retinal_error
    np.testing.assert_array_equal(gm.command(s.position), twin.command(s.position))


def test_save_keeps_the_previous_file(tmp_path):
    gm, sampler = trained("default", n=20)
    path = tmp_path / "map.npz"
    write_map(gm, path)
    first = read_map(path)
    s = sampler.draw()
    gm.adapt(s.position, s.command)
    write_map(gm, path)
    previous = read_map(tmp_path / "map.npz.prev")
    assert previous.adaptations == first.adaptations == gm.adaptations - 1
    assert [p.name for p in tmp_path.iterdir() if p.name.endswith(".tmp")] == []


def test_load_reports_missing_corrupt_and_foreign_files(tmp_path):
    with pytest.raises(MapFileError, match="no such gaze map file"):
        read_map(tmp_path / "absent.npz")
    corrupt = tmp_path / "corrupt.npz"
    corrupt.write_bytes(b"PK\x03\x04 this is not a zip archive")
    with pytest.raises(MapFileError, match="corrupt.npz: not a readable gaze map file"):
        read_map(corrupt)
    foreign = tmp_path / "foreign.npz"
    np.savez(foreign, weights=np.zeros(3))
    with pytest.raises(MapFileError, match="format"):
        read_map(foreign)


SAVER = textwrap.dedent("""
    import sys
    import numpy as np
    from calib_free.map.file import write_map
    from calib_free.map.gaze_map import GazeMap
    maps = [GazeMap.for_image(64, 48, seed=s, grid_shape=(40, 30, 21)) for s in (1, 2)]
    for n in range(10**9):
        write_map(maps[n % 2], sys.argv[1])
        if n < 3:
            print(n, flush=True)  # the parent kills us only once saving is under way
""")


@pytest.mark.parametrize("attempt", range(4))
def test_kill_during_save_leaves_a_loadable_map(tmp_path, attempt):
    path = tmp_path / "map.npz"
    child = subprocess.Popen([sys.executable, "-c", SAVER, str(path)], stdout=subprocess.PIPE, text=True)
    try:
        for _ in range(3):
            assert child.stdout.readline(), "the saver died before saving"
        # Let it run into a save at a different point of each attempt, then kill -9.
        os.sched_yield()
        subprocess.run([sys.executable, "-c", f"import time; time.sleep({0.003 * (attempt + 1)})"])
        child.send_signal(signal.SIGKILL)
    finally:
        child.wait(timeout=10)
        child.stdout.close()
    loaded = read_map(path)
    candidates = [GazeMap.for_image(64, 48, seed=s, grid_shape=(40, 30, 21)) for s in (1, 2)]
    assert any(np.array_equal(loaded.grid, c.grid) and
               np.array_equal(loaded.polynomial.coef, c.polynomial.coef) for c in candidates)


@pytest.mark.parametrize("profile, max_px", [("default", 6.0), ("paper", 20.0)])
def test_learning_brings_targets_near_the_fovea(profile, max_px):
    head = HeadModel.default()
    targets = landing_targets(head, 200, (-60, 60), seed=123)
    gm = GazeMap.for_image(320, 240, seed=3, profile=profile)
    before = np.median(landing_errors_px(head, targets, map_predictor(gm)))
    gm, _ = trained(profile, n=600, seed=3)
    after = np.median(landing_errors_px(head, targets, map_predictor(gm)))
    assert after < max_px
    assert after < before / 4


def test_thousands_of_adaptations_stay_stable():
    """Regression: round-off once made the least-squares covariance indefinite near 5,000
    samples and the map diverged to thousands of degrees."""
    head = HeadModel.default()
    gm = GazeMap.for_image(320, 240, seed=0)
    sampler = FixationSampler(head, seed=0)
    for _ in range(6000):
        s = sampler.draw()
        st = gm.adapt(s.position, s.command)
    assert np.all(st.output_error < 10)
    cov = gm.polynomial.covariance
    np.testing.assert_array_equal(cov, cov.T)
    assert np.linalg.eigvalsh(cov).min() > 0
    targets = landing_targets(head, 200, (-60, 60), seed=9)
    assert np.median(landing_errors_px(head, targets, map_predictor(gm))) < 5.0


def exploring_stream(head: HeadModel, seed: int, false_fraction: float = 0.05):
    """Endless (position, command) samples as the exploring head teaches them: a random walk of
    poses (each within a step of the last, as `FixationController.random_command`), fixating
    mostly far (a room's walls), the correspondence off by ~0.3 px and now and then (a false
    match) by ~30 px."""
    rng = np.random.default_rng(seed)
    low, high = head.limits.low, head.limits.high
    step = np.array([35.0, 25.0, 20.0])
    pose = (low + high) / 2
    while True:
        reached = rng.uniform(np.maximum(low, pose - step), np.minimum(high, pose + step))
        reached[2] = min(high[2], low[2] + rng.exponential(2.2))
        r, seen = head.image_position(head.fixation_point(reached)[None, :], pose)
        command, pose = reached - pose, reached
        position = r[0] + rng.normal(0.0, 0.3, 3)
        if rng.random() < false_fraction:
            position += rng.normal(0.0, 30.0, 3)
        if seen[0]:
            yield position, command


def far_fixating_head(**perturbation) -> HeadModel:
    head = HeadModel.default(limits=JointLimits(vergence=(1.0, 20.0)))
    return with_perturbation(head, **perturbation) if perturbation else head


def test_surprise_does_not_fire_on_a_stationary_stream_of_noisy_samples():
    """Regression: a few large errors in one window (heavy-tailed, not a change of the head)
    used to drop the memory to its minimum every few hundred adaptations, and the landing
    error drifted up over a long run."""
    gm = GazeMap.for_image(320, 240, seed=0)
    least_memory = np.inf
    for n, (position, command) in enumerate(exploring_stream(far_fixating_head(), seed=0)):
        if n == 3000:
            break
        if gm.adapt(position, command).accepted and n >= 500:
            least_memory = min(least_memory, gm.memory)
    assert least_memory == gm.params.global_memory


def test_surprise_fires_within_two_windows_of_a_change_of_the_head():
    gm = GazeMap.for_image(320, 240, seed=1)
    stream = exploring_stream(far_fixating_head(), seed=1)
    for _ in range(1000):
        gm.adapt(*next(stream))
    assert gm.memory == gm.params.global_memory
    flipped = exploring_stream(far_fixating_head(vertical_prism=True), seed=2)
    least_memory = np.inf
    for _ in range(2 * gm.params.error_window):
        gm.adapt(*next(flipped))
        least_memory = min(least_memory, gm.memory)
    assert least_memory == gm.params.global_memory_min


# --- the head's pose as an input (beyond the paper) ------------------------------------------
def pose_trained(n: int, seed: int, use_pose: bool) -> GazeMap:
    gm = GazeMap.for_image(320, 240, seed=seed)
    sampler = FixationSampler(HeadModel.default(), seed=seed)
    for _ in range(n):
        s = sampler.draw()
        assert gm.adapt(s.position, s.command, pose=s.pose_before if use_pose else None).accepted
    return gm


def test_the_pose_brings_targets_within_a_pixel_where_x_y_d_alone_cannot():
    """The image rotates with tilt and vergence: from (x, y, d) alone a map lands ~3.5 px
    off however long it learns; told the pose it lands within a pixel after 300 samples."""
    head = HeadModel.default()
    targets = landing_targets(head, 200, (-60, 60), seed=11)
    gm = pose_trained(300, seed=4, use_pose=True)
    assert gm.pose_trusted
    with_pose = np.median(landing_errors_px(head, targets, map_predictor(gm, use_pose=True)))
    without = np.median(landing_errors_px(head, targets, map_predictor(gm, use_pose=False)))
    assert with_pose < 1.0
    assert without > 2.5 * with_pose  # the same map read without a pose: its pose-free estimate


def test_a_map_that_never_saw_a_pose_answers_a_lookup_with_one_from_its_pose_free_estimate():
    gm = pose_trained(50, seed=2, use_pose=False)
    assert not gm.pose_trusted
    position = (100.0, 70.0, -5.0)
    np.testing.assert_array_equal(gm.command(position, pose=(10.0, -20.0, 12.0)), gm.command(position))
    np.testing.assert_array_equal(gm.inverse((1.0, 2.0, 0.5), pose=(10.0, -20.0, 12.0)),
                                  gm.inverse((1.0, 2.0, 0.5)))


def test_the_paper_profile_ignores_the_pose_bit_for_bit():
    a = GazeMap.for_image(320, 240, seed=6, profile="paper")
    b = GazeMap.for_image(320, 240, seed=6, profile="paper")
    sampler = FixationSampler(HeadModel.default(), seed=6)
    for _ in range(40):
        s = sampler.draw()
        assert (a.adapt(s.position, s.command, 0.9).retinal_error
                == b.adapt(s.position, s.command, 0.9, pose=s.pose_before).retinal_error)
    np.testing.assert_array_equal(a.grid, b.grid)
    np.testing.assert_array_equal(a.command((50.0, 60.0, 3.0)), b.command((50.0, 60.0, 3.0), pose=(1.0, 2.0, 9.0)))


@pytest.mark.parametrize("pose", [(0.0, float("nan"), 10.0), (0.0, 1.0), (0.0, 1e4, 10.0)])
def test_a_bad_pose_is_refused_and_named(pose):
    gm = GazeMap.for_image(320, 240, seed=0)
    st = gm.adapt((100.0, 100.0, 0.0), (1.0, 1.0, 1.0), pose=pose)
    assert not st.accepted and "pose must be 3 finite angles" in st.reason and gm.adaptations == 0
    with pytest.raises(OutOfRangeError, match="pose"):
        gm.command((100.0, 100.0, 0.0), pose=pose)


@pytest.mark.parametrize("use_pose", [False, True])
def test_uncertainty_is_largest_where_the_map_has_seen_no_sample(use_pose):
    """Samples only in the left half of the image: the polynomial's predictive variance is
    higher in the right half, and falls where samples came."""
    gm = GazeMap.for_image(320, 240, seed=0)
    sampler = FixationSampler(HeadModel.default(), seed=0)
    pose = (0.0, 5.0, 10.0) if use_pose else None
    fresh = gm.uncertainty((60.0, 120.0, 0.0), pose=pose)
    taught = 0
    while taught < 150:
        s = sampler.draw()
        if s.position[0] < 140:
            gm.adapt(s.position, s.command, pose=s.pose_before if use_pose else None)
            taught += 1
    seen, unseen = gm.uncertainty((60.0, 120.0, 0.0), pose=pose), gm.uncertainty((300.0, 120.0, 0.0), pose=pose)
    assert seen < fresh / 10
    assert unseen > 10 * seen
    assert GazeMap.for_image(320, 240, profile="paper").uncertainty((60.0, 120.0, 0.0)) == 1.0


def test_the_adapter_passes_a_samples_pose_to_the_map():
    gm = GazeMap.for_image(320, 240, seed=0)
    sampler = FixationSampler(HeadModel.default(), seed=0)
    with MapAdapter(gm) as adapter:
        for n in range(3):
            s = sampler.draw()
            adapter.submit(Sample(s.position, s.command, 1.0, tag=n, pose=s.pose_before))
        assert adapter.wait_idle(10.0)
    assert gm.adaptations == 3 and np.isfinite(gm.fit_errors).all()  # the pose-aware part learned
    np.testing.assert_array_equal(adapter.command(s.position, pose=s.pose_before), gm.command(s.position, s.pose_before))
