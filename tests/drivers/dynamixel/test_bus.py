"""The Dynamixel backend through the real dynamixel-sdk against the emulator: what is
specific to it (retries, timeouts, SDK pitfalls, EEPROM handling, scan)."""
from __future__ import annotations

import argparse
import errno
import logging
import time

import dynamixel_sdk as sdk
import pytest

from drivers.dynamixel.tables.x_series import DPS_PER_VELOCITY_UNIT, READ_BLOCK_ADDRESSES, XAddr
from drivers.dynamixel.emulator.server import DxlEmulator
from drivers.dynamixel.sdk import BlockingPortHandler, port_access_hint
from drivers.dynamixel.scan import scan
from drivers.dynamixel.bus_v2 import DynamixelBus
from drivers.errors import ServoCommError, ServoConfigError, ServoModelError, ServoTimeoutError
from drivers.servo.bus import JOINTS
from drivers.servo.config import ServoBusConfig
from headctl.cli import servos as cmd_servos
from tests.support.servo_rigs import IDS, EmulatorRig, config_mapping


def _servo(r, joint):
    return r.emulator.servo(IDS[joint])


# --- retries and timeouts ----------------------------------------------------------------
def test_a_dropped_reply_is_retried(rig):
    r = rig(retries=2)
    with r.bus as bus:
        r.emulator.drop_replies(IDS["tilt"], count=2)
        assert bus.read_state()["tilt"].position == pytest.approx(0.0, abs=0.1)


def test_dropped_replies_beyond_the_retries_name_port_joint_and_id(rig):
    r = rig(retries=1)
    with r.bus as bus:
        r.emulator.drop_replies(IDS["tilt"], count=2)
        with pytest.raises(ServoTimeoutError) as info:
            bus.read_state()
        message = str(info.value)
        assert "joint tilt (id 2)" in message and r.link in message and "2 attempt" in message
        assert isinstance(info.value, TimeoutError)
        r.emulator.wait_idle()
        assert bus.read_state()["tilt"].position == pytest.approx(0.0, abs=0.1)  # and it recovers


def test_corrupted_crc_is_retried_then_reported(rig):
    r = rig(retries=1)
    with r.bus as bus:
        r.emulator.corrupt_replies(IDS["left_eye"], count=1)
        bus.read_state()
        r.emulator.corrupt_replies(IDS["left_eye"], count=2)
        with pytest.raises(ServoCommError, match=r"joint left_eye \(id 3\).*Incorrect status packet"):
            bus.read_state()


def test_a_late_reply_within_the_timeout_is_accepted_and_a_later_one_times_out(rig):
    r = rig(retries=0)
    with r.bus as bus:
        r.emulator.delay_replies(IDS["pan"], 0.002)
        bus.read_state()
        r.emulator.delay_replies(IDS["pan"], 0.2)
        started = time.monotonic()
        with pytest.raises(ServoTimeoutError, match=r"joint pan \(id 1\)"):
            bus.read_state()
        # The reply timeout follows the configured latency (8 ms here: ~20 ms), not the SDK's 34 ms.
        assert time.monotonic() - started < 0.1
        r.emulator.wait_idle()  # the late reply has gone out and is flushed by the next read
        bus.read_state()


def test_late_replies_are_drained_before_a_retry(rig):
    r = rig(retries=0)
    with r.bus as bus:
        r.emulator.delay_replies(IDS["pan"], 0.03)  # later than the ~19 ms timeout
        model, result, _error = bus._packet.ping(bus._port, IDS["pan"])
        assert result == sdk.COMM_RX_TIMEOUT
        # The SDK matches replies by id only: this late reply would be taken as the
        # answer to the next request to pan. It is discarded instead.
        assert bus._port.drain_late_replies() == 14  # one ping status packet
        assert bus._read("pan", XAddr.PRESENT_TEMPERATURE, 1) == 35


@pytest.mark.parametrize("fault", ["late", "dropped"])
def test_a_failed_sync_read_blames_the_servo_that_failed_not_the_one_read_first(rig, fault):
    # Id 4 answers last; late (a second, much longer than the three attempts), it holds up
    # the replies to the retries behind it, so that in those the others look silent too.
    # The blame still goes to id 4.
    r = rig(retries=2)
    with r.bus as bus:
        if fault == "late":
            r.emulator.delay_replies(IDS["right_eye"], 1.0, count=1)
        else:
            r.emulator.drop_replies(IDS["right_eye"], count=3)
        with pytest.raises(ServoTimeoutError) as info:
            bus.read_state()
        message = str(info.value)
        assert message.startswith(f"joint right_eye (id 4) on {r.link}: sync read failed after 3 attempt(s)")
        assert "pan" not in message and "id 1" not in message
        r.emulator.wait_idle()
        assert bus.read_state()["right_eye"].position == pytest.approx(0.0, abs=0.1)  # and it recovers


