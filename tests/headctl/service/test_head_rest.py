"""`headctl.service.head.Head` at rest on servos that droop and whose readings wobble."""
from __future__ import annotations

import copy

import numpy as np
import pytest

from headctl.config.head import parse_config, read_yaml
from headctl.experiments.online import SimulatedHeadRig
from headctl.service.head import joints_of
from tests.support import SIM_IDEAL


def _rig(mechanics: dict, play_deg: dict[str, float] | None = None) -> SimulatedHeadRig:
    """The ideal config's head on servos with `mechanics`; `play_deg`: the joints' play the
    config states (`servo_bus.joints.<joint>.backlash_deg`), which the head takes up."""
    data = copy.deepcopy(read_yaml(SIM_IDEAL))
    data["servo_bus"]["mechanics"] = mechanics
    for joint, play in (play_deg or {}).items():
        data["servo_bus"]["joints"][joint]["backlash_deg"] = play
    return SimulatedHeadRig(seed=0, config=parse_config(data, SIM_IDEAL))


def test_the_pose_at_rest_is_the_mean_of_the_readings_that_wobble():
    with _rig({"model": "xm430_head", "read_wobble_ticks": 2, "backlash_deg": 0.0,
               "sag_deg_at_horizontal": 0.0}) as rig:
        head = rig.head
        at_rest, single = [], []
        for i in range(60):
            head.move_to(np.array([5.0 + (i % 2), -3.0, 6.0]))  # back and forth between two poses
            head.wait_settled(5.0)
            if i % 2 == 0:
                at_rest.append(head.read_pose())
                single.append(head.pose_from(head.bus.read_state().positions))
        spread_rest = np.std(np.array(at_rest)[:, 0])
        spread_single = np.std(np.array(single)[:, 0])
        assert np.ptp(np.array(single)[:, 0]) > 0.1  # two ticks of wobble show in single readings
        # the mean of the five or more readings of a rest: about half the spread (the rest's
        # own position varies too, by the dead band); one reading would spread as much as one
        assert spread_rest < 0.7 * spread_single
        head.move_to(np.array([9.0, -3.0, 6.0]))  # a goal sent: the rest's mean no longer stands
        rig.clock.advance(0.2)  # within the time a rest's mean would stand (0.5 s)
        assert head.read_pose()[0] > 7.0


def test_a_tilt_that_droops_short_of_its_goal_comes_to_rest():
    with _rig({"model": "xm430_head", "sag_deg_at_horizontal": 0.6}) as rig:
        head = rig.head
        head.move_to(np.array([0.0, 0.0, 6.0]))
        head.wait_settled(5.0)  # 0.6 deg short of the tilt's goal: more than the 0.3 deg of "at goal"
        assert 0.3 < -head.read_pose()[1] < 1.0


def _rest_time_s(rig, head) -> float:
    started = rig.clock.monotonic()
    head.wait_settled(5.0)
    return rig.clock.monotonic() - started


def test_the_droop_learned_at_one_rest_lets_the_next_come_to_rest_at_once():
    with _rig({"model": "xm430_head", "sag_deg_at_horizontal": 0.6, "backlash_deg": 0.0,
               "read_wobble_ticks": 0}) as rig:
        head = rig.head
        head.move_to(np.array([0.0, 0.0, 6.0]))
        first = _rest_time_s(rig, head)  # 0.6 deg short of the tilt's goal: the longer wait
        assert first >= head.short_settle_s
        assert head.rest_offset[1] == pytest.approx(-0.3, abs=0.05)  # half the droop after one rest
        head.move_to(np.array([0.0, 1.0, 6.0]))
        head.wait_settled(5.0)
        assert head.rest_offset[1] == pytest.approx(-0.45, abs=0.06)
        head.verge_to(6.5)  # the eyes alone: the tilt still as far short of its goal
        assert _rest_time_s(rig, head) < head.short_settle_s
        head.move_to(np.array([3.0, 1.5, 6.0]))
        assert _rest_time_s(rig, head) < head.short_settle_s + 0.1  # the move itself, then settle_s


