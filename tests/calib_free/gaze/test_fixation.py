"""The fixation strategy, the adapter thread and the online experiment on the simulated head."""
from __future__ import annotations

import json
import threading

import numpy as np
import pytest

from calib_free.map.gaze_map import GazeMap
from calib_free.map.adapter import MapAdapter, Sample
from calib_free.gaze.fixation import FixationController, FixationOutcome, FixationParams, HeadTimeoutError
from headctl.cli.main import main
from headctl.config.head import load_config
from headctl.experiments.online import SimulatedHeadRig
from headctl.experiments.perturbations import PanReadingOffset
from tests.support import SIM_IDEAL


class FrozenEyesHead:
    """A head whose images never change: vergence moves do nothing to the foveal disparity."""

    def __init__(self, disparity_px: int = 12) -> None:
        rng = np.random.default_rng(0)
        tex = (rng.random((240, 400)) * 255).astype(np.uint8)
        self.left = tex[:, 40:360]
        self.right = tex[:, 40 - disparity_px:360 - disparity_px]
        self.pose = np.array([0.0, 0.0, 8.0])
        self.pose_low, self.pose_high = np.array([-40.0, -25.0, 1.0]), np.array([40.0, 25.0, 20.0])
        self.moves = []

    def read_pose(self):
        return self.pose.copy()

    def move_to(self, pose):
        self.pose = np.clip(pose, self.pose_low, self.pose_high)
        self.moves.append(self.pose.copy())
        return self.pose.copy()

    def verge_to(self, vergence):
        return float(self.move_to(np.array([self.pose[0], self.pose[1], vergence]))[2])

    def wait_settled(self, timeout_s, same_rest=False):
        return 0.0

    def wait_pair(self, after_s, timeout_s):
        return self.left, self.right


def test_a_fixation_that_does_not_converge_never_teaches():
    head = FrozenEyesHead()
    gm = GazeMap.for_image(320, 240, seed=0)
    controller = FixationController(head, gm, FixationParams(max_vergence_steps=4), seed=1)
    record = controller.fixate()
    assert record.outcome == FixationOutcome.NOT_CONVERGED and not record.taught
    assert record.match is None  # no correspondence was even attempted
    assert record.vergence_steps == 4 and len(record.vergence_disparities_px) == 5
    assert all(d == pytest.approx(12.0, abs=0.2) for d in record.vergence_disparities_px)
    assert len(head.moves) == 1 + 4  # the saccade and four vergence steps
    assert all(np.all(m >= head.pose_low) and np.all(m <= head.pose_high) for m in head.moves)


def test_a_target_outside_the_map_is_refused_before_moving():
    head = FrozenEyesHead()
    controller = FixationController(head, GazeMap.for_image(320, 240, seed=0), seed=1)
    record = controller.fixate(target=(500.0, 10.0, 0.0))
    assert record.outcome == FixationOutcome.TARGET_OUTSIDE and "x=500" in record.detail
    assert head.moves == []


def test_a_target_its_check_refuses_in_the_view_before_the_saccade_is_refused_before_moving():
    head = FrozenEyesHead()
    controller = FixationController(head, GazeMap.for_image(320, 240, seed=0), seed=1)
    seen = []

    def refuse(left):
        seen.append(left)
        return "the target's patch repeats"

    record = controller.fixate(target=(150.0, 100.0, 0.0), target_check=refuse)
    assert record.outcome is FixationOutcome.TARGET_REFUSED and record.detail == "the target's patch repeats"
    assert head.moves == [] and not record.taught
    assert len(seen) == 1 and seen[0].dtype == np.float32 and np.array_equal(seen[0], head.left)
    passed = controller.fixate(target=(150.0, 100.0, 0.0), target_check=lambda left: "")
    assert passed.outcome is not FixationOutcome.TARGET_REFUSED and head.moves != []