def test_a_reply_that_comes_after_the_timeout_is_named_late(rig):
    # Timeout ~43 ms, then the line is drained until quiet for as long: a reply 65 ms late
    # arrives while draining, and says whose it was; so in each attempt.
    r = rig(retries=2, latency_timer_ms=20)
    with r.bus as bus:
        r.emulator.delay_replies(IDS["right_eye"], 0.065, count=3)
        with pytest.raises(ServoTimeoutError, match=r"^joint right_eye \(id 4\) .*came after the timeout"):
            bus.read_state()


def test_two_failing_servos_are_both_named_with_what_each_did(rig):
    r = rig(retries=1)
    with r.bus as bus:
        r.emulator.corrupt_replies(IDS["tilt"], count=2)
        r.emulator.drop_replies(IDS["right_eye"], count=2)
        with pytest.raises(ServoCommError) as info:
            bus.read_state()
        assert not isinstance(info.value, ServoTimeoutError)  # one of them answered, corrupt
        message = str(info.value)
        assert message.startswith(f"{r.link}: sync read failed after 2 attempt(s): ")
        assert "joint tilt (id 2): [TxRxResult] Incorrect status packet" in message
        assert "joint right_eye (id 4): [TxRxResult] There is no status packet" in message
        assert "pan" not in message and "left_eye" not in message


def test_the_blame_over_attempts():
    from drivers.dynamixel.sdk import SyncReadAttempt, blame_sync_read

    timeout, corrupt = sdk.COMM_RX_TIMEOUT, sdk.COMM_RX_CORRUPT
    everyone = frozenset({1, 2, 3, 4})

    def attempt(failures, late=()):
        return SyncReadAttempt(everyone - set(failures), failures, late)

    silent = SyncReadAttempt(frozenset(), {i: timeout for i in everyone}, ())
    # Late: the retries found the line busy; they say nothing about any one servo.
    assert blame_sync_read([attempt({4: timeout}), silent, silent]) == {4: timeout}
    # One servo recovered on the retry, the other did not.
    assert blame_sync_read([attempt({2: corrupt, 4: timeout}), attempt({4: timeout})]) == {4: timeout}
    # The failures moved (the others held up behind the first culprit): the first attempt's word.
    assert blame_sync_read([attempt({4: timeout}), attempt({1: timeout, 2: timeout})]) == {4: timeout}
    # Nobody ever answered: everyone (the caller names the first in turn, or a late one).
    assert blame_sync_read([silent, silent]) == {i: timeout for i in everyone}


def test_waiting_for_a_reply_does_not_busy_wait(rig):
    r = rig(retries=0, latency_timer_ms=50)
    with r.bus as bus:
        r.emulator.drop_replies(IDS["pan"], count=1)
        wall, cpu = time.monotonic(), time.process_time()
        with pytest.raises(ServoTimeoutError):
            bus.read_state()
        wall, cpu = time.monotonic() - wall, time.process_time() - cpu
        assert wall > 0.09  # two latency timers: the wait really happened
        assert cpu < 0.3 * wall, f"{cpu:.3f} s CPU for {wall:.3f} s of waiting"


def test_reply_timeout_follows_latency_timer_and_return_delay():
    handler = BlockingPortHandler("/dev/null", latency_timer_ms=1.0, reply_slack_ms=3.0)
    handler.tx_time_per_byte = 0.01  # 1 Mbps
    handler.setPacketTimeout(4 * 27)
    assert handler.packet_timeout == pytest.approx(1.08 + 2.0 + 3.0)


# --- open: model check, EEPROM, indirect map -----------------------------------------
def test_a_wrong_model_is_refused_at_open(tmp_path):
    r = EmulatorRig(tmp_path, model="XL430-W250")
    try:
        with pytest.raises(ServoModelError, match=r"joint pan \(id 1\).*1060 \(XL430-W250\).*XM430-W350 \(1020\)"):
            r.bus.open()
        assert not r.bus.is_open
    finally:
        r.close()