def test_a_drooping_tilt_comes_to_rest_where_it_was_asked_once_the_droop_is_learned():
    """The head sends the goal above the pose asked by the droop it saw at the last rests, so a
    step relative to the reading moves the reading by the step, not by the step less the droop
    (a look's corrective step of a pixel or two is smaller than the droop)."""
    with _rig({"model": "xm430_head", "sag_deg_at_horizontal": 0.6, "backlash_deg": 0.0,
               "read_wobble_ticks": 0}) as rig:
        head = rig.head
        for tilt in (0.0, 1.0, 0.5, 1.5, 1.0):  # a few rests: the droop learned
            head.move_to(np.array([0.0, tilt, 6.0]))
            head.wait_settled(5.0)
        assert head.read_pose()[1] == pytest.approx(1.0, abs=0.1)
        for step in (0.3, -0.2, 0.25):
            before = head.read_pose()
            aimed = head.move_to(before + np.array([0.0, step, 0.0]))
            head.wait_settled(5.0)
            moved = head.read_pose()[1] - before[1]
            assert moved == pytest.approx(step, abs=0.1)  # 1 tick: 0.09 deg
            assert aimed[1] == pytest.approx(before[1] + step, abs=0.01)


def test_a_head_still_at_its_last_rest_is_at_rest_at_once_and_one_sent_a_goal_waits_again():
    with _rig({"model": "xm430_head"}) as rig:
        head = rig.head
        head.move_to(np.array([4.0, 2.0, 6.0]))
        head.wait_settled(5.0)
        rested = _rest_time_s(rig, head)  # no goal sent since: one reading says it still rests
        assert rested < head.settle_s
        assert head.wait_settled(5.0) == pytest.approx(rig.clock.monotonic())  # pairs after now
        head.verge_to(6.5)
        assert _rest_time_s(rig, head) >= head.settle_s  # a goal sent: rest is waited for again


def test_a_head_still_at_its_last_rest_gives_that_rest_to_a_caller_that_knows_nothing_changed():
    """`same_rest` (a look's corrective fixation): the old rest's own time, so that the pair its
    target was found in will do; without it, the time now. A goal sent: waited for again."""
    with _rig({"model": "xm430_head"}) as rig:
        head = rig.head
        head.move_to(np.array([4.0, 2.0, 6.0]))
        rested_s = head.wait_settled(5.0)
        rig.clock.advance(0.2)
        assert head.wait_settled(5.0, same_rest=True) == rested_s
        assert head.wait_settled(5.0) == pytest.approx(rig.clock.monotonic())
        head.verge_to(6.5)
        assert head.wait_settled(5.0, same_rest=True) > rested_s + 0.2  # moved: a rest of its own


def test_a_pursuit_goal_is_sent_less_the_droop_and_with_the_play_taken_up():
    """`follow_to` (a track's goal each frame) as `move_to`: a drooping tilt and a pan with
    play come to where the goal says, each way the pan comes from; the goal written as it is,
    the tilt rests short of it by the droop."""
    with _rig({"model": "xm430_head", "sag_deg_at_horizontal": 0.6, "backlash_deg": 0.25,
               "read_wobble_ticks": 0}, {"pan": 0.25}) as rig:
        head = rig.head
        for tilt in (0.0, 1.0, 0.5, 1.5, 1.0):  # a few rests: the droop learned
            head.move_to(np.array([0.0, tilt, 6.0]))
            head.wait_settled(5.0)
        for pan in (3.0, 1.0, 4.0):  # the pan reverses between goals
            goal = np.array([pan, 2.0, 6.0])
            assert head.follow_to(goal) == pytest.approx(goal, abs=0.01)
            head.wait_settled(5.0)
            true = rig.devices.world.true_joints()
            assert true["pan"] == pytest.approx(pan, abs=0.1) and true["tilt"] == pytest.approx(2.0, abs=0.15)
            assert head.read_pose()[:2] == pytest.approx(goal[:2], abs=0.1)
        head.bus.write_goals(joints_of(np.array([4.0, 2.0, 6.0])))
        head.wait_settled(5.0)
        assert rig.devices.world.true_joints()["tilt"] < 2.0 - 0.3  # the droop, not taken off the goal
