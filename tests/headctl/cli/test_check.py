"""`headctl check` tries every part of a head and prints a line each (`headctl.cli.check`): a
servo adapter that is missing still leaves the cameras tried, a servo that does not answer
is named with its id and port, the adapter's latency timer is judged against the servo
loop's period, and a camera's exposure control is tried and what it cannot do is told."""
from __future__ import annotations

import cv2
import numpy as np
import pytest
import yaml

from headctl.cli import check
from headctl.cli.main import main
from headctl.config.head import load_config
from tests.support import CONFIGS


def write(tmp_path, data, name="head.yaml"):
    data["state_dir"] = str(tmp_path / "state")
    path = tmp_path / name
    path.write_text(yaml.safe_dump(data))
    return path


@pytest.fixture(scope="module")
def video(tmp_path_factory):
    path = tmp_path_factory.mktemp("video") / "eye.avi"
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 30, (160, 120))
    rng = np.random.default_rng(0)
    for _ in range(10):
        writer.write(rng.integers(0, 255, (120, 160, 3), dtype=np.uint8))
    writer.release()
    return str(path)


def webcams(tmp_path, left, right, **left_settings):
    """configs/usb-webcams.yaml on a servo port that does not exist, with these cameras."""
    data = yaml.safe_load((CONFIGS / "usb-webcams.yaml").read_text())
    data["servo_bus"]["port"] = str(tmp_path / "no-such-adapter")
    size = {"width": 160, "height": 120}
    data["cameras"] = {"left": {"backend": "opencv", "device": left, **size, **left_settings},
                       "right": {"backend": "opencv", "device": right, **size}}
    return write(tmp_path, data)


def test_a_missing_adapter_fails_every_servo_and_the_cameras_are_still_tried(tmp_path, video, capsys):
    path = webcams(tmp_path, video, str(tmp_path / "head-right"))
    assert main(["check", "--config", str(path)]) == 1
    out = capsys.readouterr().out
    port = tmp_path / "no-such-adapter"
    assert f"servo bus: FAILED: {port}: port {port} does not exist" in out
    for joint, servo_id in (("pan", 1), ("tilt", 2), ("left_eye", 3), ("right_eye", 4)):
        assert f"joint {joint} (id {servo_id}) on {port}: FAILED: not reached: the bus did not open" in out
    assert "camera left (opencv left): 160 x 120, first frame after" in out
    # A video file has no exposure to hold or set: what that costs is told, a warning.
    assert ("camera left exposure: WARNING: the camera can neither hold nor fix its exposure: where it adjusts "
            "itself, the images before and after a saccade differ in brightness, and fewer fixations teach") in out
    assert f"camera right: FAILED: right: device {tmp_path / 'head-right'} does not exist" in out
    assert out.rstrip().endswith("check: 6 problem(s) (1 warning(s))")


def test_lock_per_fixation_on_a_camera_that_cannot_hold_its_exposure_fails_naming_it(tmp_path, video, capsys):
    path = webcams(tmp_path, video, video, exposure_control="lock_per_fixation")
    assert main(["check", "--config", str(path)]) == 1
    out = capsys.readouterr().out
    assert ("camera left: FAILED: left: exposure_control: lock_per_fixation, but this opencv camera cannot hold "
            "its exposure") in out
    assert "camera right (opencv right): 160 x 120" in out


def test_a_servo_that_does_not_answer_is_named_and_the_others_reported(tmp_path, capsys):
    data = yaml.safe_load((CONFIGS / "sim.yaml").read_text())
    data["servo_bus"]["wiring"] = {i: {"joint": joint, "off_bus": joint == "tilt"} for i, joint in
                                   enumerate(("pan", "tilt", "left_eye", "right_eye"), start=1)}
    assert main(["check", "--config", str(write(tmp_path, data))]) == 1
    out = capsys.readouterr().out
    assert "joint tilt (id 2) on sim-servo-bus(sim:head): FAILED: not answering (" in out
    for joint, servo_id in (("pan", 1), ("left_eye", 3), ("right_eye", 4)):
        assert f"joint {joint} (id {servo_id}) on sim-servo-bus(sim:head): XM430-W350, at " in out
    assert "camera left (sim left): 320 x 240" in out and "camera right (sim right): 320 x 240" in out
    assert out.rstrip().endswith("check: 1 problem(s)")


@pytest.fixture
def adapter(tmp_path, monkeypatch):
    """A port /dev-like ttyUSB0 whose FTDI latency timer a fake sysfs tells."""
    sysfs = tmp_path / "sys"
    timer = sysfs / "bus" / "usb-serial" / "devices" / "ttyUSB0" / "latency_timer"
    timer.parent.mkdir(parents=True)
    port = tmp_path / "dev" / "ttyUSB0"
    port.parent.mkdir()
    port.write_text("")
    monkeypatch.setattr(check, "SYSFS", str(sysfs))
    data = yaml.safe_load((CONFIGS / "usb-webcams.yaml").read_text())
    data["servo_bus"]["port"] = str(port)
    config = load_config(write(tmp_path, data))

    def report(latency_ms: str | None):
        if latency_ms is None:
            timer.unlink(missing_ok=True)
        else:
            timer.write_text(latency_ms + "\n")
        result = check.Report()
        check.report_latency_timer(config, result)
        return result

    return port, report


def test_the_default_16_ms_latency_timer_fails_a_100_hz_servo_loop(adapter, capsys):
    port, report = adapter
    assert report("16").failures == 1
    out = capsys.readouterr().out
    assert (f"adapter latency timer of {port}: FAILED: 16 ms: every servo reply waits up to that long in the "
            "adapter, more than half the 10 ms period of the 100 Hz servo loop") in out
    assert "set it to 1 ms with udev/99-headctl-servos.rules" in out and "sudo udevadm trigger" in out


def test_a_short_latency_timer_passes_and_an_unreadable_one_says_nothing(adapter, capsys):
    port, report = adapter
    assert report("1").failures == 0
    assert capsys.readouterr().out == f"  adapter latency timer of {port}: 1 ms\n"
    assert report("4").failures == 0
    assert "4 ms, within the 100 Hz loop's period; 1 ms shortens every read" in capsys.readouterr().out
    assert report(None).failures == 0 and capsys.readouterr().out == ""
