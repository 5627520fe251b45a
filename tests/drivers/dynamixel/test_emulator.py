"""The Protocol 2.0 emulator on its own: the wire format, and a plain dynamixel_sdk client
talking to it the way it talks to real servos."""
from __future__ import annotations

import os
import select
import signal
import subprocess
import sys
import termios
import threading

import pytest

try:
    import dynamixel_sdk as sdk
except ImportError as err:  # no silent skips: name the install step
    raise ImportError(f"{err}: run ./setup.sh (installs dynamixel-sdk into .venv)") from err

from drivers.clock import ManualClock
from drivers.dynamixel.tables.x_series import DEG_PER_TICK, DPS_PER_VELOCITY_UNIT, XAddr
from drivers.dynamixel.emulator.server import DxlEmulator
from drivers.dynamixel.protocol.v2 import (
    ERR_ACCESS,
    ERR_CRC,
    ERR_DATA_LIMIT,
    PacketParser,
    build_packet,
    crc16,
    status_packet,
    stuff,
    unstuff,
)


# --- wire format ------------------------------------------------------------------------
def test_crc_matches_the_manual_ping_example():
    assert crc16(bytes.fromhex("FFFFFD0001030001")) == 0x4E19
    assert build_packet(1, 0x01) == bytes.fromhex("FFFFFD0001030001194E")


def test_crc_matches_the_sdk_table():
    data = bytes(range(256)) * 3
    assert crc16(data) == sdk.PacketHandler(2.0).updateCRC(0, list(data), len(data))


def test_byte_stuffing_round_trip_and_length():
    body = bytes([0x03, 0x74, 0x00, 0xFF, 0xFF, 0xFD, 0x01])
    stuffed = stuff(body)
    assert stuffed == bytes([0x03, 0x74, 0x00, 0xFF, 0xFF, 0xFD, 0xFD, 0x01])
    assert unstuff(stuffed) == body
    packet = build_packet(5, 0x03, body[1:])
    assert packet[5] == len(stuffed) + 2  # LEN counts the stuffed bytes and the CRC
    [parsed] = list(PacketParser().feed(b"\x00\xff garbage" + packet))
    assert (parsed.servo_id, parsed.instruction, parsed.params, parsed.crc_ok) == (5, 0x03, body[1:], True)


def test_parser_flags_a_bad_crc_and_handles_split_input():
    packet = bytearray(status_packet(2, 0x80, b"\x01\x02"))
    parser = PacketParser()
    assert list(parser.feed(bytes(packet[:5]))) == []
    [ok] = list(parser.feed(bytes(packet[5:])))
    assert ok.crc_ok and ok.params == b"\x80\x01\x02"
    packet[-1] ^= 0xFF
    [bad] = list(parser.feed(bytes(packet)))
    assert not bad.crc_ok


# --- a plain SDK client -----------------------------------------------------------------
def _timed_out(reply) -> bool:
    return sdk.COMM_RX_TIMEOUT in (reply if isinstance(reply, tuple) else (reply,))


def retried(port, call, *args):
    """Run one SDK transaction, again after a reply timeout (5 tries), as a robust client does.

    The stock PortHandler spins while it waits, in this same process as the emulator
    thread; on an overloaded machine that can outlast the SDK's fixed ~34 ms timeout. The
    late reply is drained before trying again, else the SDK (which matches replies by id
    only) would take it as the answer. A reply that is wrong, not late, still fails.
    """
    for _ in range(5):
        reply = call(*args)
        if not _timed_out(reply):
            break
        while select.select([port.ser.fileno()], [], [], 0.1)[0] and port.ser.read(4096):
            pass
    return reply


class PatientPacketHandler:
    """The SDK's PacketHandler with every transaction `retried`; `.once` is the plain one."""

    def __init__(self, packet_handler, port) -> None:
        self.once = packet_handler
        self.port = port

    def __getattr__(self, name):
        attr = getattr(self.once, name)
        return (lambda *args: retried(self.port, attr, *args)) if callable(attr) else attr


