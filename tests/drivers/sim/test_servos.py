"""The simulated servo bus and the motion model it shares with the emulator."""
from __future__ import annotations

import math

import pytest

from drivers.clock import ManualClock
from drivers.errors import BusDownError, ServoTimeoutError
from drivers.servo.bus import create_servo_bus
from drivers.servo.config import ServoBusConfig
from drivers.sim.servos import ProfileAxis, SimulatedServoBus
from tests.support.servo_rigs import config_mapping


# --- ProfileAxis ------------------------------------------------------------------------
def test_trapezoidal_profile_timing():
    axis = ProfileAxis(0.0, 0.0, max_velocity=100.0, max_acceleration=500.0)
    axis.set_goal(90.0)
    # 0.2 s accelerating (10 deg), 0.7 s at 100 deg/s (70 deg), 0.2 s braking (10 deg).
    axis.advance_to(0.2)
    assert axis.velocity == pytest.approx(100.0, rel=0.01)
    assert axis.position == pytest.approx(10.0, abs=0.2)
    axis.advance_to(0.9)
    assert axis.position == pytest.approx(80.0, abs=0.3)
    assert axis.moving
    axis.advance_to(1.11)
    assert not axis.moving and axis.position == 90.0 and axis.velocity == 0.0


def test_triangular_profile_when_the_move_is_short():
    axis = ProfileAxis(0.0, 0.0, max_velocity=1000.0, max_acceleration=100.0)
    axis.set_goal(4.0)  # peak 20 deg/s after 0.2 s, never reaching the limit
    axis.advance_to(0.2)
    assert axis.velocity == pytest.approx(20.0, rel=0.05)
    axis.advance_to(0.45)
    assert axis.position == 4.0 and not axis.moving


def test_unlimited_axis_jumps_and_a_new_goal_reverses_smoothly():
    axis = ProfileAxis(0.0, 0.0)
    axis.set_goal(10.0)
    axis.advance_to(0.001)
    assert axis.position == 10.0
    axis = ProfileAxis(0.0, 0.0, max_velocity=50.0, max_acceleration=100.0)
    axis.set_goal(50.0)
    axis.advance_to(0.5)
    assert axis.velocity > 0
    axis.set_goal(-10.0)
    axis.advance_to(0.51)
    assert axis.velocity > 0  # it cannot reverse instantly
    axis.advance_to(5.0)
    assert axis.position == -10.0 and not axis.moving


def test_time_going_back_is_ignored():
    axis = ProfileAxis(0.0, 1.0, max_velocity=10.0, max_acceleration=math.inf)
    axis.set_goal(5.0)
    axis.advance_to(0.5)
    assert axis.position == 0.0


# --- SimulatedServoBus ------------------------------------------------------------------
def _bus(**config):
    clock = ManualClock(0.0)
    return SimulatedServoBus(ServoBusConfig.from_mapping(config_mapping(**config)), clock=clock), clock


def test_created_by_name_from_the_backend_table():
    bus = create_servo_bus(ServoBusConfig.from_mapping(config_mapping(backend="sim")), clock=ManualClock())
    assert isinstance(bus, SimulatedServoBus)
    assert {"reboot", "fault_injection", "watchdog"} <= bus.capabilities


def test_initial_positions_and_state_survive_close_and_reopen():
    clock = ManualClock(0.0)
    config = ServoBusConfig.from_mapping(config_mapping())
    bus = SimulatedServoBus(config, clock=clock, initial_positions={"pan": 15.0})
    with bus:
        assert bus.read_state()["pan"].position == pytest.approx(15.0)
        bus.enable()
        bus.write_goals({"tilt": 20.0})
        clock.advance(2.0)
    assert bus.true_position("tilt") == pytest.approx(20.0)
    with bus:
        assert bus.read_state()["tilt"].position == pytest.approx(20.0)


def test_read_state_time_is_the_clock():
    bus, clock = _bus()
    clock.advance(42.0)
    with bus:
        assert bus.read_state().time_s == 42.0


def test_bus_down_hook_fails_open_until_restored():
    bus, clock = _bus()
    bus.inject_bus_down()
    with pytest.raises(BusDownError, match="unplugged"):
        bus.open()
    bus.restore_bus()
    with bus:
        assert not bus.is_down


# --- wiring: the simulated head's truth, and its servos by id ---------------------------
WIRING = {1: {"joint": "tilt", "direction": -1, "zero_offset": 10.0}, 2: {"joint": "pan"},
          3: {"joint": "left_eye"}, 4: {"joint": "right_eye", "direction": -1}}


