"""Without cyclonedds, `convert` and `frames` build `bagtypes`' messages, whose CDR bytes are
those of `messages` (Cyclone DDS's) for the same data: a recording made on an ARM board
without the `ros2` extra holds what a ROS 2 publisher would send."""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

from tests.headctl.ros2.support import need

need("rosbags")
need("cyclonedds")

ROOT = Path(__file__).resolve().parents[3]

# Every message the recorder writes, from fixed data, as hex CDR: run with and without cyclonedds.
PROGRAM = r"""
import json, sys
import numpy as np
if sys.argv[1] == "without":
    sys.modules["cyclonedds"] = None  # as if not installed: its import fails
from drivers.cameras.camera import Frame
from drivers.servo.state import BusState, JointState
from headctl.config.ros2 import Ros2Config
from headctl.ros2 import convert
from headctl.ros2.frames import HeadFrames
from headctl.ros2.recorder import cdr

m = convert.m
stamp = m.Time.of_seconds(1700000000.25)
state = BusState(time_s=1.0, joints={j: JointState(position=10.0 * i, velocity=-1.5 * i, moving=False,
                                                torque_on=True, hardware_error_bits=0, temperature_c=40.0,
                                                input_voltage_v=12.0)
                                     for i, j in enumerate(("pan", "tilt", "left_eye", "right_eye"))})
image = (np.arange(48 * 64 * 3) % 251).astype(np.uint8).reshape(48, 64, 3)
frame = Frame(camera="left", counter=3, image=image, time_s=1.0, exposure_start_s=0.99)
frames = HeadFrames(Ros2Config())
event = {"seq": 4, "type": "fixation_refused", "reason": "low confidence", "confidence": 0.25, "xy": [1, 2]}
msgs = {"joint_state": convert.joint_state(state, stamp, "h/"),
        "tf": frames.moving({"pan": 5.0, "tilt": -3.0, "left_eye": 1.0, "right_eye": -2.0}, stamp),
        "tf_static": frames.static(stamp),
        "compressed": convert.compressed(frame, stamp, "left_camera_optical_frame", 80),
        "image": convert.image(frame, stamp, "left_camera_optical_frame"),
        "camera_info": convert.camera_info(64, 48, stamp, "left_camera_optical_frame"),
        "gaze_state": convert.gaze_state(event, "h/"),
        "diagnostics": m.DiagnosticArray(header=m.Header(stamp=stamp, frame_id=""),
                                         status=[convert.gaze_state(event), convert.gaze_state({"type": "look_done"})])}
print(json.dumps({"module": m.__name__, **{k: cdr(v).hex() for k, v in msgs.items()}}))
"""


def run(mode: str) -> dict[str, str]:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    done = subprocess.run([sys.executable, "-c", PROGRAM, mode], capture_output=True, text=True, env=env,
                          cwd=ROOT, timeout=120)
    assert done.returncode == 0, done.stderr
    out: dict[str, str] = json.loads(done.stdout.strip().splitlines()[-1])
    return out


def test_the_bytes_without_cyclonedds_are_those_with_it() -> None:
    with_dds, without = run("with"), run("without")
    assert with_dds.pop("module") == "headctl.ros2.messages"
    assert without.pop("module") == "headctl.ros2.bagtypes"
    assert sorted(without) == sorted(with_dds)
    for name in with_dds:
        assert without[name] == with_dds[name], f"{name}: the CDR bytes differ"
