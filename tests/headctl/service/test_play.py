"""The joints' play taken up: goals beyond their targets by half the play, in the direction of
approach (`headctl.service.play`), so that a joint rests where it was asked whichever way it came."""
from __future__ import annotations

import copy

import numpy as np
import pytest

from headctl.config.head import parse_config, read_yaml
from headctl.experiments.online import SimulatedHeadRig
from headctl.service.play import PlayCompensation
from tests.support import SIM_IDEAL

LIMITS = {"pan": (-40.0, 40.0), "tilt": (-25.0, 25.0)}


def test_a_goal_is_sent_beyond_its_target_the_way_the_joint_comes():
    play = PlayCompensation({"pan": 0.4, "tilt": 0.0}, LIMITS)
    assert play.goals({"pan": 5.0, "tilt": 2.0}, lambda: {"pan": 0.0, "tilt": 0.0}) == {"pan": 5.2, "tilt": 2.0}
    assert play.goals({"pan": 4.0, "tilt": 1.0}, dict) == {"pan": 3.8, "tilt": 1.0}  # a reversal
    assert play.goals({"pan": 4.0}, dict) == {"pan": 3.8}  # the same target: the same way
    assert play.goals({"pan": 4.1}, dict) == pytest.approx({"pan": 4.3})


def test_the_first_direction_is_from_where_the_encoder_reads_the_joint():
    play = PlayCompensation({"pan": 0.4}, LIMITS)
    assert play.joints({"pan": 3.0}) == {"pan": 3.0}  # no move yet: as read
    assert play.goals({"pan": 2.0}, lambda: {"pan": 3.0}) == {"pan": 1.8}
    assert play.joints({"pan": 1.8}) == pytest.approx({"pan": 2.0})  # the joint trails the shaft


def test_no_goal_passes_a_limit():
    play = PlayCompensation({"pan": 0.4}, LIMITS)
    assert play.goals({"pan": 40.0}, lambda: {"pan": 0.0}) == {"pan": 40.0}
    assert play.goals({"pan": -40.0}, dict) == {"pan": -40.0}


def _rig(backlash_deg: float) -> SimulatedHeadRig:
    data = copy.deepcopy(read_yaml(SIM_IDEAL))
    data["servo_bus"]["mechanics"] = {"model": "xm430_head", "sag_deg_at_horizontal": 0.0, "read_wobble_ticks": 0}
    for joint in ("pan", "left_eye", "right_eye"):
        data["servo_bus"]["joints"][joint]["backlash_deg"] = backlash_deg
    return SimulatedHeadRig(seed=0, config=parse_config(data, SIM_IDEAL))


def _rests(backlash_deg: float) -> tuple[list[float], list[float]]:
    """(how far the true pan rested from each target, how far the head's reading of it was
    from the true pan), pan sent back and forth on servos with 0.25 deg of play."""
    off_target, misread = [], []
    with _rig(backlash_deg) as rig:
        head = rig.head
        for pan in (5.0, 6.0, 5.5, 7.0, 6.8, 6.9, 4.0):
            head.move_to(np.array([pan, 0.0, 6.0]))
            head.wait_settled(5.0)
            true_pan = rig.devices.world.true_joints()["pan"]
            off_target.append(abs(true_pan - pan))
            misread.append(abs(head.read_pose()[0] - true_pan))
    return off_target, misread


def test_a_joint_with_play_rests_where_it_was_asked_after_a_reversal():
    off_target, misread = _rests(0.25)
    assert max(off_target) < 0.05, off_target  # a tick of the encoder (0.088 deg) and the dead band
    assert max(misread) < 0.05, misread
    uncompensated, _ = _rests(0.0)
    assert max(uncompensated) > 0.12, uncompensated  # the joint trails its shaft by half the play
