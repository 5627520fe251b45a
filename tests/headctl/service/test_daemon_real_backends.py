"""The same daemon on the real backends' paths: the Dynamixel backend through dynamixel-sdk
against the servo emulator on a pty (another process, real time), a GenICam camera through
Aravis (its in-process Fake camera) and a V4L2-style OpenCV camera (a video file)."""
from __future__ import annotations

import pathlib
import subprocess
import sys
import time

import cv2
import numpy as np
import pytest
import yaml

from tests.support.daemon_proc import ROOT

pytestmark = [pytest.mark.timeout(120), pytest.mark.slow]


@pytest.fixture
def emulator(tmp_path):
    link = tmp_path / "head-servos"
    proc = subprocess.Popen([sys.executable, "-m", "headctl.cli.main", "emulate-servos", "--ids", "1,2,3,4",
                             "--baud", "1000000", "--link", str(link)], cwd=ROOT,
                            stdout=subprocess.PIPE, stderr=subprocess.DEVNULL)
    assert proc.stdout is not None
    proc.stdout.readline()  # the pty path: the emulator is serving
    deadline = time.monotonic() + 10
    while not link.exists():
        assert time.monotonic() < deadline and proc.poll() is None, "the emulator did not start"
        time.sleep(0.01)
    yield link
    proc.terminate()
    proc.wait(5)


@pytest.fixture
def video(tmp_path):
    path = tmp_path / "right.avi"
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 30, (320, 240))
    assert writer.isOpened()
    rng = np.random.default_rng(1)
    for _ in range(30):
        writer.write(rng.integers(0, 255, (240, 320, 3), dtype=np.uint8))
    writer.release()
    return path


def emulated_config(tmp_path, emulator, video) -> pathlib.Path:
    """configs/xm430-u2d2-aravis.yaml on the emulator's pty, Aravis's Fake camera and a video file."""
    config = yaml.safe_load((ROOT / "configs" / "xm430-u2d2-aravis.yaml").read_text())
    config["servo_bus"].update(port=str(emulator), latency_timer_ms=8, watchdog_ms=0)
    config["cameras"] = {
        "left": {"backend": "aravis", "id": "Fake_1", "width": 320, "height": 240, "fps": 30},
        "right": {"backend": "opencv", "device": str(video), "width": 320, "height": 240, "fps": 30},
        "tolerance_s": 0.02,
    }
    config["fixation"].update(rate_hz=0, settle_timeout_s=2.0, frame_timeout_s=1.0)
    config["service"]["safe_state"] = "torque_off"
    path = tmp_path / "emulated.yaml"
    path.write_text(yaml.safe_dump(config))
    return path


def test_check_connects_and_reports_each_servo_and_camera(tmp_path, emulator, video):
    path = emulated_config(tmp_path, emulator, video)
    out = subprocess.run([sys.executable, "-m", "headctl.cli.main", "check", "--config", str(path)], cwd=ROOT,
                         capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stdout + out.stderr
    for joint, servo_id in (("pan", 1), ("tilt", 2), ("left_eye", 3), ("right_eye", 4)):
        assert f"joint {joint} (id {servo_id}) on {emulator}: XM430-W350, at " in out.stdout
    assert "camera left (aravis left): 320 x 240" in out.stdout
    assert "camera right (opencv right): 320 x 240" in out.stdout
    # Aravis's Fake camera has GainAuto, which can be held; the video file has no exposure at all.
    assert "camera left exposure: auto; the camera can hold it: exposure_control: lock_per_fixation" in out.stdout
    assert "camera right exposure: WARNING: the camera can neither hold nor fix its exposure" in out.stdout
    assert out.stdout.rstrip().endswith("check: OK (1 warning(s))")


def test_daemon_on_the_servo_emulator_and_aravis_fake_camera(tmp_path, emulator, video, service_process):
    path = emulated_config(tmp_path, emulator, video)
    d = service_process(tmp_path / "state", path)
    s = d.wait(lambda s: s["state"] == "running" and s["fixation"]["done"] >= 2, 60, "two fixations")
    assert s["servo_loop"]["cycles"] > 50
    assert s["cameras"]["left"]["health"] == s["cameras"]["right"]["health"] == "streaming"
    # These cameras do not see the head's scene: the fixations run and are refused, never taught.
    assert s["fixation"]["taught"] == 0 and sum(s["fixation"]["refused"].values()) == s["fixation"]["done"]
    positions = [s["joints"]["pan"]["position_deg"]]
    s = d.wait(lambda s: abs(s["joints"]["pan"]["position_deg"] - positions[0]) > 0.5, 30, "the head moving")
    assert all(j["torque_on"] for j in s["joints"].values())
    # Torque through the API, on the real driver: off on every servo, then on again.
    assert d.client.set_torque(False) is False
    d.wait(lambda s: not any(j["torque_on"] for j in s["joints"].values()), 10, "torque off on the servos")
    assert d.client.set_torque(True) is True
    d.wait(lambda s: all(j["torque_on"] for j in s["joints"].values()), 10, "torque on again")
    code, seconds = d.terminate()
    assert code == 0 and seconds < 5.0