def test_a_bus_drives_servos_by_id_and_the_wiring_decides_which_joint_moves():
    from drivers.servo.config import ServoBusConfig

    clock = ManualClock()
    config = ServoBusConfig.from_mapping(config_mapping(wiring=WIRING))  # joints believe pan is id 1
    bus = SimulatedServoBus(config, clock=clock, initial_positions={"pan": 0, "tilt": 0, "left_eye": 0,
                                                                    "right_eye": 0})
    with bus:
        assert bus.true_position("tilt") == pytest.approx(0.0)  # servo 1 starts at its wired zero, 10 deg
        bus.enable()
        bus.write_goals({"pan": 15.0})  # servo 1: 15 deg from its centre
        clock.advance(2.0)
        assert bus.true_position("tilt") == pytest.approx(-5.0)  # -1 * (15 - 10)
        assert bus.true_position("pan") == pytest.approx(0.0)


def test_wiring_is_checked_and_only_the_simulated_bus_takes_it():
    from drivers.backends import check_servo_bus_config
    from drivers.dynamixel.bus_v2 import DynamixelBus
    from drivers.errors import ServoConfigError
    from drivers.servo.config import PartialServoBusConfig, ServoBusConfig

    with pytest.raises(ServoConfigError, match=r"servo_bus\.wiring\.3\.joint: got 'pan', expected a joint not "
                                               r"already wired to id 2"):
        PartialServoBusConfig.from_mapping({"backend": "sim", "wiring": {**WIRING, 3: {"joint": "pan"}}})
    with pytest.raises(ServoConfigError, match=r"servo_bus\.wiring: .*right_eye missing"):
        PartialServoBusConfig.from_mapping({"backend": "sim", "wiring": {k: WIRING[k] for k in (1, 2, 3)}})
    with pytest.raises(ServoConfigError, match=r"servo_bus\.wiring\.x: .*a servo id"):
        PartialServoBusConfig.from_mapping({"backend": "sim", "wiring": {"x": {"joint": "pan"}}})
    with pytest.raises(ServoConfigError, match=r"servo_bus\.joints: missing"):
        ServoBusConfig.from_mapping({"backend": "sim", "wiring": WIRING})  # a head to run needs its joints
    config = ServoBusConfig.from_mapping(config_mapping(backend="dynamixel", wiring=WIRING))
    with pytest.raises(ServoConfigError, match=r"servo_bus\.wiring: .*not used by the 'dynamixel' backend"):
        check_servo_bus_config(config, DynamixelBus)


def test_the_probe_moves_servos_by_id_safely():
    from drivers.errors import JointLimitError
    from drivers.servo.config import PartialServoBusConfig
    from drivers.servo.probe import MotionSafety, create_servo_probe

    clock = ManualClock()
    probe = create_servo_probe(PartialServoBusConfig.from_mapping({"backend": "sim", "wiring": WIRING}), clock=clock)
    with probe:
        assert [s.servo_id for s in probe.scan()] == [1, 2, 3, 4]
        probe.limit_motion(2, MotionSafety(velocity_dps=10.0, acceleration_dps2=1e6, watchdog_s=0.5))
        probe.set_torque(2, True)
        probe.write_goal(2, 20.0)
        for _ in range(10):  # the host reads it every 0.1 s: the watchdog stays quiet
            clock.advance(0.1)
            probe.status(2)
        assert probe.status(2).position_deg == pytest.approx(10.0, abs=0.1)  # 10 deg/s
        clock.advance(0.6)  # the host falls silent longer than the watchdog: it stops there
        assert probe.status(2).position_deg == pytest.approx(15.0, abs=0.1)
        assert not probe.status(2).moving
        with pytest.raises(JointLimitError, match="id 2 .*outside the servo's own limits"):
            probe.write_goal(2, 200.0)
        probe.restore_motion(2)
        assert probe.torque_limit(2) is None


def test_a_servo_missing_at_open_is_driven_around_and_picked_up_without_a_jump():
    clock = ManualClock(0.0)
    bus = SimulatedServoBus(ServoBusConfig.from_mapping(config_mapping()), clock=clock)
    bus.remove_servo("left_eye")  # missing at start
    with bus:
        missing = bus.missing["left_eye"]
        assert (missing.servo_id, missing.port) == (3, bus.name)
        assert "no reply (the simulated servo is off the bus)" in missing.reason
        bus.enable()
        assert bus.write_goals({"pan": 10.0, "left_eye": 8.0}) == {"pan": 10.0}
        clock.advance(2.0)
        state = bus.read_state()
        assert set(state.joints) == {"pan", "tilt", "right_eye"} and set(state.missing) == {"left_eye"}
        assert bus.true_position("pan") == pytest.approx(10.0) and bus.true_position("left_eye") == 0.0
        bus.add_servo("left_eye")
        clock.advance(5.0)  # past the next ping of its back-off
        state = bus.read_state()
        assert state["left_eye"].torque_on and state["left_eye"].position == pytest.approx(0.0)
        assert not bus.missing


