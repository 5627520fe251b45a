"""End to end: `headctl run` on the simulated head (configs/sim.yaml) in a subprocess.

Each test drives the daemon through its HTTP API (polling with deadlines, never a bare
sleep): it learns, survives injected faults, stops on SIGTERM within 5 s with the map saved,
continues from that map after a restart, and a kill -9 during a checkpoint leaves a loadable map.
"""
from __future__ import annotations

import signal
import time

import pytest
import yaml

from calib_free.map.file import read_map
from tests.support.daemon_proc import SIM

pytestmark = [pytest.mark.timeout(180), pytest.mark.slow]


def _taught(n):
    return lambda s: s["state"] in ("running", "degraded") and s["fixation"]["taught"] >= n


def test_learns_survives_faults_and_continues_after_sigterm_and_restart(tmp_path, service_process):
    state = tmp_path / "state"
    d = service_process(state)
    s = d.wait(_taught(2), 60, "two taught fixations")
    assert s["state"] == "running" and s["map"]["restored_from"] == "new"
    assert set(s["joints"]) == {"pan", "tilt", "left_eye", "right_eye"}
    assert s["servo_loop"]["rate_hz"] == 100.0 and s["servo_loop"]["cycles"] > 50
    assert s["learning"]["adaptations"] >= 1

    # The servo bus goes down: degraded with the reason, motion paused; back: it resumes.
    d.inject("bus_down")
    s = d.wait(lambda s: s["state"] == "degraded" and any("servo bus down" in f for f in s["faults"]),
               10, "degraded: servo bus down")
    d.wait(lambda s: s["fixation"]["state"] == "paused (servo bus down)", 10, "fixations paused")
    d.inject("restore_bus")
    done = d.wait(lambda s: s["state"] == "running", 15, "running again")["fixation"]["done"]
    d.wait(lambda s: s["fixation"]["done"] >= done + 2, 30, "fixations after the bus came back")

    # A servo hardware error (overload cuts torque): reported, the servo rebooted as configured.
    d.inject("hardware_error", joint="tilt", bits=0x20)
    s = d.wait(lambda s: any("tilt" in e["message"] and "hardware error" in e["message"] for e in s["events"]),
               10, "the hardware error reported")
    s = d.wait(lambda s: s["joints"]["tilt"]["torque_on"] and not s["joints"]["tilt"]["hardware_errors"],
               10, "tilt rebooted, torque back")
    assert any("tilt" in e["message"] and "rebooting" in e["message"] for e in s["events"])
    # An error that leaves torque on (input voltage): the joint held and reported until the
    # daemon's reboot clears it (reboot_on_hardware_error), then free again.
    d.inject("hardware_error", joint="pan", bits=0x01)
    d.wait(lambda s: any("pan" in f and "input voltage out of range (joint held)" in f for f in s["faults"]),
           10, "pan held and reported")
    s = d.wait(lambda s: s["state"] == "running" and not s["joints"]["pan"]["hardware_errors"], 15,
               "pan rebooted, free again")
    assert any("pan" in e["message"] and "hardware error cleared" in e["message"] for e in s["events"])

    # A camera stalls: no fixation completes on stale frames; frames back: it learns again.
    d.inject("camera_stall", camera="left")
    s = d.wait(lambda s: any("camera left: stalled" in f for f in s["faults"]), 10, "camera left stalled")
    taught_at_stall = s["fixation"]["taught"]
    s = d.wait(lambda s: s["fixation"]["refused"].get("no stereo pair in time", 0) >= 1, 15,
               "a fixation refused for want of frames")
    assert s["fixation"]["taught"] <= taught_at_stall + 1  # at most the one that had its frames already
    # Silent for camera_stall_s (5 s): the daemon restarts the camera's stream.
    s = d.wait(lambda s: s["cameras"]["left"]["restarts"] >= 1, 15, "the stalled camera's stream restarted")
    assert any("camera left: no frame for" in e["message"] and "restarting" in e["message"] for e in s["events"])
    assert s["cameras"]["right"]["restarts"] == 0
    d.inject("camera_resume", camera="left")
    d.wait(lambda s: s["state"] == "running" and s["fixation"]["taught"] >= taught_at_stall + 2, 60,
           "learning again after the camera came back")

    before = d.status()["learning"]
    code, seconds = d.terminate()
    assert code == 0 and seconds < 5.0
    saved = read_map(state / "gaze_map.npz")
    assert saved.adaptations >= before["adaptations"]
    assert not (state / "api.url").exists()

    again = service_process(state)
    s = again.wait(lambda s: s["state"] == "running", 30, "restarted")
    assert s["map"]["restored_from"] == str(state / "gaze_map.npz")
    assert s["learning"]["adaptations"] >= saved.adaptations
    restored = s["map"]["restored"]  # the learning figures it started from: those it saved
    assert restored["adaptations"] == saved.adaptations
    assert restored["recent_retinal_errors"] == pytest.approx(list(saved.recent_errors))
    assert restored["recent_retinal_errors"] == pytest.approx(before["recent_retinal_errors"][-len(
        restored["recent_retinal_errors"]):]) or saved.adaptations > before["adaptations"]
    again.wait(_taught(1), 60, "learning goes on after the restart")
    code, seconds = again.terminate()
    assert code == 0 and seconds < 5.0
    assert read_map(state / "gaze_map.npz").adaptations > saved.adaptations


def test_kill_9_during_a_checkpoint_leaves_a_loadable_map(tmp_path, service_process):
    config = yaml.safe_load(SIM.read_text())
    config["service"]["checkpoint_every"] = 1  # a checkpoint after every adaptation
    path = tmp_path / "sim-every.yaml"
    path.write_text(yaml.safe_dump(config))
    state = tmp_path / "state"
    d = service_process(state, path)
    d.wait(lambda s: s["map"]["checkpoints"] >= 1, 60, "a first checkpoint")
    # Kill the moment a checkpoint's temporary file exists (mid-write), watching the directory.
    deadline = time.monotonic() + 60
    while not any(p.name.endswith(".tmp") for p in state.iterdir()):
        assert time.monotonic() < deadline, "no checkpoint in progress seen within 60 s"
        assert d.proc.poll() is None
    d.proc.send_signal(signal.SIGKILL)
    d.proc.wait(5)
    gm = read_map(state / "gaze_map.npz")
    assert gm.adaptations >= 1
    again = service_process(state, path)
    s = again.wait(lambda s: s["state"] == "running", 30, "restarted after kill -9")
    assert s["map"]["restored_from"] == str(state / "gaze_map.npz") and not s["map"]["problems"]
    assert again.terminate()[0] == 0


def test_status_command_prints_the_state_and_fails_without_a_daemon(tmp_path, service_process, capsys):
    from headctl.cli.main import main

    assert main(["status", "--state-dir", str(tmp_path / "none"), "--url", "http://127.0.0.1:9"]) == 1
    assert "cannot reach the daemon" in capsys.readouterr().err
    state = tmp_path / "state"
    d = service_process(state)
    d.wait(lambda s: s["state"] == "running" and s["fixation"]["done"] >= 1, 30, "a fixation")
    assert main(["status", "--state-dir", str(state)]) == 0
    out = capsys.readouterr().out
    assert out.startswith("running") and "servo loop: 100.0 Hz" in out and "fixation:" in out
    assert "camera left: streaming" in out
    assert d.terminate()[0] == 0
