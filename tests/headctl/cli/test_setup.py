"""`headctl setup` as a person runs it: a subprocess on the simulated head end to end, and
Ctrl-C (SIGINT) in the middle of probing emulated servos, read back through the real SDK."""
from __future__ import annotations

import os
import signal
import subprocess
import sys

import yaml
from dynamixel_sdk import PacketHandler, PortHandler

from drivers.dynamixel.tables.x_series import XAddr
from drivers.dynamixel.emulator.server import DxlEmulator
from headctl.config.head import load_config
from tests.conftest import wait_until

EYE = {"backend": "sim", "width": 160, "height": 120, "fps": 30, "lens": "foveated", "seed": 0, "noise_std": 2.0}
CAMERAS = {"left": {**EYE, "eye": "left"}, "right": {**EYE, "eye": "right"}}


def headctl(*args: str, **kwargs) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "headctl", "--log-level", "WARNING", *args],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, **kwargs)


def test_setup_writes_a_config_that_check_accepts(tmp_path):
    wiring = {9: {"joint": "right_eye", "direction": -1, "zero_offset": 14.0},
              4: {"joint": "pan", "direction": 1, "zero_offset": -11.0},
              21: {"joint": "left_eye", "direction": -1, "zero_offset": -6.5},
              2: {"joint": "tilt", "direction": -1, "zero_offset": 19.0}}
    partial = {"servo_bus": {"backend": "sim", "port": "sim:cli", "wiring": wiring}, "cameras": CAMERAS,
               "fixation": {"vergence_range": [1, 20]}, "state_dir": str(tmp_path / "state"),
               "api": {"port": 0}}
    (tmp_path / "partial.yaml").write_text(yaml.safe_dump(partial))
    proc = headctl("setup", "--config", str(tmp_path / "partial.yaml"), "--write", str(tmp_path / "head.yaml"),
                   "--yes", "--jog", "pan", "-33")
    out, err = proc.communicate(timeout=60)
    assert proc.returncode == 0, out + err
    assert "check: OK" in out
    config = load_config(tmp_path / "head.yaml")
    for servo_id, wired in wiring.items():
        jc = config.servo_bus.joints[wired["joint"]]
        assert (jc.servo_id, jc.direction) == (servo_id, wired["direction"])
    assert config.servo_bus.joints["pan"].min_angle < -32  # widened by the jog
    assert "# " in (tmp_path / "head.yaml").read_text().split("joints:")[1]  # a comment per value


def _read(port: PortHandler, packet: PacketHandler, servo_id: int, address: int, size: int) -> int:
    data, result, _error = packet.readTxRx(port, servo_id, address, size)
    assert result == 0, packet.getTxRxResult(result)
    return int.from_bytes(bytes(data), "little", signed=size == 4)


def test_ctrl_c_leaves_every_servo_holding_where_it_is_torque_as_it_was(tmp_path):
    with DxlEmulator([1, 2, 3]) as emulator:
        emulator.servo(2).write(XAddr.TORQUE_ENABLE, bytes([1]))  # one servo holding before setup starts
        settings_before = {i: emulator.servo(i).get(XAddr.PROFILE_VELOCITY, 4) for i in (1, 2, 3)}
        partial = {"servo_bus": {"backend": "dynamixel", "port": emulator.pty_path, "latency_timer_ms": 8},
                   "cameras": CAMERAS}
        (tmp_path / "partial.yaml").write_text(yaml.safe_dump(partial))
        # Slow moves, so that the interrupt lands in the middle of one.
        proc = headctl("setup", "--config", str(tmp_path / "partial.yaml"), "--yes", "--baud", "1000000",
                       "--protocol", "2.0", "--step", "20", env={**os.environ, "PYTHONUNBUFFERED": "1"})
        assert proc.stdout is not None
        lines = []
        for line in proc.stdout:
            lines.append(line)
            if "id 2: moving" in line:
                break
        else:
            proc.kill()
            raise AssertionError("".join(lines) + proc.stderr.read())
        # Mid-move: servo 2 has left its start (a 20 deg move at 30 deg/s takes 0.7 s each way).
        # Its goal is written after the line is printed, later still on a loaded machine.
        servo_2 = emulator.servo(2)
        wait_until(lambda: abs(servo_2.get(XAddr.PRESENT_POSITION, 4, signed=True) - 2048) * 360 / 4096 >= 1.0,
                   timeout_s=10.0, what="servo 2 to start its move")
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=20)
        assert proc.returncode == 130, "".join(lines) + out + err
        assert "left holding" in out
        port, packet = PortHandler(emulator.pty_path), PacketHandler(2.0)
        assert port.openPort()
        try:
            # Held where it was: it comes to rest (decelerating) and stays there.
            wait_until(lambda: _read(port, packet, 2, XAddr.MOVING, 1) == 0, timeout_s=5.0, what="servo 2 at rest")
            for servo_id, torque in ((1, 0), (2, 1), (3, 0)):
                present = _read(port, packet, servo_id, XAddr.PRESENT_POSITION, 4)
                goal = _read(port, packet, servo_id, XAddr.GOAL_POSITION, 4)
                assert _read(port, packet, servo_id, XAddr.TORQUE_ENABLE, 1) == torque, servo_id
                assert _read(port, packet, servo_id, XAddr.MOVING, 1) == 0, servo_id
                assert _read(port, packet, servo_id, XAddr.BUS_WATCHDOG, 1) == 0, servo_id
                assert _read(port, packet, servo_id, XAddr.PROFILE_VELOCITY, 4) == settings_before[servo_id]
                if torque:
                    assert abs(goal - present) <= 1, (servo_id, goal, present)
            # Servo 2 was stopped on its way out: neither back at the start nor at the goal.
            moved = _read(port, packet, 2, XAddr.PRESENT_POSITION, 4) - 2048
            assert 0 < abs(moved) * 360 / 4096 < 20
        finally:
            port.closePort()
