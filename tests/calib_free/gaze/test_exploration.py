"""Exploration policies: the paper's random commands, and targets chosen to teach."""
from __future__ import annotations

from types import SimpleNamespace

import cv2
import numpy as np
import pytest

from calib_free.errors import OutOfRangeError
from calib_free.gaze.exploration import (ChoiceKind, ExplorationView, RandomMotor, TeachingExplorer, TeachingParams,
                                    make_exploration)
from calib_free.gaze.fixation import FixationController, FixationParams

WIDTH, HEIGHT = 320, 240
LOW, HIGH = np.array([-40.0, -25.0, 1.0]), np.array([40.0, 25.0, 20.0])
D_RANGE = (-60.0, 60.0)
DISPARITY_PX = 6  # the synthetic pair's: content at x in the left image is at x + 6 in the right


class LinearMap:
    """A map that knows the head: commands proportional to the target's offset from the fovea."""

    def command(self, position, pose=None):
        x, y, d = position
        problem = self.check_position(position)
        if problem:
            raise OutOfRangeError(problem)
        return np.array([-(x - (WIDTH - 1) / 2) * 0.25, -(y - (HEIGHT - 1) / 2) * 0.25, -0.2 * d])

    def check_position(self, position):
        x, y, d = position
        if not (-0.5 <= x <= WIDTH - 0.5 and -0.5 <= y <= HEIGHT - 0.5):
            return f"({x}, {y}) is outside the image"
        if not D_RANGE[0] <= d <= D_RANGE[1]:
            return f"d={d} is outside the disparity range"
        return ""


def textured_pair(seed=0):
    """A left image of blobs at several scales and the right one shifted by DISPARITY_PX."""
    rng = np.random.default_rng(seed)
    noise = rng.random((HEIGHT, WIDTH + 2 * 40)).astype(np.float32)
    texture = cv2.GaussianBlur(noise, (0, 0), 2.0) * 2.0 + cv2.GaussianBlur(noise, (0, 0), 5.0) * 3.0
    texture = cv2.normalize(texture, None, 0, 255, cv2.NORM_MINMAX)
    return texture[:, 40:40 + WIDTH].copy(), texture[:, 40 - DISPARITY_PX:40 - DISPARITY_PX + WIDTH].copy()


def view(left, right, pose, gaze_map=None):
    gaze_map = gaze_map or LinearMap()
    return ExplorationView(np.asarray(pose, dtype=float), LOW, HIGH, left, right,
                           lambda r: gaze_map.command(r, pose), gaze_map.check_position)


def taught(position, pose):
    return SimpleNamespace(taught=True, position=np.asarray(position, dtype=float), pose_after=np.asarray(pose))


def test_random_motor_draws_the_papers_commands_bit_for_bit():
    step = np.array([35.0, 25.0, 20.0])
    policy = RandomMotor(np.random.default_rng(7), step)
    reference = np.random.default_rng(7)
    left, right = textured_pair()
    pose = np.array([30.0, -20.0, 5.0])
    for _ in range(20):
        choice = policy.choose(view(left, right, pose))
        low, high = np.maximum(LOW, pose - step), np.minimum(HIGH, pose + step)
        expected = reference.uniform(low, np.maximum(low, high)) - pose  # as the paper's exploration drew
        assert choice.kind is ChoiceKind.RANDOM and choice.target is None
        np.testing.assert_array_equal(choice.command, expected)
        pose = pose + choice.command
        assert np.all(pose >= LOW) and np.all(pose <= HIGH)


def test_the_controller_explores_through_its_policy_with_the_same_draws():
    class Head:
        pose_low, pose_high = LOW, HIGH

    controller = FixationController(Head(), LinearMap(), FixationParams(exploration="random"), seed=3)
    policy = make_exploration("random", np.random.default_rng(3))
    left, right = textured_pair()
    pose = np.array([0.0, 0.0, 8.0])
    for _ in range(5):
        np.testing.assert_array_equal(controller.random_command(pose), policy.choose(view(left, right, pose)).command)


def test_teaching_targets_lie_in_the_image_the_disparity_range_and_the_joint_limits():
    left, right = textured_pair()
    rng = np.random.default_rng(1)
    explorer = TeachingExplorer(np.random.default_rng(2), params=TeachingParams(warmup_taught=0))
    gaze_map = LinearMap()
    targets = []
    for n in range(12):
        pose = rng.uniform(LOW, HIGH)  # near the limits too: many targets are out of reach there
        choice = explorer.choose(view(left, right, pose, gaze_map))
        if choice.kind is ChoiceKind.RANDOM:
            assert choice.target is None
        else:
            x, y, d = choice.target
            assert 0 <= x <= WIDTH - 1 and 0 <= y <= HEIGHT - 1
            assert D_RANGE[0] <= d <= D_RANGE[1]
            assert d == pytest.approx(DISPARITY_PX, abs=0.5)  # measured in the pair, along the rows
            np.testing.assert_allclose(choice.command, gaze_map.command(choice.target))
            targets.append(choice.target)
        reached = pose + choice.command
        assert np.all(reached >= LOW) and np.all(reached <= HIGH), (pose, choice)
        explorer.observe(taught(choice.target if choice.target is not None else (160, 120, 0), reached))
    assert len(targets) >= 8