@pytest.fixture
def bus(tmp_path):
    """(emulator on a ManualClock, sdk PortHandler, sdk PacketHandler)."""
    clock = ManualClock(0.0)
    emulator = DxlEmulator([1, 2, 3, 4], clock=clock, link=str(tmp_path / "servos")).start()
    port = sdk.PortHandler(emulator.port)
    assert port.openPort() and port.setBaudRate(1_000_000)
    try:
        yield emulator, port, PatientPacketHandler(sdk.PacketHandler(2.0), port)
    finally:
        try:
            port.closePort()
        except (OSError, termios.error):
            pass  # the port vanished in that test
        emulator.stop()


def test_ping_returns_the_model_number(bus):
    _emulator, port, ph = bus
    assert ph.ping(port, 3) == (1020, sdk.COMM_SUCCESS, 0)
    assert ph.once.ping(port, 9)[1] == sdk.COMM_RX_TIMEOUT


def test_broadcast_ping_is_answered_by_every_servo(bus):
    _emulator, port, ph = bus
    found, result = ph.broadcastPing(port)
    assert result == sdk.COMM_SUCCESS
    assert found == {i: [1020, 48] for i in (1, 2, 3, 4)}


def test_sync_read_of_present_position(bus):
    _emulator, port, ph = bus
    group = sdk.GroupSyncRead(port, ph, XAddr.PRESENT_POSITION, 4)
    for servo_id in (1, 2, 3, 4):
        assert group.addParam(servo_id)
    assert retried(port, group.txRxPacket) == sdk.COMM_SUCCESS
    assert [group.getData(i, XAddr.PRESENT_POSITION, 4) for i in (1, 2, 3, 4)] == [2048] * 4


def test_sync_write_then_motion_follows_the_profile(bus):
    emulator, port, ph = bus
    clock = emulator.clock
    ph.write4ByteTxRx(port, 1, XAddr.PROFILE_VELOCITY, 73)   # ~100 deg/s
    ph.write4ByteTxRx(port, 1, XAddr.PROFILE_ACCELERATION, 0)  # unlimited: constant speed
    ph.write1ByteTxRx(port, 1, XAddr.TORQUE_ENABLE, 1)
    writer = sdk.GroupSyncWrite(port, ph, XAddr.GOAL_POSITION, 4)
    writer.addParam(1, list((2048 + 1024).to_bytes(4, "little")))  # +90 deg
    assert writer.txPacket() == sdk.COMM_SUCCESS
    emulator.wait_idle()
    clock.advance(0.5)
    moving, _, _ = ph.read1ByteTxRx(port, 1, XAddr.MOVING)
    position, _, _ = ph.read4ByteTxRx(port, 1, XAddr.PRESENT_POSITION)
    speed_dps = 73 * DPS_PER_VELOCITY_UNIT
    assert moving == 1
    assert (position - 2048) * DEG_PER_TICK == pytest.approx(0.5 * speed_dps, abs=0.5)
    clock.advance(1.0)
    assert ph.read4ByteTxRx(port, 1, XAddr.PRESENT_POSITION)[0] == 2048 + 1024
    assert ph.read1ByteTxRx(port, 1, XAddr.MOVING)[0] == 0


def test_bulk_read_of_different_items(bus):
    _emulator, port, ph = bus
    group = sdk.GroupBulkRead(port, ph)
    group.addParam(1, XAddr.PRESENT_POSITION, 4)
    group.addParam(2, XAddr.MODEL_NUMBER, 2)
    assert retried(port, group.txRxPacket) == sdk.COMM_SUCCESS
    assert group.getData(1, XAddr.PRESENT_POSITION, 4) == 2048
    assert group.getData(2, XAddr.MODEL_NUMBER, 2) == 1020


def test_stuffed_data_survives_a_write_and_read_back(bus):
    _emulator, port, ph = bus
    value = 0x00FDFFFF  # FF FF FD on the wire: needs stuffing both ways
    assert ph.write4ByteTxRx(port, 2, XAddr.PROFILE_VELOCITY, value) == (sdk.COMM_SUCCESS, 0)
    assert ph.read4ByteTxRx(port, 2, XAddr.PROFILE_VELOCITY) == (value, sdk.COMM_SUCCESS, 0)