def test_a_servo_off_the_bus_while_running_is_dropped_after_half_a_second_and_back_without_a_jump():
    clock = ManualClock(0.0)
    bus = SimulatedServoBus(ServoBusConfig.from_mapping(config_mapping()), clock=clock)
    with bus:
        bus.enable()
        bus.write_goals({"pan": 10.0, "left_eye": 8.0})
        clock.advance(2.0)
        bus.remove_servo("left_eye")  # unplugged while running: it stops, torque gone
        with pytest.raises(ServoTimeoutError, match=r"joint left_eye \(id 3\)"):
            bus.read_state()
        clock.advance(0.5)
        assert set(bus.read_state().missing) == {"left_eye"}
        bus.write_goals({"pan": -10.0, "left_eye": -8.0})
        clock.advance(2.0)
        assert bus.true_position("pan") == pytest.approx(-10.0)
        assert bus.true_position("left_eye") == pytest.approx(8.0)
        bus.add_servo("left_eye")  # back, just powered up: torque off, goal at its position
        clock.advance(5.0)
        state = bus.read_state()
        assert state["left_eye"].torque_on  # restored by the bus, at the position read back
        clock.advance(1.0)
        assert bus.true_position("left_eye") == pytest.approx(8.0), "the servo jumped when it came back"


# --- a brown-out: every servo loses power and comes back ---------------------------------
def _brown_out_rig(**bus):
    clock = ManualClock(100.0)
    bus_ = SimulatedServoBus(ServoBusConfig.from_mapping(config_mapping(**bus)), clock=clock)
    bus_.open()
    bus_.enable()
    bus_.write_goals({"pan": 20.0, "tilt": -10.0})
    clock.advance(2.0)
    bus_.read_state()
    return clock, bus_


def test_a_brown_out_is_silence_then_the_servos_are_initialised_again_without_a_jump(caplog):
    from drivers.errors import ServoTimeoutError
    clock, bus = _brown_out_rig()
    with bus:
        bus.inject_power_loss()
        clock.advance(0.5)
        with pytest.raises(ServoTimeoutError, match="no servo answered"):
            bus.read_state()
        resting = {joint: bus.true_position(joint) for joint in ("pan", "tilt")}
        bus.restore_power()
        assert all(servo.axis.max_velocity == bus.max_velocity_dps for servo in bus._servos.values())  # RAM defaults
        with caplog.at_level("WARNING"):
            state = bus.read_state()
        assert "lost power and came back" in caplog.text and "torque restored" in caplog.text
        assert bus.power_losses == 1 and bus.is_enabled
        assert all(state[joint].torque_on for joint in state.joints)
        # The settings are the config's again and the goals are where the servos were: no jump.
        assert all(servo.axis.max_velocity == 100.0 and servo.axis.max_acceleration == 1000.0
                   for servo in bus._servos.values())
        clock.advance(1.0)
        assert bus.read_state()["pan"].position == pytest.approx(resting["pan"], abs=1e-6)
        assert bus.true_position("tilt") == pytest.approx(resting["tilt"], abs=1e-6)
        bus.write_goals({"pan": 0.0})  # and it obeys again
        clock.advance(2.0)
        assert bus.read_state()["pan"].position == pytest.approx(0.0, abs=1e-6)
        assert bus.power_losses == 1  # healed once, not on every read


def test_a_brown_out_that_leaves_an_input_voltage_error_is_healed_too():
    clock, bus = _brown_out_rig()
    with bus:
        bus.inject_power_loss()
        clock.advance(0.2)
        bus.restore_power(bits=0x01)  # Input Voltage error
        bus.read_state()
        clock.advance(1.5)  # an error that leaves torque on is rebooted once it lasted 1 s
        state = bus.read_state()
        assert not state.faults and all(state[joint].torque_on for joint in state.joints)
        assert bus.power_losses == 1
        assert all(servo.axis.max_velocity == 100.0 for servo in bus._servos.values())


def test_with_power_loss_torque_off_the_head_stays_limp_until_enabled_by_hand():
    from drivers.errors import DeviceStateError
    clock, bus = _brown_out_rig(power_loss_torque="off")
    with bus:
        bus.inject_power_loss()
        clock.advance(0.2)
        bus.restore_power()
        state = bus.read_state()
        assert not bus.is_enabled and not any(state[joint].torque_on for joint in state.joints)
        assert "torque off on every joint" in (bus.last_power_loss or "")
        with pytest.raises(DeviceStateError):
            bus.write_goals({"pan": 0.0})
        before = state["pan"].position
        bus.enable()  # goal := present first: no jump
        clock.advance(1.0)
        assert bus.read_state()["pan"].position == pytest.approx(before, abs=1e-6)


def test_servos_found_at_ram_defaults_on_a_bus_not_enabled_get_their_settings_back():
    clock = ManualClock(100.0)
    bus = SimulatedServoBus(ServoBusConfig.from_mapping(config_mapping()), clock=clock)
    with bus:
        bus.inject_power_loss()
        bus.restore_power()
        state = bus.read_state()
        assert bus.power_losses == 1 and not bus.is_enabled
        assert not any(state[joint].torque_on for joint in state.joints)
        assert all(servo.axis.max_velocity == 100.0 for servo in bus._servos.values())