def test_timeouts_become_refusals():
    class StuckHead(FrozenEyesHead):
        def wait_settled(self, timeout_s, same_rest=False):
            raise HeadTimeoutError("the head did not come to rest within 3.0 s")

    record = FixationController(StuckHead(), GazeMap.for_image(320, 240, seed=0)).fixate()
    assert record.outcome == "head did not settle" and "rest" in record.detail


def test_fixation_params_are_checked():
    with pytest.raises(ValueError, match="executed_command"):
        FixationParams(executed_command="guessed")
    with pytest.raises(ValueError, match="confidence_floor"):
        FixationParams(confidence_floor=1.5)


@pytest.fixture(scope="module")
def explored():
    """60 exploratory fixations of the simulated head from a random map."""
    gm = GazeMap.for_image(320, 240, seed=0)
    with SimulatedHeadRig(seed=0, config=load_config(SIM_IDEAL)) as rig:
        controller = FixationController(rig.head, gm, rig.fixation, seed=3, clock=rig.clock.monotonic)
        records = [controller.fixate() for _ in range(60)]
        limits = (rig.head.pose_low, rig.head.pose_high)
    return records, limits


def test_fine_vergence_converges_within_five_steps(explored):
    records, _ = explored
    matched = [r for r in records if r.vergence_disparities_px and r.outcome != "foveal patches do not match"]
    converged = [r for r in matched if r.converged]
    assert len(matched) >= 30
    assert len(converged) / len(matched) >= 0.95
    assert all(r.vergence_steps <= 5 and abs(r.vergence_disparities_px[-1]) <= 1.0 for r in converged)


def test_only_converged_confident_fixations_teach(explored):
    records, (low, high) = explored
    taught = [r for r in records if r.outcome is FixationOutcome.TAUGHT]
    assert len(taught) >= 15
    for r in records:
        assert r.outcome  # every fixation says what became of it
        if r.taught:
            assert r.converged and r.confidence >= FixationParams().confidence_floor
            assert np.all(r.pose_after >= low - 0.5) and np.all(r.pose_after <= high + 0.5)
            np.testing.assert_allclose(r.executed, r.pose_after - r.pose_before)
    json.dumps([r.as_dict() for r in records])  # records serialise for logs and the API


def test_adapter_learns_on_its_thread_and_never_blocks_the_caller():
    gm = GazeMap.for_image(320, 240, seed=0)
    seen = []
    with MapAdapter(gm, queue_size=4, on_adapted=lambda s, r: seen.append((s.tag, threading.current_thread().name))) as ad:
        for n in range(20):
            ad.submit(Sample(np.array([100.0, 80.0, 5.0]), np.array([1.0, 2.0, 0.5]), 0.9, tag=n))
        assert ad.wait_idle(10.0)
        assert ad.command((100.0, 80.0, 5.0)).shape == (3,)
    assert {name for _, name in seen} == {"gaze-adapter"}
    assert len(seen) + ad.dropped == 20 and seen[-1][0] == 19  # the newest are kept
    assert gm.adaptations == len(seen)


def test_an_adaptation_error_reaches_the_callback_and_learning_goes_on():
    class Flaky(GazeMap):
        calls = 0

        def adapt(self, position, command, confidence=1.0):
            Flaky.calls += 1
            if Flaky.calls == 1:
                raise RuntimeError("boom")
            return super().adapt(position, command, confidence)

    gm = Flaky(GazeMap.for_image(320, 240, seed=0).params, seed=0)
    errors = []
    with MapAdapter(gm, on_error=errors.append) as ad:
        for n in range(3):
            ad.submit(Sample(np.array([100.0, 80.0, 5.0]), np.array([1.0, 2.0, 0.5]), 0.9, tag=n))
        assert ad.wait_idle(10.0)
    assert [str(e) for e in errors] == ["boom"] and isinstance(ad.error, RuntimeError)
    assert gm.adaptations == 2


