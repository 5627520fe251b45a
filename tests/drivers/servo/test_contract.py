"""The servo-bus contract, run against every backend.

`rig` is parametrised over the simulated bus and the Dynamixel backend driving the
emulator through the real dynamixel-sdk, in Protocol 2.0 (X-series, Fast Sync Read) and
in Protocol 1.0 (MX-28: Bulk Read; AX-12A: per-servo reads); `-m hardware` with
HEADCTL_HW_CONFIG runs the basic contract on a real head. The fault contract needs fault
injection, so it runs on the sim and the emulator only. Positions are compared to within
the rig's servo resolution (`rig.tick_deg`); what some servos lack (acceleration control on
AX, a bus watchdog on Protocol 1.0) is tested only on the rigs that have it.
"""
from __future__ import annotations

import logging
import math

import pytest

from drivers.errors import (
    BusDownError,
    DeviceStateError,
    JointLimitError,
    ServoConfigError,
    ServoHardwareError,
)
from drivers.servo.bus import JOINTS, REOPEN_BACKOFF_MAX_S, BusState

EMULATED = ["dynamixel-emulator", "dynamixel-1.0-mx28-emulator", "dynamixel-1.0-ax12a-emulator"]
BACKENDS = ["sim", *EMULATED, pytest.param("hardware", marks=pytest.mark.hardware)]
FAULT_BACKENDS = ["sim", *EMULATED]
# What some servos lack is not tested on their rigs: AX servos have no acceleration control,
# Protocol 1.0 servos no bus watchdog.
ACCELERATION_BACKENDS = ["sim", "dynamixel-emulator", "dynamixel-1.0-mx28-emulator"]
WATCHDOG_BACKENDS = ["sim", "dynamixel-emulator"]


def _settle(rig, bus, timeout_s: float = 10.0) -> BusState:
    """Advance time until no joint moves; return the final state."""
    waited = 0.0
    state = bus.read_state()
    while state.moving:
        assert waited < timeout_s, f"still moving after {timeout_s} s: {state}"
        rig.advance(0.1)
        waited += 0.1
        state = bus.read_state()
    return state


# --- basic contract (also on hardware) ---------------------------------------------------
@pytest.mark.parametrize("make", BACKENDS, indirect=True)
class TestContract:
    def test_read_state_covers_every_joint_in_joint_units(self, make):
        rig = make()
        with rig.bus as bus:
            state = bus.read_state()
            assert set(state.joints) == set(JOINTS)
            for joint in JOINTS:
                s = state[joint]
                assert -180.0 <= s.position <= 180.0
                assert s.hardware_error_bits == 0 and s.hardware_errors == ()
                assert 0.0 < s.input_voltage_v < 30.0
                assert 0.0 < s.temperature_c < 90.0
            assert math.isfinite(state.time_s)

    def test_motion_needs_enable_and_enable_does_not_move(self, make):
        rig = make()
        with rig.bus as bus:
            before = bus.read_state().positions
            with pytest.raises(DeviceStateError, match="enable"):
                bus.write_goals({"pan": before["pan"] + 5})
            bus.enable()
            rig.advance(0.5)
            after = bus.read_state()
            for joint in JOINTS:
                assert after[joint].torque_on
                assert after[joint].position == pytest.approx(before[joint], abs=2 * rig.tick_deg)

    def test_goal_round_trip_in_degrees(self, make):
        rig = make()
        with rig.bus as bus:
            bus.enable()
            start = bus.read_state().positions
            goals = {"pan": start["pan"] + 5.0, "tilt": start["tilt"] - 4.0}
            assert bus.write_goals(goals) == goals
            rig.advance(0.02)
            assert bus.read_state().moving
            state = _settle(rig, bus)
            for joint, goal in goals.items():
                assert state[joint].position == pytest.approx(goal, abs=1.5 * rig.tick_deg)
            assert state["left_eye"].position == pytest.approx(start["left_eye"], abs=2 * rig.tick_deg)

    def test_disable_turns_torque_off_and_refuses_goals(self, make):
        rig = make()
        with rig.bus as bus:
            bus.enable()
            bus.disable()
            assert not any(s.torque_on for s in bus.read_state().joints.values())
            with pytest.raises(DeviceStateError):
                bus.write_goals({"pan": 0.0})

    def test_close_is_idempotent_and_turns_torque_off_by_default(self, make):
        rig = make()
        bus = rig.bus
        bus.open()
        bus.enable()
        bus.close()
        bus.close()
        assert not bus.is_open
        with pytest.raises(DeviceStateError):
            bus.read_state()
        if rig.kind != "hardware":
            assert not any(rig.torque_on(j) for j in JOINTS)

    def test_unknown_joint_and_non_finite_goal_are_refused(self, make):
        rig = make()
        with rig.bus as bus:
            bus.enable()
            with pytest.raises(ServoConfigError, match="'neck'"):
                bus.write_goals({"neck": 1.0})
            with pytest.raises(JointLimitError, match="pan"):
                bus.write_goals({"pan": float("nan")})


