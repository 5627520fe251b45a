from __future__ import annotations

import pickle

import pytest

from drivers.errors import BusDownError, DriverError, JointLimitError, ServoConfigError
from drivers.servo.bus import ServoBus
from drivers.sim.servos import SimulatedServoBus
from headctl.errors import ServoLoopStoppedError
from headctl.service.servo_io.messages import (ERROR_CLASSES, Done, ErrorKind, FaultsChanged, InjectFault,
                                               RemoteError, ServoFault, Stopped, WriteGoals)
from headctl.service.servo_io.process import ServoProcessError


@pytest.mark.parametrize("kind", sorted(ERROR_CLASSES, key=lambda k: k.value))
def test_an_error_of_the_table_crosses_as_its_own_class(kind):
    err = ERROR_CLASSES[kind]("what went wrong")
    remote = pickle.loads(pickle.dumps(RemoteError.of(err)))
    assert remote.kind is kind
    again = remote.exception(ServoProcessError)
    assert type(again) is type(err) and str(again) == "what went wrong"


def test_an_error_outside_the_table_is_raised_as_the_receivers_fallback():
    remote = RemoteError.of(ServoConfigError(key_path="servo_bus.port", value="x", expected="a port"))
    assert remote.kind is ErrorKind.OTHER
    assert type(remote.exception(ServoProcessError)) is ServoProcessError
    assert type(remote.exception(DriverError)) is DriverError
    assert "servo_bus.port" in str(remote.exception(DriverError))


def test_messages_survive_the_pipe():
    for message in (WriteGoals(1, {"pan": 3.0}), InjectFault(2, ServoFault("hardware_error"), "pan", 32),
                    Done(1, {"pan": 3.0}), Done(2, error=RemoteError.of(BusDownError("down"))),
                    FaultsChanged(None, {"pan": ("overload",)}, ""), Stopped()):
        assert pickle.loads(pickle.dumps(message, protocol=pickle.HIGHEST_PROTOCOL)) == message
    assert RemoteError.of(JointLimitError("x")).kind is ErrorKind.JOINT_LIMIT
    assert RemoteError.of(ServoLoopStoppedError("x")).kind is ErrorKind.LOOP_STOPPED


def test_a_simulated_bus_declares_that_it_reports_its_true_motion():
    assert SimulatedServoBus.reports_true_motion
    assert not ServoBus.reports_true_motion