def test_online_experiment_command(tmp_path, capsys):
    code = main(["--log-level", "WARNING", "experiment", "online", "--fixations", "40", "--floor-samples", "500",
                 "--landing-every", "20", "--out", str(tmp_path)])
    assert code == 0
    out = capsys.readouterr().out
    assert "online (default profile), " in out and "fine vergence:" in out
    summary = json.loads((tmp_path / "online-default.json").read_text())
    assert summary["online"]["fixations"] == 40
    assert summary["online"]["taught"] == summary["fixations"] > 5
    assert sum(summary["online"]["outcomes"].values()) == 40
    assert (tmp_path / "online-default.png").stat().st_size > 10_000


def test_the_head_clamps_goals_and_the_pan_reading_offset_shifts_moves():
    with SimulatedHeadRig(seed=0, config=load_config(SIM_IDEAL)) as rig:
        head = rig.head
        head.move_to(np.array([100.0, -90.0, 50.0]))  # far outside every limit
        head.wait_settled(5.0)
        np.testing.assert_allclose(head.read_pose(), head.pose_high * [1, 0, 1] + head.pose_low * [0, 1, 0],
                                   atol=0.3)
        head.move_to(np.array([0.0, 0.0, 6.0]))
        head.wait_settled(5.0)
        head.bus = PanReadingOffset(head.bus, 10.0)  # the paper's fig. 9 defect
        before = head.read_pose()
        assert before[0] == pytest.approx(10.0, abs=0.3)
        head.move_to(before + np.array([5.0, 0.0, 0.0]))
        head.wait_settled(5.0)
        assert rig.bus.true_position("pan") == pytest.approx(15.0, abs=0.3)  # 5 commanded, 15 done


def test_with_the_pan_reading_offset_no_goal_is_clamped_by_the_bus_and_moves_stay_commanded_plus_offset():
    # The head clips a goal in the coordinates it writes, the joints' own: near the pan
    # limit the bus sends what was asked, and the head moves exactly the commanded move plus
    # the offset -- what `executed_command="commanded"` teaches stays consistent.
    with SimulatedHeadRig(seed=0, config=load_config(SIM_IDEAL)) as rig:
        head = rig.head
        controller = FixationController(head, GazeMap.for_image(320, 240, seed=0), seed=3)
        head.move_to(np.array([32.0, 0.0, 6.0]))
        head.wait_settled(5.0)
        head.bus = PanReadingOffset(head.bus, 10.0)
        asked_goals, sent_goals = [], []
        write_goals = rig.bus.write_goals

        def spy(goals):
            asked_goals.append(dict(goals))
            sent_goals.append(write_goals(goals))
            return sent_goals[-1]

        rig.bus.write_goals = spy
        for n in range(12):
            before = head.read_pose()
            planned = np.array([25.0, 0.0, 0.0]) if n % 3 == 0 else controller.random_command(before)
            commanded = head.move_to(before + planned) - before
            head.wait_settled(5.0)
            assert head.read_pose()[0] - before[0] == pytest.approx(commanded[0] + 10.0, abs=0.3)
        assert asked_goals == sent_goals
        assert sum(goals["pan"] == head.pose_high[0] for goals in sent_goals) >= 2  # the limit was reached


def test_a_missing_stereo_pair_is_told_apart_from_a_head_that_does_not_settle():
    from calib_free.gaze.fixation import PairTimeoutError

    class Blind(FrozenEyesHead):
        def wait_pair(self, after_s, timeout_s):
            raise PairTimeoutError("no stereo pair exposed after t=1.000 s")

    record = FixationController(Blind(), GazeMap.for_image(320, 240, seed=0)).fixate()
    assert record.outcome == "no stereo pair in time"


def test_a_step_the_servos_did_not_make_is_followed_by_a_longer_one_up_to_twice():
    from calib_free.gaze.fixation import MAX_BOOST, next_boost

    assert next_boost(1.0, None) == 1.0  # the first step: as planned
    assert next_boost(1.0, -3.2) == 1.0  # it moved the error: as planned
    assert next_boost(1.0, 0.1) == 2.0  # it did not: twice as long
    assert next_boost(2.0, 0.0) == MAX_BOOST == 2.0  # and no longer
    assert next_boost(2.0, 1.5) == 1.0  # once a step moves, back to plan