# --- contract with fault injection (sim and emulator) ------------------------------------
@pytest.mark.parametrize("make", FAULT_BACKENDS, indirect=True)
class TestFaultContract:
    def test_direction_and_zero_offset(self, make):
        rig = make(joints={"tilt": {"direction": -1, "zero_offset": 10.0}})
        with rig.bus as bus:
            # The servo rests at its centre: joint = -1 * (0 - 10) = 10.
            assert bus.read_state()["tilt"].position == pytest.approx(10.0, abs=rig.tick_deg)
            bus.enable()
            bus.write_goals({"tilt": 30.0})
            rig.advance(0.05)
            assert bus.read_state()["tilt"].velocity > 0  # joint frame: toward +30
            state = _settle(rig, bus)
            assert state["tilt"].position == pytest.approx(30.0, abs=rig.tick_deg)
            assert rig.servo_angle("tilt") == pytest.approx(10.0 - 30.0, abs=rig.tick_deg)

    def test_stale_goal_does_not_jump_at_enable(self, make):
        rig = make()
        with rig.bus as bus:
            rig.set_stale_goal("pan", 45.0)
            bus.enable()
            rig.advance(1.0)
            assert bus.read_state()["pan"].position == pytest.approx(0.0, abs=rig.tick_deg)

    def test_clamp_policy_clamps_and_logs(self, make, caplog):
        rig = make(limit_policy="clamp")
        with rig.bus as bus:
            bus.enable()
            with caplog.at_level(logging.WARNING, logger="drivers.servo.bus"):
                sent = bus.write_goals({"pan": 200.0, "tilt": -10.0})
            assert sent == {"pan": 90.0, "tilt": -10.0}
            assert "outside limits" in caplog.text and "pan" in caplog.text
            state = _settle(rig, bus)
            assert state["pan"].position == pytest.approx(90.0, abs=rig.tick_deg)
            assert state["tilt"].position == pytest.approx(-10.0, abs=rig.tick_deg)

    def test_refuse_policy_sends_nothing(self, make):
        rig = make(limit_policy="refuse")
        with rig.bus as bus:
            bus.enable()
            with pytest.raises(JointLimitError, match=r"joint pan \(id 1\).*200.*\[-90, 90\]"):
                bus.write_goals({"tilt": 20.0, "pan": 200.0})
            rig.advance(1.0)
            state = bus.read_state()
            # The whole command was refused: not even the valid tilt goal went out.
            assert state["tilt"].position == pytest.approx(0.0, abs=rig.tick_deg)
            assert not state.moving

    def test_torque_on_close_leaves_torque_on(self, make):
        rig = make(torque_on_close=True)
        with rig.bus as bus:
            bus.enable()
        assert all(rig.torque_on(j) for j in JOINTS)

    def test_hardware_error_reported_and_cleared_by_reboot(self, make, caplog):
        rig = make(reboot_on_hardware_error=False)
        with rig.bus as bus:
            bus.enable()
            bus.write_goals({"left_eye": 20.0})
            _settle(rig, bus)
            rig.hardware_error("left_eye", 0x20)  # overload: shutdown cuts torque
            with caplog.at_level(logging.ERROR, logger="drivers.servo.bus"):
                state = bus.read_state()
            assert state["left_eye"].hardware_error_bits == 0x20
            assert state["left_eye"].hardware_errors == ("overload",)
            assert state.faults == {"left_eye": ("overload",)}
            assert "joint left_eye (id 3)" in caplog.text and "overload" in caplog.text
            with pytest.raises(ServoHardwareError, match="left_eye.*overload"):
                bus.write_goals({"left_eye": 0.0})
            bus.reboot("left_eye")
            state = bus.read_state()
            assert state["left_eye"].hardware_error_bits == 0
            assert state["left_eye"].torque_on
            # Torque came back where the eye was: no jump.
            assert state["left_eye"].position == pytest.approx(20.0, abs=rig.tick_deg)
            bus.write_goals({"left_eye": 0.0})
            assert _settle(rig, bus)["left_eye"].position == pytest.approx(0.0, abs=rig.tick_deg)

    def test_a_servo_in_shutdown_refuses_enable_for_the_whole_bus(self, make):
        rig = make(reboot_on_hardware_error=False)
        with rig.bus as bus:
            rig.hardware_error("pan", 0x20)
            with pytest.raises(ServoHardwareError, match=r"joint pan \(id 1\).*overload"):
                bus.enable()
            assert not bus.is_enabled
            assert not any(s.torque_on for s in bus.read_state().joints.values())  # all or nothing
            bus.reboot("pan")
            bus.enable()
            assert all(s.torque_on for s in bus.read_state().joints.values())

    def test_hardware_error_recovered_by_automatic_reboot(self, make, caplog):
        rig = make(reboot_on_hardware_error=True)
        with rig.bus as bus:
            bus.enable()
            bus.write_goals({"tilt": -15.0})
            _settle(rig, bus)
            rig.hardware_error("tilt", 0x04)  # overheating
            with caplog.at_level(logging.WARNING, logger="drivers.servo.bus"):
                state = bus.read_state()
            assert "overheating" in caplog.text and "rebooting" in caplog.text
            assert state["tilt"].hardware_error_bits == 0
            assert state["tilt"].torque_on
            assert state["tilt"].position == pytest.approx(-15.0, abs=rig.tick_deg)
            # Rebooted inside the read, so the state reads clear; the fault log saw it all.
            [episode] = bus.fault_log.episodes().values()
            assert (episode.joint, episode.servo_id, episode.bits, episode.meanings) == ("tilt", 2, 0x04,
                                                                                       ("overheating",))
            assert (episode.recovery, episode.cleared_by) == ("rebooted", "automatic reboot")

    @pytest.mark.parametrize("auto_reboot", [False, True])
    def test_an_error_that_keeps_torque_is_rebooted_only_once_it_lasts(self, make, auto_reboot):
        rig = make(reboot_on_hardware_error=auto_reboot)
        with rig.bus as bus:
            bus.enable()
            rig.hardware_error("tilt", 0x01)  # input voltage: not in the default Shutdown mask
            state = bus.read_state()["tilt"]
            assert state.torque_on and state.hardware_errors == ("input voltage out of range",)
            bus.write_goals({"tilt": 5.0})  # the servo still works: goals go through
            assert _settle(rig, bus)["tilt"].position == pytest.approx(5.0, abs=rig.tick_deg)
            rig.advance(0.5)
            assert bus.read_state()["tilt"].hardware_error_bits == 0x01  # not yet: it may pass
            rig.advance(bus.recovery.limits.persist_s)
            state = bus.read_state()["tilt"]
            # Lasting: rebooted (the error is latched until then), torque back where it was.
            assert state.hardware_error_bits == (0 if auto_reboot else 0x01)
            assert state.torque_on and state.position == pytest.approx(5.0, abs=rig.tick_deg)
            assert bus.recovery.reboots == ({("tilt", "input voltage out of range"): 1} if auto_reboot else {})

    def test_a_repeating_hardware_error_is_not_rebooted_in_a_loop(self, make):
        rig = make(reboot_on_hardware_error=True)
        with rig.bus as bus:
            bus.enable()
            limits = bus.recovery.limits
            rig.hardware_error("pan", 0x04)
            assert bus.read_state()["pan"].hardware_error_bits == 0  # rebooted once
            rig.hardware_error("pan", 0x04)
            assert bus.read_state()["pan"].hardware_error_bits == 0x04  # reported, not rebooted
            for _ in range(limits.max_reboots - 1):  # back after each holdoff: rebooted again...
                rig.advance(limits.holdoff_s)
                assert bus.read_state()["pan"].hardware_error_bits == 0
                rig.hardware_error("pan", 0x04)
            rig.advance(limits.holdoff_s)  # ...until the limit: then left to a person
            assert bus.read_state()["pan"].hardware_error_bits == 0x04
            assert bus.recovery.given_up == {"pan"} and bus.recovery.reboots[("pan", "overheating")] == 3
            bus.reboot("pan")  # by hand: free again, and automatic recovery applies again
            assert bus.read_state()["pan"].hardware_error_bits == 0 and not bus.recovery.given_up

    def test_bus_down_then_back_restores_torque_after_reading_positions(self, make, caplog):
        rig = make()
        with rig.bus as bus:
            bus.enable()
            bus.write_goals({"pan": 12.0})
            _settle(rig, bus)
            rig.bus_down()
            with pytest.raises(BusDownError):
                bus.read_state()
            assert bus.is_down
            with pytest.raises(BusDownError, match="next reopen attempt"):
                bus.write_goals({"pan": 0.0})
            rig.advance(REOPEN_BACKOFF_MAX_S)
            with pytest.raises(BusDownError, match="reopen attempt 1 failed"):
                bus.read_state()  # the adapter is still gone
            rig.bus_up()
            rig.advance(REOPEN_BACKOFF_MAX_S)
            with caplog.at_level(logging.WARNING, logger="drivers.servo.bus"):
                state = bus.read_state()
            assert "back up" in caplog.text
            assert not bus.is_down
            assert state["pan"].torque_on
            assert state["pan"].position == pytest.approx(12.0, abs=rig.tick_deg)
            bus.write_goals({"pan": 0.0})
            assert _settle(rig, bus)["pan"].position == pytest.approx(0.0, abs=rig.tick_deg)

    def test_a_servo_missing_at_open_is_never_commanded_and_picked_up_where_it_is(self, make):
        rig = make()
        rig.remove_servo("left_eye")
        with rig.bus as bus:
            assert bus.present_joints == ("pan", "tilt", "right_eye")
            bus.enable()
            assert bus.write_goals({"pan": 10.0, "left_eye": 10.0}) == {"pan": 10.0}
            state = _settle(rig, bus)
            assert "left_eye" not in state.joints and "joint left_eye (id 3)" in state.missing["left_eye"]
            assert state["pan"].position == pytest.approx(10.0, abs=rig.tick_deg)
            where = rig.servo_angle("left_eye")
            rig.add_servo("left_eye")
            rig.advance(5.0)  # its boot and the ping back-off
            state = bus.read_state()
            assert not state.missing and state["left_eye"].torque_on and rig.torque_on("left_eye")
            rig.advance(1.0)
            assert rig.servo_angle("left_eye") == pytest.approx(where, abs=rig.tick_deg), "it jumped when it came back"
            bus.write_goals({"left_eye": 10.0})
            assert _settle(rig, bus)["left_eye"].position == pytest.approx(10.0, abs=rig.tick_deg)

    def test_disable_while_the_bus_is_down_takes_effect_when_it_is_back(self, make):
        rig = make()
        with rig.bus as bus:
            bus.enable()
            rig.bus_down()
            with pytest.raises(BusDownError):
                bus.read_state()
            with pytest.raises(BusDownError):
                bus.disable()
            assert not bus.is_enabled
            rig.bus_up()
            rig.advance(REOPEN_BACKOFF_MAX_S)
            assert not any(s.torque_on for s in bus.read_state().joints.values())