def test_eeprom_needs_torque_off_and_goals_respect_position_limits(bus):
    _emulator, port, ph = bus
    assert ph.write1ByteTxRx(port, 1, XAddr.RETURN_DELAY_TIME, 0) == (sdk.COMM_SUCCESS, 0)
    ph.write1ByteTxRx(port, 1, XAddr.TORQUE_ENABLE, 1)
    assert ph.write1ByteTxRx(port, 1, XAddr.RETURN_DELAY_TIME, 10) == (sdk.COMM_SUCCESS, ERR_ACCESS)
    assert ph.write1ByteTxRx(port, 1, XAddr.PRESENT_TEMPERATURE, 10)[1] == ERR_ACCESS  # read-only
    ph.write1ByteTxRx(port, 1, XAddr.TORQUE_ENABLE, 0)
    ph.write4ByteTxRx(port, 1, XAddr.MAX_POSITION_LIMIT, 3000)
    assert ph.write4ByteTxRx(port, 1, XAddr.GOAL_POSITION, 3500)[1] == ERR_DATA_LIMIT


def test_torque_on_with_a_stale_goal_jumps(bus):
    """The pitfall the driver guards against, reproduced by the emulator."""
    emulator, port, ph = bus
    ph.write4ByteTxRx(port, 1, XAddr.GOAL_POSITION, 3000)
    emulator.clock.advance(5.0)
    assert ph.read4ByteTxRx(port, 1, XAddr.PRESENT_POSITION)[0] == 2048  # torque off: no motion
    ph.write1ByteTxRx(port, 1, XAddr.TORQUE_ENABLE, 1)
    emulator.clock.advance(5.0)
    assert ph.read4ByteTxRx(port, 1, XAddr.PRESENT_POSITION)[0] == 3000


def test_hardware_error_sets_the_alert_bit_until_reboot(bus):
    emulator, port, ph = bus
    ph.write1ByteTxRx(port, 4, XAddr.TORQUE_ENABLE, 1)
    emulator.set_hardware_error(4, 0x24)  # overheating + overload: shutdown
    model, result, error = ph.ping(port, 4)
    assert error & 0x80
    assert ph.read1ByteTxRx(port, 4, XAddr.HARDWARE_ERROR_STATUS)[0] == 0x24
    assert ph.read1ByteTxRx(port, 4, XAddr.TORQUE_ENABLE)[0] == 0
    # GroupSyncRead hides it: the SDK drops the status error byte.
    group = sdk.GroupSyncRead(port, ph, XAddr.PRESENT_POSITION, 4)
    group.addParam(4)
    assert retried(port, group.txRxPacket) == sdk.COMM_SUCCESS
    assert ph.reboot(port, 4) == (sdk.COMM_SUCCESS, 0x80)
    emulator.clock.advance(0.5)  # boot
    assert ph.ping(port, 4) == (1020, sdk.COMM_SUCCESS, 0)
    assert ph.read1ByteTxRx(port, 4, XAddr.HARDWARE_ERROR_STATUS)[0] == 0


def test_indirect_addressing_gathers_scattered_items(bus):
    _emulator, port, ph = bus
    ph.write2ByteTxRx(port, 1, XAddr.INDIRECT_ADDRESS_1, XAddr.ID)
    ph.write2ByteTxRx(port, 1, XAddr.INDIRECT_ADDRESS_1 + 2, XAddr.PRESENT_TEMPERATURE)
    data, result, _ = ph.readTxRx(port, 1, XAddr.INDIRECT_DATA_1, 2)
    assert result == sdk.COMM_SUCCESS and list(data) == [1, 35]


def test_injected_faults_reach_the_client(bus):
    emulator, port, ph = bus
    emulator.drop_replies(1)
    assert ph.once.ping(port, 1)[1] == sdk.COMM_RX_TIMEOUT
    emulator.corrupt_replies(1)
    assert ph.once.ping(port, 1)[1] == sdk.COMM_RX_CORRUPT
    assert ph.ping(port, 1)[1] == sdk.COMM_SUCCESS