def test_targets_spread_over_the_image():
    left, right = textured_pair(3)
    explorer = TeachingExplorer(np.random.default_rng(0), params=TeachingParams(warmup_taught=0))
    pose = np.array([0.0, 0.0, 10.0])
    cells = set()
    for _ in range(16):
        choice = explorer.choose(view(left, right, pose))
        assert choice.kind is ChoiceKind.TARGET
        cells.add((int(choice.target[0] // 80), int(choice.target[1] // 80)))
        explorer.observe(taught(choice.target, pose + choice.command))
    assert len(cells) >= 5  # of the 4 x 3 quarters of the image


def test_targets_follow_the_aim_drawn_over_the_joint_range():
    """Each choice aims at a pan and tilt drawn as the paper's random command would be, and
    takes the target whose saccade reaches nearest it: the poses reached spread over the joint
    range as random commands do, whatever the image offers where."""
    left, right = textured_pair(3)
    explorer = TeachingExplorer(np.random.default_rng(0), params=TeachingParams(warmup_taught=0))
    pose, reached, aims = np.array([0.0, 0.0, 10.0]), [], []
    for _ in range(24):
        choice = explorer.choose(view(left, right, pose))
        assert choice.kind is ChoiceKind.TARGET and choice.aim is not None
        reached.append(pose[:2] + choice.command[:2])
        aims.append(choice.aim)
        explorer.observe(taught(choice.target, pose + choice.command))
    reached_, aims_ = np.array(reached), np.array(aims)
    # The image spans about 80 x 60 deg of this map's commands: a saccade lands within a few
    # degrees of its own aim, and tens of degrees from the next choice's.
    own = np.median(np.hypot(*(reached_ - aims_).T))
    other = np.median(np.hypot(*(reached_ - np.roll(aims_, 1, axis=0)).T))
    assert own < 6.0 and other > 3 * own
    assert np.ptp(reached_[:, 0]) > 40 and np.ptp(reached_[:, 1]) > 25


def test_a_far_target_below_the_least_vergence_is_planned_at_the_limit():
    class FarMap(LinearMap):  # every target needs 3 deg less vergence than the head has now
        def command(self, position, pose=None):
            return super().command(position, pose) + np.array([0.0, 0.0, -3.0])

    left, right = textured_pair()
    explorer = TeachingExplorer(np.random.default_rng(0), params=TeachingParams(warmup_taught=0))
    pose = np.array([0.0, 0.0, LOW[2] + 1.0])
    choice = explorer.choose(view(left, right, pose, FarMap()))
    assert choice.kind is ChoiceKind.TARGET
    assert pose[2] + choice.command[2] == pytest.approx(LOW[2])  # at the limit, never beyond it
    np.testing.assert_allclose(choice.command[:2], FarMap().command(choice.target)[:2])


@pytest.mark.parametrize("pattern", ["checkerboard", "flat"])
def test_without_a_target_that_could_teach_the_command_is_random(pattern):
    if pattern == "checkerboard":  # structure everywhere, repeated every 16 px
        ys, xs = np.mgrid[0:HEIGHT, 0:WIDTH + 40]
        board = (((xs // 8) + (ys // 8)) % 2 * 200 + 20).astype(np.float32)
        left, right = board[:, 20:20 + WIDTH].copy(), board[:, 20 - DISPARITY_PX:20 - DISPARITY_PX + WIDTH].copy()
    else:
        left = right = np.full((HEIGHT, WIDTH), 128.0, dtype=np.float32)
    explorer = TeachingExplorer(np.random.default_rng(0), params=TeachingParams(warmup_taught=0))
    choice = explorer.choose(view(left, right, (0.0, 0.0, 10.0)))
    assert choice.kind is ChoiceKind.RANDOM and choice.target is None
    assert "no candidate" in choice.detail
    if pattern == "checkerboard":
        assert {"a rival along the row", "a repeat elsewhere in the image"} & set(explorer.stats.rejected)


@pytest.mark.parametrize("window", [0, 200])
def test_a_place_whose_fixations_did_not_teach_is_not_chosen_again(window):
    """A target fixation that taught nothing weighs the places near it down: the next choices
    go elsewhere. Without the memory (a window of 0) the same place wins again, as nothing
    else about the ranking changed: one ring of eccentricity, an aim too wide to matter, and a
    map most uncertain at the image's right edge."""
    left, right = textured_pair()
    params = TeachingParams(warmup_taught=0, aim_spread_deg=1e6, ring_width_fraction=2.0, nearby_window=window)
    explorer = TeachingExplorer(np.random.default_rng(0), params=params)
    pose = np.array([0.0, 0.0, 10.0])
    gaze_map = LinearMap()
    uncertain_right = ExplorationView(pose, LOW, HIGH, left, right, lambda r: gaze_map.command(r, pose),
                                      gaze_map.check_position, lambda r: 1.0 + float(r[0]))
    refused = []
    for _ in range(4):
        choice = explorer.choose(uncertain_right)
        assert choice.kind is ChoiceKind.TARGET
        refused.append(choice.target)
        explorer.observe(SimpleNamespace(taught=False, position=choice.target, pose_after=pose + choice.command))
    repeats = sum(np.all(np.abs(b[:2] - a[:2]) <= params.nearby_px) for i, b in enumerate(refused) for a in refused[:i])
    if window:
        assert repeats == 0, refused
    else:
        assert repeats == 6  # all four the same place


def test_a_young_map_explores_at_random_until_fixations_have_taught():
    left, right = textured_pair()
    explorer = TeachingExplorer(np.random.default_rng(0), params=TeachingParams(warmup_taught=3))
    pose = np.array([0.0, 0.0, 10.0])
    kinds = []
    for _ in range(5):
        choice = explorer.choose(view(left, right, pose))
        kinds.append(choice.kind)
        explorer.observe(taught((150, 110, 6), pose))
    assert kinds[:3] == [ChoiceKind.RANDOM] * 3 and kinds[3:] == [ChoiceKind.TARGET] * 2


def test_targets_missed_by_far_bring_random_commands_back():
    left, right = textured_pair()
    explorer = TeachingExplorer(np.random.default_rng(0),
                                params=TeachingParams(warmup_taught=0, doubt_window=10, doubt_random=1.0))
    pose = np.array([0.0, 0.0, 10.0])
    missed = 0
    for _ in range(10):  # each target's fixation lands 100 px off it: the map is wrong
        choice = explorer.choose(view(left, right, pose))
        if choice.kind is ChoiceKind.RANDOM:
            break
        explorer.observe(taught(choice.target + np.array([100.0, 0.0, 0.0]), pose))
        missed += 1
    assert choice.kind is ChoiceKind.RANDOM and "missed by 100 px" in choice.detail
    assert missed == 5  # judged once half the window is full


def test_the_controller_saccades_to_the_chosen_target_within_the_limits():
    left, right = textured_pair()

    class StillHead:  # images that never change: the fixation does not converge, which is fine here
        pose_low, pose_high = LOW, HIGH

        def __init__(self):
            self.pose = np.array([10.0, 5.0, 10.0])
            self.goals = []

        def read_pose(self):
            return self.pose.copy()

        def move_to(self, pose):
            self.goals.append(np.asarray(pose, dtype=float))
            self.pose = np.clip(pose, LOW, HIGH)
            return self.pose.copy()

        def verge_to(self, vergence):
            return float(self.move_to(np.array([self.pose[0], self.pose[1], vergence]))[2])

        def wait_settled(self, timeout_s, same_rest=False):
            return 0.0

        def wait_pair(self, after_s, timeout_s):
            return left, right

    head = StillHead()
    explorer = TeachingExplorer(np.random.default_rng(0), params=TeachingParams(warmup_taught=0))
    controller = FixationController(head, LinearMap(), FixationParams(max_vergence_steps=0), seed=0,
                                    exploration=explorer)
    record = controller.fixate()
    assert record.explore_target is not None and record.target is None
    np.testing.assert_allclose(record.planned, LinearMap().command(record.explore_target))
    np.testing.assert_allclose(head.goals[0], record.pose_before + record.planned)
    assert np.all(head.goals[0] >= LOW) and np.all(head.goals[0] <= HIGH)


def test_the_exploration_setting_is_checked():
    with pytest.raises(ValueError, match="exploration must be one of random, teaching"):
        FixationParams(exploration="sideways")
    assert FixationParams().exploration == "teaching"
    with pytest.raises(ValueError, match="exploration"):
        make_exploration("sideways", np.random.default_rng(0))


def test_the_map_behind_the_adapter_tells_the_explorer_where_it_is_uncertain():
    from calib_free.map.adapter import MapAdapter
    from calib_free.gaze.exploration import UncertainMap
    from calib_free.map.gaze_map import GazeMap

    gm = GazeMap.for_image(320, 240, seed=0)
    adapter = MapAdapter(gm)  # not started: lookups only
    assert isinstance(adapter, UncertainMap)
    at = (60.0, 120.0, 0.0), (0.0, 0.0, 4.0)
    assert adapter.uncertainty(*at) == gm.uncertainty(at[0], pose=at[1])