def test_an_absent_servo_is_recorded_missing_at_open_naming_joint_id_and_port(tmp_path):
    r = EmulatorRig(tmp_path, retries=0, joints={"right_eye": {"id": 9}})
    try:
        with r.bus as bus:
            missing = bus.missing["right_eye"]
            assert (missing.joint, missing.servo_id, missing.port) == ("right_eye", 9, r.link)
            assert missing.describe().startswith(f"joint right_eye (id 9) on {r.link}: not answering (")
            assert bus.present_joints == ("pan", "tilt", "left_eye")
    finally:
        r.close()


def test_open_fails_when_no_servo_answers_naming_each(tmp_path):
    r = EmulatorRig(tmp_path, retries=0)
    try:
        for servo_id in IDS.values():
            r.emulator.remove_servo(servo_id)
        with pytest.raises(ServoTimeoutError, match=r"no servo answered: joint pan \(id 1\).*joint right_eye \(id 4\)"):
            r.bus.open()
        assert not r.bus.is_open
    finally:
        r.close()


def test_an_unknown_model_name_is_a_config_error():
    config = ServoBusConfig.from_mapping(config_mapping(backend="dynamixel", joints={"tilt": {"model": "XM430"}}))
    with pytest.raises(ServoConfigError, match=r"servo_bus\.joints\.tilt\.model: got 'XM430'"):
        DynamixelBus(config)


def test_open_writes_eeprom_with_torque_off_and_keeps_a_holding_servo_in_place(rig, caplog):
    r = rig(return_delay_us=0)
    pan = _servo(r, "pan")
    # A servo left holding at tick 2100 by an earlier session, default Return Delay Time.
    pan.table[XAddr.GOAL_POSITION:XAddr.GOAL_POSITION + 4] = (2100).to_bytes(4, "little")
    pan.axis.position = pan.axis.goal = 2100.0
    pan.table[XAddr.TORQUE_ENABLE] = 1
    assert pan.table[XAddr.RETURN_DELAY_TIME] == 250
    with caplog.at_level(logging.INFO, logger="drivers.dynamixel.bus_v2"):
        with r.bus as bus:
            state = bus.read_state()
    assert "torque briefly off" in caplog.text
    assert pan.table[XAddr.RETURN_DELAY_TIME] == 0
    assert state["pan"].torque_on
    assert pan.get(XAddr.PRESENT_POSITION, 4) == 2100
    # Position limits follow the joint limits (+-90 deg = +-1024 ticks around the centre).
    assert (pan.get(XAddr.MIN_POSITION_LIMIT, 4), pan.get(XAddr.MAX_POSITION_LIMIT, 4)) == (1024, 3072)


def test_eeprom_is_not_rewritten_when_it_already_matches(rig):
    r = rig()
    with r.bus:
        pass
    pan = _servo(r, "pan")
    writes = []
    original = pan.write
    pan.write = lambda addr, data: (writes.append(addr), original(addr, data))[1]
    with r.bus:
        pass
    assert all(addr >= XAddr.EEPROM_END and addr not in range(168, 224) for addr in writes), writes


def test_the_sync_read_block_comes_through_indirect_addresses(rig):
    r = rig()
    with r.bus:
        servo = _servo(r, "right_eye")
        mapped = [servo.get(XAddr.INDIRECT_ADDRESS_1 + 2 * i, 2) for i in range(len(READ_BLOCK_ADDRESSES))]
        assert mapped == list(READ_BLOCK_ADDRESSES)
        assert XAddr.HARDWARE_ERROR_STATUS in mapped  # the Alert cause, in the same transaction


def test_a_power_cycled_servo_is_configured_again_and_re_torqued(rig, caplog):
    r = rig()
    with r.bus as bus:
        bus.enable()
        bus.write_goals({"tilt": 10.0})
        r.advance(2.0)
        r.emulator.power_cycle(IDS["tilt"])  # RAM defaults: indirect map gone, torque off
        r.advance(0.5)  # it boots
        with caplog.at_level(logging.WARNING):
            state = bus.read_state()
        assert "indirect mapping lost" in caplog.text and "lost power and came back" in caplog.text
        assert state["tilt"].torque_on
        assert state["tilt"].position == pytest.approx(10.0, abs=0.1)


