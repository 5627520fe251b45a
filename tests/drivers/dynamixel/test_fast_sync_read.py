"""Fast Sync Read (0x8A): the emulator's answer byte for byte, the bus using it where the
servos' firmware has it, and falling back to Sync Read where it does not or where it fails.
The bus side goes through the real dynamixel-sdk `PortHandler` against the emulator."""
from __future__ import annotations

import logging
import struct

import dynamixel_sdk as sdk
import pytest

import drivers.dynamixel.emulator.server as dxl_emulator
from drivers.dynamixel.tables.x_series import XAddr
from drivers.dynamixel.emulator.server import DxlEmulator
from drivers.dynamixel.sdk import BlockingPortHandler, FastSyncRead
from tests.support.servo_rigs import IDS

IDS_IN_TURN = list(IDS.values())


def _sdk_crc(data: bytes) -> int:
    """The CRC by dynamixel-sdk's own implementation, independent of drivers.dynamixel.protocol.v2."""
    return int(sdk.Protocol2PacketHandler().updateCRC(0, list(data), len(data)))


def test_the_emulator_answers_fast_sync_read_with_one_packet_of_chained_blocks(tmp_path):
    with DxlEmulator([1, 2, 3], link=str(tmp_path / "servos")) as emulator:
        port = BlockingPortHandler(emulator.port, 8.0, 20.0)
        assert port.openPort()
        try:
            # FF FF FD 00, broadcast, length 10, 0x8A, address 132 (Present Position), 4 bytes, ids 1 2 3.
            body = bytes([0xFF, 0xFF, 0xFD, 0x00, 0xFE, 10, 0, 0x8A, 132, 0, 4, 0, 1, 2, 3])
            port.writePort(body + struct.pack("<H", _sdk_crc(body)))
            expected_size = 8 + 3 * (4 + 4)
            port.setPacketTimeout(expected_size)
            reply = b""
            while len(reply) < expected_size and not port.isPacketTimeout():
                reply += port.readPort(expected_size - len(reply))
        finally:
            port.closePort()
    assert reply[:8] == bytes([0xFF, 0xFF, 0xFD, 0x00, 0xFE, 1 + 3 * 8, 0, 0x55])
    for k, servo_id in enumerate([1, 2, 3]):
        end = 8 + (k + 1) * 8
        block = reply[end - 8: end]
        assert block[0] == 0 and block[1] == servo_id
        assert struct.unpack_from("<i", block, 2)[0] == 2048  # each servo rests at its centre
        # Each block ends with the CRC of the whole packet so far; the last one ends the packet.
        assert struct.unpack_from("<H", block, 6)[0] == _sdk_crc(reply[:end - 2])
    assert len(reply) == expected_size


def test_old_firmware_does_not_answer_fast_sync_read_and_cuts_the_packet_there(tmp_path):
    with DxlEmulator([1, 2, 3], firmware={2: 44}, link=str(tmp_path / "servos")) as emulator:
        port = BlockingPortHandler(emulator.port, 8.0, 20.0)
        assert port.openPort()
        try:
            read = FastSyncRead(port, XAddr.ID, 1, [1, 2, 3])
            assert read.txRxPacket() != sdk.COMM_SUCCESS
        finally:
            port.closePort()
    # The servo before the old one answered; the old one did not, and the one after it waits for it.
    assert read.answered == {1} and bytes(read.data_dict[1]) == b"\x01"
    assert read.failures == {2: sdk.COMM_RX_TIMEOUT, 3: sdk.COMM_RX_TIMEOUT}


def test_the_bus_reads_by_fast_sync_read(rig):
    r = rig()
    with r.bus as bus:
        assert bus.read_method == "fast sync read"
        bus.enable()
        bus.write_goals({"pan": 8.0})
        r.advance(1.0)
        r.emulator.wait_idle()
        before = dict(r.emulator.instructions_received)
        for _ in range(5):
            state = bus.read_state()
        r.emulator.wait_idle()
        after = r.emulator.instructions_received
        assert (after[0x8A] - before.get(0x8A, 0), after[0x82] - before.get(0x82, 0)) == (5, 0)
        assert state["pan"].position == pytest.approx(8.0, abs=r.tick_deg)


def test_a_servo_with_old_firmware_makes_the_bus_use_sync_read(rig, caplog):
    with caplog.at_level(logging.INFO, logger="drivers.dynamixel.bus_v2"):
        r = rig(firmware={IDS["tilt"]: 44})
        with r.bus as bus:
            assert bus.read_method == "sync read"
            r.emulator.wait_idle()
            before = dict(r.emulator.instructions_received)
            bus.read_state()
            r.emulator.wait_idle()
            after = r.emulator.instructions_received
            assert (after[0x8A] - before.get(0x8A, 0), after[0x82] - before.get(0x82, 0)) == (0, 1)
    assert "joint tilt (id 2)" in caplog.text and "has 44" in caplog.text


def test_fast_sync_read_can_be_turned_off(rig):
    r = rig(fast_sync_read=False)
    with r.bus as bus:
        assert bus.read_method == "sync read"


def test_a_failed_probe_falls_back_to_sync_read(rig, monkeypatch, caplog):
    # Firmware that claims Fast Sync Read but never answers it.
    monkeypatch.setattr(dxl_emulator, "fast_sync_read", lambda *args: (b"", 0.0))
    with caplog.at_level(logging.WARNING, logger="drivers.dynamixel.bus_v2"):
        r = rig()
        with r.bus as bus:
            assert bus.read_method == "sync read"
            assert set(bus.read_state().joints) == set(IDS)
    assert "probe failed" in caplog.text


def test_a_failed_fast_sync_read_is_retried_as_a_sync_read(rig):
    r = rig(retries=1)
    with r.bus as bus:
        assert bus.read_method == "fast sync read"
        r.emulator.drop_replies(IDS["tilt"], count=1)
        state = bus.read_state()  # the fast read loses tilt and those after it; the Sync Read retry gets all
        assert set(state.joints) == set(IDS) and state["tilt"].position == pytest.approx(0.0, abs=r.tick_deg)
        assert r.emulator.injected()["servos"][IDS["tilt"]]["drop"] == 0
