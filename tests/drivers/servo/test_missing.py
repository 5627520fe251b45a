"""The record of servos that do not answer: back-off of the pings, drop-off of a servo
whose reads fail alone."""
from __future__ import annotations

import pytest

from drivers.errors import ServoTimeoutError
from drivers.servo.missing import MissingServos

IDS = {"pan": 1, "tilt": 2, "left_eye": 3, "right_eye": 4}


def test_a_missing_servo_is_pinged_again_after_0_1_s_doubling_to_5_s():
    missing = MissingServos(IDS, "/dev/head-servos")
    err = ServoTimeoutError("joint left_eye (id 3) on /dev/head-servos: ping failed: no status packet")
    missing.add("left_eye", err, 10.0, " at open")
    entry = missing.snapshot()["left_eye"]
    assert (entry.servo_id, entry.port, entry.reason) == (3, "/dev/head-servos", "ping failed: no status packet")
    assert entry.describe() == "joint left_eye (id 3) on /dev/head-servos: not answering (ping failed: no status packet)"
    now, waits = 10.0, []
    for _ in range(8):
        due_at = now + 0.001
        while not missing.due(due_at):
            due_at += 0.001
        waits.append(round(due_at - now, 2))
        now = due_at
        missing.ping_failed("left_eye", now, err)
    assert waits == [0.1, 0.2, 0.4, 0.8, 1.6, 3.2, 5.0, 5.0]
    assert missing.found("left_eye").since_s == 10.0
    assert not missing.snapshot() and "left_eye" not in missing


@pytest.mark.parametrize("blamed, dropped", [
    (("left_eye",), ["left_eye"]),
    (("pan", "tilt", "left_eye", "right_eye"), []),  # all of them: power or wiring, not one servo
    ((), []),  # the request itself failed: the bus
])
def test_reads_failing_for_one_servo_drop_it_after_half_a_second(blamed, dropped):
    missing = MissingServos(IDS, "/dev/head-servos")
    assert missing.read_failed(blamed, IDS, 1.0) == []
    assert missing.read_failed(blamed, IDS, 1.4) == []
    assert missing.read_failed(blamed, IDS, 1.5) == dropped


def test_a_read_that_works_restarts_the_count():
    missing = MissingServos(IDS, "/dev/head-servos")
    missing.read_failed(["tilt"], IDS, 1.0)
    missing.read_ok()
    assert missing.read_failed(["tilt"], IDS, 1.6) == []
    assert missing.read_failed(["tilt"], IDS, 2.1) == ["tilt"]
