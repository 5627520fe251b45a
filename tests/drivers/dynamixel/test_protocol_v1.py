"""Protocol 1.0: the emulator answering dynamixel-sdk's Protocol 1.0 packet handler (ping,
model, firmware, Bulk Read on MX only), the bus choosing Bulk Read or per-servo reads,
refusing what these servos cannot do, noticing a power cycle, and the error byte's
refusal bits. The shared behaviour is the contract suite (test_servo_bus_contract.py)."""
from __future__ import annotations

import logging
import os
import signal
import subprocess
import sys

import dynamixel_sdk as sdk
import pytest

from drivers.dynamixel.emulator.server import DxlEmulator
from drivers.dynamixel.sdk import BlockingPortHandler, BulkRead1
from drivers.dynamixel.scan import scan
from drivers.backends import check_servo_bus_config, servo_bus_backend
from drivers.dynamixel.factory import create_dynamixel_bus
from drivers.servo.bus import ServoBus
from drivers.errors import ServoConfigError, ServoError, ServoTimeoutError
from drivers.servo.config import ServoBusConfig
from tests.support.servo_rigs import IDS, EmulatorRig, config_mapping


@pytest.fixture
def port_to(tmp_path):
    opened = []

    def factory(emulator: DxlEmulator) -> BlockingPortHandler:
        port = BlockingPortHandler(emulator.port, 8.0, 20.0)
        assert port.openPort()
        opened.append(port)
        return port

    yield factory
    for port in opened:
        port.closePort()


def test_ping_gives_model_and_firmware_in_both_protocols(tmp_path, port_to):
    with DxlEmulator([1, 2], protocol=1.0, models={2: "MX-28"}, firmware={1: 30},
                     link=str(tmp_path / "p1")) as emulator:
        port, packet = port_to(emulator), sdk.PacketHandler(1.0)
        assert packet.ping(port, 1)[:2] == (12, sdk.COMM_SUCCESS)   # AX-12A
        assert packet.ping(port, 2)[:2] == (29, sdk.COMM_SUCCESS)   # MX-28
        assert packet.read1ByteTxRx(port, 1, 2)[:2] == (30, sdk.COMM_SUCCESS)
        assert packet.ping(port, 3)[1] == sdk.COMM_RX_TIMEOUT
        # A Protocol 2.0 ping is not understood by Protocol 1.0 servos.
        assert sdk.PacketHandler(2.0).ping(port, 1)[1] != sdk.COMM_SUCCESS
    with DxlEmulator([5], firmware=44, link=str(tmp_path / "p2")) as emulator:
        replies, result = sdk.PacketHandler(2.0).broadcastPing(port_to(emulator))
        assert result == sdk.COMM_SUCCESS and replies == {5: [1020, 44]}


def test_scan_finds_protocol_1_servos_with_their_names(tmp_path):
    with DxlEmulator([3, 7], protocol=1.0, model="MX-28", link=str(tmp_path / "servos")) as emulator:
        found = scan(emulator.port, [57600, 1_000_000], protocol=1.0, ids=range(10),
                     latency_timer_ms=16.0)  # the FTDI default: room for an emulator on a busy machine
    assert [(r.servo_id, r.model_name, r.baud, r.protocol) for r in found] == [
        (3, "MX-28", 1_000_000, 1.0), (7, "MX-28", 1_000_000, 1.0)]


def test_bulk_read_is_answered_by_mx_servos_only(tmp_path, port_to):
    with DxlEmulator([1, 2, 3], protocol=1.0, models={1: "MX-28", 2: "AX-12A", 3: "MX-64"},
                     link=str(tmp_path / "servos")) as emulator:
        port = port_to(emulator)
        read = BulkRead1(port, sdk.PacketHandler(1.0), [(1, 3, 1), (3, 0, 2)])
        assert read.txRxPacket() == sdk.COMM_SUCCESS
        assert bytes(read.data_dict[1]) == b"\x01" and bytes(read.data_dict[3]) == (310).to_bytes(2, "little")
        # An AX-12A has no Bulk Read: it stays silent, and the MX after it waits for it.
        read = BulkRead1(port, sdk.PacketHandler(1.0), [(2, 3, 1), (3, 3, 1)])
        assert read.txRxPacket() == sdk.COMM_RX_TIMEOUT
        assert read.failures == {2: sdk.COMM_RX_TIMEOUT, 3: sdk.COMM_RX_TIMEOUT}


@pytest.mark.parametrize(("models", "method"), [
    ({}, "bulk read"),
    ({"tilt": "AX-12A"}, "per-servo reads"),
])
def test_the_bus_uses_bulk_read_only_when_every_servo_has_it(tmp_path, models, method):
    emulator = DxlEmulator(IDS.values(), protocol=1.0, model="MX-28",
                           models={IDS[j]: m for j, m in models.items()}, link=str(tmp_path / "servos")).start()
    joints = {j: {"model": models.get(j, "MX-28"), "profile_acceleration": 0} for j in IDS}
    config = ServoBusConfig.from_mapping(config_mapping(port=emulator.link, backend="dynamixel", protocol=1.0,
                                                        joints=joints))
    try:
        with create_dynamixel_bus(config) as bus:
            assert type(bus).__name__ == "Protocol1Bus" and bus.read_method == method
            emulator.wait_idle()
            before = emulator.packets_received
            bus.read_state()
            emulator.wait_idle()
            assert emulator.packets_received - before == (1 if method == "bulk read" else 4)
    finally:
        emulator.stop()