def test_a_brown_out_is_healed_settings_written_again_goals_at_present_torque_restored(rig, caplog):
    r = rig()
    with r.bus as bus:
        bus.enable()
        bus.write_goals({"tilt": 10.0, "pan": -5.0})
        r.advance(2.0)
        bus.read_state()
        r.emulator.brown_out(1.0)  # every servo: silent for 1 s, then RAM defaults
        r.advance(0.3)
        with pytest.raises(ServoTimeoutError, match="no servo answered"):
            bus.read_state()
        r.advance(1.0)
        with caplog.at_level(logging.WARNING):
            state = bus.read_state()
        assert "lost power and came back" in caplog.text and "torque restored" in caplog.text
        assert bus.power_losses == 1
        r.emulator.wait_idle()
        for joint in JOINTS:
            servo = _servo(r, joint)
            assert state[joint].torque_on and servo.torque_on
            # The config's RAM settings again, and the goal where the servo is: no jump.
            assert servo.get(XAddr.PROFILE_VELOCITY, 4) == round(100 / DPS_PER_VELOCITY_UNIT)
            assert servo.get(XAddr.PROFILE_ACCELERATION, 4) > 0
            assert servo.get(XAddr.GOAL_POSITION, 4, signed=True) == servo.get(XAddr.PRESENT_POSITION, 4, signed=True)
        assert state["tilt"].position == pytest.approx(10.0, abs=0.1)
        assert state["pan"].position == pytest.approx(-5.0, abs=0.1)
        bus.write_goals({"tilt": 0.0})
        r.advance(2.0)
        assert bus.read_state()["tilt"].position == pytest.approx(0.0, abs=0.1)
        assert bus.power_losses == 1


def test_a_brown_out_with_an_input_voltage_error_is_healed(rig):
    r = rig()
    with r.bus as bus:
        bus.enable()
        bus.read_state()
        r.emulator.brown_out(0.5, bits=0x01)
        r.advance(0.6)
        bus.read_state()
        r.advance(1.5)
        state = bus.read_state()
        assert not state.faults and all(state[joint].torque_on for joint in JOINTS)
        assert bus.power_losses == 1


def test_reconnecting_uses_a_new_port_handler(rig):
    r = rig()
    with r.bus as bus:
        first = bus._port
        r.emulator.vanish()
        with pytest.raises(ServoCommError):
            bus.read_state()
        r.emulator.reappear()
        r.advance(10.0)
        bus.read_state()
        assert bus._port is not first and bus._port.ser is not None


def test_close_when_the_adapter_is_gone_does_not_hang_or_raise(rig):
    r = rig()
    bus = r.bus
    bus.open()
    bus.enable()
    r.emulator.vanish()
    bus.close()
    assert not bus.is_open


# --- scan -------------------------------------------------------------------------------
def test_scan_finds_every_servo_at_its_baud_only(tmp_path):
    with DxlEmulator([1, 2, 7], baud=1_000_000, link=str(tmp_path / "bus")) as emulator:
        found = scan(emulator.port, [57600, 1_000_000])
    assert [(s.servo_id, s.model_number, s.model_name, s.firmware, s.baud) for s in found] == [
        (1, 1020, "XM430-W350", 48, 1_000_000),
        (2, 1020, "XM430-W350", 48, 1_000_000),
        (7, 1020, "XM430-W350", 48, 1_000_000),
    ]


def _run_cli(argv):
    parser = argparse.ArgumentParser(prog="headctl")
    cmd_servos.register(parser.add_subparsers(dest="command", required=True))
    args = parser.parse_args(argv)
    return args.func(args)


def test_scan_command_prints_a_table(tmp_path, capsys):
    with DxlEmulator([3, 4], model="XL430-W250", baud=57600, link=str(tmp_path / "bus")) as emulator:
        assert _run_cli(["scan", "--port", emulator.port, "--baud", "57600"]) == 0
    out = capsys.readouterr().out.splitlines()
    assert out[0].split() == ["id", "model", "number", "firmware", "baud"]
    assert out[1].split() == ["3", "XL430-W250", "1060", "48", "57600"]
    assert out[2].split()[0] == "4"


def test_scan_command_names_the_fix_for_a_missing_port(tmp_path, capsys):
    assert _run_cli(["scan", "--port", str(tmp_path / "nothing"), "--baud", "1000000"]) == 2
    err = capsys.readouterr().err
    assert "does not exist" in err and "99-headctl-servos.rules" in err


