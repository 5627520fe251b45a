"""Parsing the servo-bus config from plain mappings, and the interface's small helpers."""
from __future__ import annotations

import pytest

from drivers.errors import BackendNotFoundError, ServoConfigError
from drivers.dynamixel.tables.x_series import decode_hardware_error
from drivers.servo.bus import JOINTS, create_servo_bus
from drivers.servo.config import JointConfig, ServoBusConfig
from tests.support.servo_rigs import config_mapping


def test_a_full_config_parses_into_typed_objects():
    config = ServoBusConfig.from_mapping(config_mapping(
        backend="dynamixel", port="/dev/head-servos", baud=3_000_000, protocol=2.0, limit_policy="refuse",
        watchdog_ms=100, return_delay_us=4, torque_on_close=True,
        joints={"tilt": {"direction": -1, "zero_offset": 12.5, "model": "XL430-W250"}},
    ))
    assert list(config.joints) == list(JOINTS)
    tilt = config.joints["tilt"]
    assert (tilt.servo_id, tilt.direction, tilt.zero_offset, tilt.model) == (2, -1, 12.5, "XL430-W250")
    assert (config.baud, config.limit_policy, config.watchdog_ms, config.torque_on_close) == (3_000_000, "refuse", 100, True)
    assert tilt.servo_angle(10.0) == 2.5 and tilt.joint_angle(2.5) == 10.0


def test_defaults_fill_what_is_not_given():
    config = ServoBusConfig.from_mapping({"joints": {j: {"id": i} for i, j in enumerate(JOINTS, 1)}})
    assert (config.backend, config.baud, config.retries, config.limit_policy) == ("dynamixel", 1_000_000, 2, "clamp")
    assert config.reboot_on_hardware_error and not config.torque_on_close


@pytest.mark.parametrize(
    ("patch", "message"),
    [
        ({"speed": 5}, (r"servo_bus\.speed: got 5, expected a known key \(servo_bus takes joints, backend, port, .*"
                        r"reboot_timeout_s\); 'speed' is an unknown key")),
        ({"baud": 4_500_000}, r"servo_bus\.baud: got 4500000, expected one of 9600, .*4000000"),
        ({"limit_policy": "wrap"}, r"servo_bus\.limit_policy: got 'wrap', expected one of clamp, refuse"),
        ({"watchdog_ms": 30}, r"servo_bus\.watchdog_ms: got 30, expected a multiple of 20"),
        ({"retries": True}, r"servo_bus\.retries: got True, expected an integer"),
        ({"torque_on_close": "yes"}, r"servo_bus\.torque_on_close: got 'yes', expected true or false"),
        ({"joints": {"pan": {"id": 1}}}, (r"servo_bus\.joints\.tilt: missing, expected every one of pan, tilt, "
                                          r"left_eye, right_eye under servo_bus\.joints \(missing: tilt, left_eye, "
                                          r"right_eye\)")),
        ({"protocol": 3.0}, r"servo_bus\.protocol: got 3\.0, expected one of 2\.0, 1\.0$"),
        ({"return_delay_us": 3}, r"servo_bus\.return_delay_us: got 3, expected an even number"),
    ],
)
def test_bad_bus_values_name_key_path_value_and_expectation(patch, message):
    data = config_mapping()
    data.update(patch)
    with pytest.raises(ServoConfigError, match=message):
        ServoBusConfig.from_mapping(data)


@pytest.mark.parametrize(
    ("joint_patch", "message"),
    [
        ({"speed": 1}, (r"servo_bus\.joints\.tilt\.speed: got 1, expected a known key \(servo_bus\.joints\.tilt "
                        r"takes id, model, .*\); 'speed' is an unknown key")),
        ({"id": 300}, r"servo_bus\.joints\.tilt\.id: got 300, expected an integer in \[0, 252\]"),
        ({"direction": 2}, r"servo_bus\.joints\.tilt\.direction: got 2, expected one of 1, -1"),
        ({"min_angle": 10, "max_angle": 5}, r"tilt\.min_angle: got 10\.0, expected less than max_angle"),
        ({"zero_offset": 120, "max_angle": 90}, r"tilt\.max_angle: got 90\.0, expected an angle whose servo angle .*210"),
        ({"profile_velocity": "fast"}, r"tilt\.profile_velocity: got 'fast', expected a number"),
        ({"id": 1}, r"servo_bus\.joints\.tilt\.id: got 1, expected an id not already used by joint pan"),
    ],
)
def test_bad_joint_values_name_the_joint_key_path(joint_patch, message):
    with pytest.raises(ServoConfigError, match=message):
        ServoBusConfig.from_mapping(config_mapping(joints={"tilt": joint_patch}))


def test_joints_come_in_the_order_of_JOINTS_whatever_the_file_s():
    data = config_mapping()
    data["joints"] = dict(reversed(data["joints"].items()))
    assert list(ServoBusConfig.from_mapping(data).joints) == list(JOINTS)


def test_an_unknown_joint_is_rejected():
    data = config_mapping()
    data["joints"]["neck"] = {"id": 9}
    with pytest.raises(ServoConfigError, match=r"servo_bus\.joints\.neck: got \{'id': 9\}, expected a known key "
                                               r"\(servo_bus\.joints takes pan, tilt, left_eye, right_eye\); "
                                               r"'neck' is an unknown key"):
        ServoBusConfig.from_mapping(data)


def test_not_a_mapping():
    with pytest.raises(ServoConfigError, match=r"head\.servos: got \[1, 2\], expected a mapping with keys joints, "):
        ServoBusConfig.from_mapping([1, 2], key_path="head.servos")
    with pytest.raises(ServoConfigError, match=r"servo_bus\.joints\.pan\.id: missing, expected an integer in "
                                               r"\[0, 252\]"):
        JointConfig.from_mapping({}, "servo_bus.joints.pan")


def test_hardware_error_bits_decode_to_meanings():
    assert decode_hardware_error(0) == ()
    assert decode_hardware_error(0x25) == ("input voltage out of range", "overheating", "overload")
    assert decode_hardware_error(0x40) == ("unknown bits 0x40",)


def test_an_unknown_backend_is_not_an_import_error():
    config = ServoBusConfig.from_mapping(config_mapping(backend="canbus"))
    with pytest.raises(BackendNotFoundError, match="canbus"):
        create_servo_bus(config)