def test_a_corrupted_instruction_gets_a_crc_error_status(bus):
    emulator, port, _ph = bus
    packet = bytearray(build_packet(2, 0x01))
    packet[-1] ^= 0x55
    with open(emulator.pty_path, "r+b", buffering=0) as raw:
        os.write(raw.fileno(), bytes(packet))
        emulator.wait_idle()
    # The status came back on the client's port (both share the pty).
    reply = port.ser.read(64)
    [status] = list(PacketParser().feed(reply))
    assert status.params[0] == ERR_CRC


def test_other_baud_rates_are_not_understood(bus):
    _emulator, port, ph = bus
    port.setBaudRate(57600)
    assert ph.once.ping(port, 1)[1] == sdk.COMM_RX_TIMEOUT
    port.setBaudRate(1_000_000)
    assert ph.ping(port, 1)[1] == sdk.COMM_SUCCESS


def test_the_port_vanishes_and_comes_back(bus, tmp_path):
    emulator, port, ph = bus
    link = str(tmp_path / "servos")
    emulator.vanish()
    assert not os.path.lexists(link)
    with pytest.raises((OSError, termios.error)):  # termios.error is not an OSError
        ph.ping(port, 1)
    assert port.is_using  # the SDK pitfall: the handler is stuck from now on
    emulator.reappear()
    assert os.path.islink(link)
    fresh = sdk.PortHandler(link)
    assert fresh.openPort()
    try:
        assert ph.ping(fresh, 1)[0] == 1020
    finally:
        fresh.closePort()


# --- lifecycle --------------------------------------------------------------------------
def test_thread_is_named_and_stop_is_idempotent(tmp_path):
    emulator = DxlEmulator([1], link=str(tmp_path / "x"))
    with emulator:
        names = [t.name for t in threading.enumerate()]
        assert f"dxl-emulator({tmp_path / 'x'})" in names
    emulator.stop()
    assert not any(t.name.startswith(f"dxl-emulator({tmp_path}") for t in threading.enumerate())
    assert not os.path.lexists(tmp_path / "x")


def test_emulate_servos_command_prints_the_pty_and_stops_on_sigterm(tmp_path):
    link = tmp_path / "head-servos"
    script = (
        "import argparse, sys\n"
        "from headctl.cli import servos as cmd_servos\n"
        "p = argparse.ArgumentParser(); cmd_servos.register(p.add_subparsers(required=True))\n"
        "a = p.parse_args(sys.argv[1:]); sys.exit(a.func(a))\n"
    )
    proc = subprocess.Popen(
        [sys.executable, "-c", script, "emulate-servos", "--ids", "1,2", "--link", str(link)],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )
    try:
        pty_path = proc.stdout.readline().strip()
        assert pty_path.startswith("/dev/pts/")
        assert os.path.realpath(link) == pty_path
        port = sdk.PortHandler(str(link))
        assert port.openPort()
        assert sdk.PacketHandler(2.0).ping(port, 2)[0] == 1020
        port.closePort()
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(timeout=10) == 0
        assert not os.path.lexists(link)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


def test_a_handler_error_reaches_the_callback_and_serving_goes_on(tmp_path):
    errors = []
    with DxlEmulator([1], link=str(tmp_path / "x"), on_error=errors.append) as emulator:
        original = emulator._dispatch
        emulator._dispatch = lambda packet, now: (_ for _ in ()).throw(RuntimeError("boom"))
        port = sdk.PortHandler(emulator.port)
        assert port.openPort()
        try:
            packet = sdk.PacketHandler(2.0)
            assert packet.ping(port, 1)[1] == sdk.COMM_RX_TIMEOUT
            emulator.wait_idle()
            assert [str(e) for e in errors] == ["boom"] and emulator.last_error is errors[0]
            emulator._dispatch = original
            assert retried(port, packet.ping, port, 1)[0] == 1020
        finally:
            port.closePort()