def test_the_hint_for_a_port_without_permission_names_dialout_and_udev(tmp_path):
    port = tmp_path / "ttyUSB0"
    port.touch()
    hint = port_access_hint(str(port), PermissionError(errno.EACCES, "Permission denied"))
    assert "dialout" in hint and "usermod -aG dialout" in hint and "99-headctl-servos.rules" in hint


def test_scan_with_protocol_1_finds_nothing_on_a_protocol_2_bus(tmp_path):
    with DxlEmulator([1], link=str(tmp_path / "bus")) as emulator:
        assert scan(emulator.port, [1_000_000], protocol=1.0, ids=range(0, 8)) == []


def test_all_joints_are_configured():
    assert set(config_mapping()["joints"]) == set(JOINTS)


def _goal_packets_to(r, servo_id):
    """Count the packets that set `servo_id`'s Goal Position (a write or a sync write)."""
    sent = []
    handle = r.emulator._handle

    def spy(packet):
        params = packet.params
        if packet.instruction == sdk.INST_WRITE and packet.servo_id == servo_id \
                and int.from_bytes(params[:2], "little") == XAddr.GOAL_POSITION:
            sent.append(packet)
        elif packet.instruction == sdk.INST_SYNC_WRITE \
                and int.from_bytes(params[:2], "little") == XAddr.GOAL_POSITION:
            size = int.from_bytes(params[2:4], "little")
            if servo_id in params[4::size + 1]:
                sent.append(packet)
        handle(packet)

    r.emulator._handle = spy
    return sent


def test_a_servo_missing_at_open_gets_no_goal_and_is_picked_up_with_torque_where_it_is(rig, caplog):
    r = rig(retries=0)
    r.emulator.remove_servo(IDS["left_eye"])  # missing at start
    goals_to_left_eye = _goal_packets_to(r, IDS["left_eye"])
    with r.bus as bus:
        assert list(bus.missing) == ["left_eye"]
        bus.enable()
        state = bus.read_state()
        assert "left_eye" not in state.joints
        assert state.missing["left_eye"].startswith(f"joint left_eye (id 3) on {r.link}: not answering")
        assert bus.write_goals({"pan": 5.0, "left_eye": 5.0}) == {"pan": 5.0}  # never sent to id 3
        r.advance(1.0)
        assert bus.read_state()["pan"].position == pytest.approx(5.0, abs=0.1)  # the others go on
        r.emulator.wait_idle()
        assert goals_to_left_eye == []
        where = r.servo_angle("left_eye")
        r.emulator.add_servo(IDS["left_eye"])  # back, just powered up: torque off, RAM defaults
        r.advance(0.5)  # past its boot and the next ping of the back-off
        with caplog.at_level(logging.WARNING):
            state = bus.read_state()
        assert "joint left_eye (id 3)" in caplog.text and "answers again" in caplog.text
        assert not bus.missing and not state.missing
        assert state["left_eye"].torque_on and r.torque_on("left_eye")
        assert state["left_eye"].position == pytest.approx(where, abs=0.1)
        r.advance(1.0)
        assert r.servo_angle("left_eye") == pytest.approx(where, abs=0.1), "the servo jumped when it came back"
        assert bus.write_goals({"left_eye": 5.0}) == {"left_eye": 5.0}
        r.advance(1.0)
        assert bus.read_state()["left_eye"].position == pytest.approx(5.0, abs=0.1)


def test_a_servo_that_leaves_the_bus_while_running_is_recorded_missing_and_back_once_added(rig, caplog):
    r = rig(retries=1)  # the retry is a plain Sync Read, which blames the silent servo alone
    with r.bus as bus:
        bus.enable()
        bus.write_goals({"left_eye": 5.0})
        r.advance(1.0)
        r.emulator.remove_servo(IDS["left_eye"])  # unplugged while running
        with pytest.raises(ServoTimeoutError, match=r"joint left_eye \(id 3\)") as info:
            bus.read_state()  # one failed read is a failed read
        assert info.value.joints == ("left_eye",)
        r.advance(0.6)
        with caplog.at_level(logging.ERROR):
            state = bus.read_state()  # failing alone for 0.5 s: it has left the bus
        assert "left the bus" in caplog.text and set(state.joints) == {"pan", "tilt", "right_eye"}
        assert list(bus.missing) == ["left_eye"]
        r.emulator.add_servo(IDS["left_eye"])
        r.advance(0.5)
        state = bus.read_state()
        assert state["left_eye"].torque_on and state["left_eye"].position == pytest.approx(5.0, abs=0.1)