# --- what only some servos have ------------------------------------------------------
@pytest.mark.parametrize("make", ACCELERATION_BACKENDS, indirect=True)
def test_profile_velocity_and_acceleration_shape_the_move(make):
    rig = make(joints={"pan": {"profile_velocity": 50.0, "profile_acceleration": 500.0}})
    with rig.bus as bus:
        bus.enable()
        bus.write_goals({"pan": 60.0})
        # 0.1 s to reach 50 deg/s (2.5 deg), 1.1 s cruising, 0.1 s braking: 1.3 s.
        rig.advance(0.6)
        mid = bus.read_state()["pan"]
        assert mid.moving
        assert mid.velocity == pytest.approx(50.0, rel=0.05)
        assert mid.position == pytest.approx(2.5 + 50.0 * 0.5, abs=1.0)
        rig.advance(0.8)
        end = bus.read_state()["pan"]
        assert not end.moving
        assert end.position == pytest.approx(60.0, abs=rig.tick_deg)


@pytest.mark.parametrize("make", WATCHDOG_BACKENDS, indirect=True)
def test_bus_watchdog_stops_the_head_when_the_host_falls_silent(make):
    rig = make(watchdog_ms=100, joints={"pan": {"profile_velocity": 50.0, "profile_acceleration": 0}})
    with rig.bus as bus:
        bus.enable()
        bus.write_goals({"pan": 80.0})  # 1.6 s at 50 deg/s
        rig.advance(0.05)
        bus.read_state()
        rig.advance(1.0)  # the host is silent for 1 s
        state = bus.read_state()
        # Stopped 0.1 s after the last packet: about 0.15 s * 50 deg/s.
        assert state["pan"].position == pytest.approx(7.5, abs=1.0)
        assert not state["pan"].moving
        # The host speaks again: the watchdog is re-armed and goals work.
        bus.write_goals({"pan": 10.0})
        rig.advance(0.05)
        bus.read_state()
        rig.advance(0.05)
        assert bus.read_state()["pan"].position == pytest.approx(10.0, abs=rig.tick_deg)
