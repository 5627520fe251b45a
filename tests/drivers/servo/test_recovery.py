"""The fault recovery policy (drivers.servo.recovery) on its own, on explicit times."""
from __future__ import annotations

import logging

from drivers.servo.recovery import Fault, FaultRecovery, RecoveryLimits

OVERLOAD_CUT = Fault(("overload",), torque_on=False)
VOLTAGE_KEPT = Fault(("input voltage out of range",), torque_on=True)


def test_an_error_that_cut_torque_is_rebooted_at_once_and_counted():
    recovery = FaultRecovery()
    assert recovery.due({"tilt": OVERLOAD_CUT}, 100.0) == [("tilt", "overload")]
    assert recovery.reboots == {("tilt", "overload"): 1}


def test_an_error_that_keeps_torque_waits_until_it_lasted():
    recovery = FaultRecovery(RecoveryLimits(persist_s=1.0))
    assert recovery.due({"pan": VOLTAGE_KEPT}, 10.0) == []
    assert recovery.due({"pan": VOLTAGE_KEPT}, 10.9) == []
    assert recovery.due({}, 10.95) == []  # gone: its clock starts again
    assert recovery.due({"pan": VOLTAGE_KEPT}, 11.0) == []
    assert recovery.due({"pan": VOLTAGE_KEPT}, 12.0) == [("pan", "input voltage out of range")]


def test_no_reboot_within_the_holdoff_and_a_person_after_the_limit(caplog):
    limits = RecoveryLimits(holdoff_s=10.0, max_reboots=3, window_s=600.0)
    recovery = FaultRecovery(limits)
    times = [0.0, 5.0, 10.0, 20.0, 30.0]
    with caplog.at_level(logging.ERROR, logger="drivers.servo.recovery"):
        rebooted = [bool(recovery.due({"pan": OVERLOAD_CUT}, t)) for t in times]
    assert rebooted == [True, False, True, True, False]  # 5 s: within the holdoff; 30 s: the fourth
    assert recovery.given_up == {"pan"} and recovery.reboots[("pan", "overload")] == 3
    assert "left to a person" in caplog.text and "joint pan" in caplog.text
    assert recovery.due({"pan": OVERLOAD_CUT}, 1000.0) == []  # however long after: a person's
    recovery.rebooted_by_hand("pan")
    assert recovery.due({"pan": OVERLOAD_CUT}, 1001.0) == [("pan", "overload")]


def test_reboots_older_than_the_window_no_longer_count():
    recovery = FaultRecovery(RecoveryLimits(holdoff_s=1.0, max_reboots=2, window_s=100.0))
    assert recovery.due({"tilt": OVERLOAD_CUT}, 0.0)
    assert recovery.due({"tilt": OVERLOAD_CUT}, 150.0)  # the one at 0 s has left the window
    assert recovery.due({"tilt": OVERLOAD_CUT}, 160.0)  # two within 100 s: the limit reached...
    assert not recovery.due({"tilt": OVERLOAD_CUT}, 170.0)  # ...so the third is a person's
    assert recovery.given_up == {"tilt"}