@pytest.mark.parametrize(("bus", "joints", "match"), [
    ({}, {"pan": {"model": "XM430-W350"}}, r"servo_bus\.joints\.pan\.model: got 'XM430-W350'.*Protocol 1\.0"),
    ({"watchdog_ms": 100}, {}, r"servo_bus\.watchdog_ms: got 100, expected 0"),
    ({"baud": 2_000_000}, {}, r"servo_bus\.baud: got 2000000"),
    ({}, {"tilt": {"model": "AX-12A", "profile_acceleration": 300}},
     r"servo_bus\.joints\.tilt\.profile_acceleration: got 300, expected 0.*AX-12A has no acceleration"),
    ({}, {"pan": {"model": "AX-12A", "min_angle": -160}}, r"servo_bus\.joints\.pan\.min_angle: got -160.*AX-12A"),
    ({}, {"pan": {"profile_velocity": 2000}}, r"servo_bus\.joints\.pan\.profile_velocity: got 2000"),
])
def test_the_config_refuses_what_protocol_1_servos_cannot_do(bus, joints, match):
    all_joints = {j: {"model": "MX-28"} for j in IDS}
    for joint, values in joints.items():
        all_joints[joint].update(values)
    config = ServoBusConfig.from_mapping(config_mapping(backend="dynamixel", protocol=1.0, joints=all_joints, **bus))
    with pytest.raises(ServoConfigError, match=match):
        check_servo_bus_config(config, servo_bus_backend(config, ServoBus))


def test_protocol_2_refuses_protocol_1_models():
    config = ServoBusConfig.from_mapping(config_mapping(backend="dynamixel", joints={"pan": {"model": "AX-12A"}}))
    with pytest.raises(ServoConfigError, match=r"joints\.pan\.model: got 'AX-12A'.*protocol: 1\.0"):
        check_servo_bus_config(config, servo_bus_backend(config, ServoBus))


def test_a_power_cycled_servo_is_configured_again(tmp_path, caplog):
    r = EmulatorRig(tmp_path, protocol=1.0, model="MX-28", joints={"pan": {"profile_velocity": 50.0}})
    try:
        with r.bus as bus:
            r.emulator.power_cycle(IDS["pan"])
            r.advance(0.2)  # it boots
            with caplog.at_level(logging.WARNING, logger="drivers.dynamixel.bus_v1"):
                assert not bus.read_state()["pan"].torque_on
            assert "joint pan (id 1)" in caplog.text and "configuring it again" in caplog.text
            bus.enable()
            bus.write_goals({"pan": 20.0})
            r.advance(0.3)
            # Moving Speed is back: 50 deg/s, not the servo's top speed.
            assert bus.read_state()["pan"].velocity == pytest.approx(50.0, rel=0.05)
    finally:
        r.close()


def test_a_brown_out_of_protocol_1_servos_is_healed_with_torque_restored(tmp_path, caplog):
    r = EmulatorRig(tmp_path, protocol=1.0, model="MX-28", joints={"pan": {"profile_velocity": 50.0}})
    try:
        with r.bus as bus:
            bus.enable()
            bus.write_goals({"pan": 20.0})
            r.advance(2.0)
            bus.read_state()
            r.emulator.brown_out(0.5)
            r.advance(0.2)
            with pytest.raises(ServoTimeoutError):
                bus.read_state()
            r.advance(0.5)
            with caplog.at_level(logging.WARNING):
                state = bus.read_state()
            assert "lost power and came back" in caplog.text and bus.power_losses == 1
            assert all(state[joint].torque_on for joint in IDS)
            assert state["pan"].position == pytest.approx(20.0, abs=0.5)  # goal := present: no jump
            bus.write_goals({"pan": 0.0})
            r.advance(0.2)
            assert bus.read_state()["pan"].velocity == pytest.approx(-50.0, rel=0.05)  # Moving Speed again
    finally:
        r.close()


def test_a_refused_instruction_is_an_error_naming_the_joint(tmp_path):
    r = EmulatorRig(tmp_path, protocol=1.0, model="AX-12A")
    try:
        with r.bus as bus:
            # Goal Position beyond the CCW Angle Limit the bus wrote: the Angle Limit bit.
            with pytest.raises(ServoError, match=r"joint pan \(id 1\).*refused.*Angle limit"):
                bus._write("pan", 30, 2, 1023)
    finally:
        r.close()


def test_emulate_servos_speaks_protocol_1_from_the_command_line(tmp_path):
    link = tmp_path / "servos"
    env = dict(os.environ, PYTHONPATH=os.getcwd())
    proc = subprocess.Popen([sys.executable, "-m", "headctl", "emulate-servos", "--protocol", "1.0", "--ids", "1,2",
                             "--model", "MX-28", "--link", str(link)],
                            stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True, env=env)
    try:
        assert proc.stdout is not None and proc.stdout.readline().strip().startswith("/dev/pts/")
        port = sdk.PortHandler(str(link))
        assert port.openPort()
        try:
            assert sdk.PacketHandler(1.0).ping(port, 2)[:2] == (29, sdk.COMM_SUCCESS)
        finally:
            port.closePort()
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(timeout=10) == 0
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
