"""The `dynamixel` servo probe of `headctl setup` against the emulator, both protocols, through
the real SDK: the scan finds each servo with its model, and a move under `MotionSafety` runs
under the settings it asked for and leaves them as they were."""
from __future__ import annotations

import time

import pytest

from drivers.dynamixel.emulator.server import DxlEmulator
from drivers.servo.config import PartialServoBusConfig
from drivers.servo.probe import MotionSafety, create_servo_probe


@pytest.mark.parametrize(("protocol", "model", "number"), [(2.0, "XM430-W350", 1020), (1.0, "AX-12A", 12)])
def test_scan_and_a_safe_move(protocol, model, number):
    with DxlEmulator([3, 6], protocol=protocol, model=model) as emulator:
        config = PartialServoBusConfig.from_mapping({"backend": "dynamixel", "port": emulator.pty_path,
                                                     "latency_timer_ms": 8})
        with create_servo_probe(config, ids=range(8), bauds=[57600, 1_000_000], protocols=[protocol]) as probe:
            found = probe.scan()
            assert [(s.servo_id, s.model_number, s.model_name, s.protocol, s.baud) for s in found] == [
                (3, number, model, protocol, 1_000_000), (6, number, model, protocol, 1_000_000)]
            start = probe.status(6)
            probe.set_torque(6, True)
            probe.limit_motion(6, MotionSafety(velocity_dps=60.0, torque_fraction=0.3))
            assert probe.status(6).torque_on  # limits are set in RAM: torque never goes off
            if protocol == 2.0:  # Goal PWM (100) caps the motor at 30 % of its PWM Limit (885)
                assert int.from_bytes(emulator.servos[6].table[100:102], "little") == round(0.3 * 885)
            probe.write_goal(6, start.position_deg + 6.0)
            deadline = time.monotonic() + 3.0
            while probe.status(6).moving or abs(probe.status(6).position_deg - start.position_deg - 6.0) > 0.5:
                assert time.monotonic() < deadline, probe.status(6)
                time.sleep(0.02)
            probe.keep_alive(6)
            probe.restore_motion(6)
            if protocol == 2.0:
                assert int.from_bytes(emulator.servos[6].table[100:102], "little") == 885
            probe.set_torque(6, False)
            assert not probe.status(6).torque_on
            assert probe.status(3).position_deg == start.position_deg  # the other one never moved
