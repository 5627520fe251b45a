"""The service on ROS 2 topics, seen by a second DDS participant on the loopback interface:
the topics under their ROS 2 names, types and QoS, joint states at the configured rate,
images at the camera's, the frames, diagnostics, and the commands (accepted only when the
config says so, refused with the HTTP API's reasons on /head/gaze_state)."""
from __future__ import annotations

import dataclasses
import math
import os
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from tests.headctl.ros2.support import need

need("cyclonedds")

from headctl.api.compose import serve  # noqa: E402
from headctl.config.head import HeadConfig  # noqa: E402
from headctl.config.ros2 import Ros2Config, Ros2Rates  # noqa: E402
from headctl.errors import InvalidRequestError, UnavailableError  # noqa: E402
from headctl.ros2 import messages as m  # noqa: E402
from headctl.ros2.commands import GAZE_STATE, LOOK_AT, LOOK_AT_ANGLES, TRACK  # noqa: E402
from headctl.ros2.interface import Ros2Interface  # noqa: E402
from headctl.ros2.node import QosKind  # noqa: E402
from headctl.ros2.streams import DIAGNOSTICS, JOINT_STATES, TF, TF_STATIC, image_topics  # noqa: E402
from headctl.service.daemon import Daemon  # noqa: E402
from tests.conftest import sim_head_config, wait_until  # noqa: E402
from tests.headctl.ros2.peer import Peer  # noqa: E402

# Another engineer's tests on this machine use other domains: this process's own.
DOMAIN = 100 + os.getpid() % 100


def ros2_config(tmp_path: Path, **ros2: Any) -> HeadConfig:
    config = sim_head_config(tmp_path / "state")
    section = Ros2Config(enabled=True, domain_id=DOMAIN, localhost_only=True, **ros2)
    return dataclasses.replace(config, ros2=section)


@pytest.fixture
def running(tmp_path: Path, request: pytest.FixtureRequest) -> Iterator[tuple[Daemon, Peer]]:
    marker = request.node.get_closest_marker("ros2")
    config = ros2_config(tmp_path, **(marker.kwargs if marker else {}))
    with serve(config) as daemon:
        peer = Peer(config.ros2)
        try:
            yield daemon, peer
        finally:
            peer.close()


def has_recent_pair(daemon: Daemon) -> bool:
    """Whether the daemon holds a pair recent enough to measure a target's disparity in."""
    try:
        daemon.control.measure_disparity(160.0, 120.0)
    except UnavailableError:
        return False
    except InvalidRequestError:  # measured in a pair, only not a place to look at
        pass
    return True


def interface(daemon: Daemon) -> Ros2Interface:
    composite = daemon.front_end
    assert composite is not None
    found = [p for p in getattr(composite, "parts", ()) if isinstance(p, Ros2Interface)]
    assert found, f"no ROS 2 interface among the front ends: {composite!r}"
    return found[0]


def test_topics_types_and_qos_as_ros2_names_them(running: tuple[Daemon, Peer]) -> None:
    daemon, peer = running
    specs = [JOINT_STATES, TF, TF_STATIC, DIAGNOSTICS, GAZE_STATE, *image_topics("left"), *image_topics("right")]
    for spec in specs:
        peer.subscribe(spec)
    for spec in specs:  # each matched: same DDS name (rt/...), same type name, compatible QoS
        wait_until(lambda: peer.matched(spec.ros_name(peer.config)) == 1, 10.0, f"{spec.name} matched")
    assert JOINT_STATES.dds_name(peer.config) == "rt/joint_states"
    assert m.JointState.__idl_typename__ == "sensor_msgs::msg::dds_::JointState_"
    # images are best effort: a reliable reader does not match, and says why
    left_raw = image_topics("left")[0]
    strict = dataclasses.replace(left_raw, name="head/left/image_raw")
    reliable_peer_reader = peer.subscribe(strict, QosKind.DEFAULT)  # replaces the best-effort one in `readers`
    wait_until(lambda: peer.incompatible("/head/left/image_raw") >= 1, 10.0, "a reliable image reader refused")
    assert reliable_peer_reader.get_subscription_matched_status().current_count == 0
    # /tf_static is transient local: a reader that joins late still gets the optical frames
    static = peer.wait_for("/tf_static")[0]
    children = {t.child_frame_id: t for t in static.transforms}
    assert set(children) == {"left_camera_optical_frame", "right_camera_optical_frame"}
    assert children["left_camera_optical_frame"].header.frame_id == "left_eye_link"
    # a ROS 2 user's node list reads ros_discovery_info
    # (its Gid size per distro is checked in test_messages)


def test_joint_states_at_the_servo_rate_stamped_at_the_read_in_radians(running: tuple[Daemon, Peer]) -> None:
    daemon, peer = running
    peer.subscribe(JOINT_STATES)
    rate_hz = peer.rate_hz("/joint_states", 100)
    assert 85 <= rate_hz <= 110, f"joint states at {rate_hz:.1f} Hz, the servo loop's 100"
    msg = peer.samples["/joint_states"][-1][1]
    assert msg.name == ["pan", "tilt", "left_eye", "right_eye"] and msg.effort == []
    state = daemon.control.joint_state()
    assert state is not None
    assert all(abs(p) <= math.radians(45) for p in msg.position)  # radians, within the sim's limits
    stamps = [s.header.stamp.seconds for _, s in peer.samples["/joint_states"][-50:]]
    assert all(b > a for a, b in zip(stamps, stamps[1:]))  # a new read each time
    assert abs(stamps[-1] - time.time()) < 1.0  # ROS time: the wall clock


@pytest.mark.ros2(rates=Ros2Rates(joint_states_hz=25.0))
def test_joint_states_at_the_configured_rate(running: tuple[Daemon, Peer]) -> None:
    daemon, peer = running
    peer.subscribe(JOINT_STATES)
    rate_hz = peer.rate_hz("/joint_states", 25)
    assert 20 <= rate_hz <= 28, f"joint states at {rate_hz:.1f} Hz, configured 25"


def test_images_at_the_camera_rate_with_camera_info_and_jpeg(running: tuple[Daemon, Peer]) -> None:
    daemon, peer = running
    for side in ("left", "right"):
        for spec in image_topics(side):
            peer.subscribe(spec)
    fps = peer.rate_hz("/head/left/image_raw", 30)
    assert 24 <= fps <= 33, f"left images at {fps:.1f} fps, the camera's 30"
    img = peer.samples["/head/left/image_raw"][-1][1]
    assert (img.width, img.height, img.header.frame_id) == (320, 240, "left_camera_optical_frame")
    channels = 3 if img.encoding == "bgr8" else 1
    assert img.encoding in ("bgr8", "mono8") and img.step == 320 * channels and len(img.data) == img.step * 240
    info = peer.wait_for("/head/right/camera_info")[0]
    assert (info.width, info.height, list(info.k)) == (320, 240, [0.0] * 9)  # uncalibrated
    assert info.header.frame_id == "right_camera_optical_frame"
    jpeg = peer.wait_for("/head/right/image_raw/compressed")[0]
    import cv2
    decoded = cv2.imdecode(np.frombuffer(jpeg.data, np.uint8), cv2.IMREAD_UNCHANGED)
    assert decoded.shape[:2] == (240, 320) and "jpeg" in jpeg.format


def test_tf_and_diagnostics(running: tuple[Daemon, Peer]) -> None:
    daemon, peer = running
    peer.subscribe(TF)
    peer.subscribe(DIAGNOSTICS)
    tf = peer.wait_for("/tf")[0]
    chain = {(t.header.frame_id, t.child_frame_id) for t in tf.transforms}
    assert chain == {("base_link", "neck_pan_link"), ("neck_pan_link", "neck_tilt_link"),
                     ("neck_tilt_link", "left_eye_link"), ("neck_tilt_link", "right_eye_link")}
    eye = next(t for t in tf.transforms if t.child_frame_id == "left_eye_link")
    assert (eye.transform.translation.x, eye.transform.translation.y) == pytest.approx((0.02, 0.03))
    diag = peer.wait_for("/diagnostics", timeout_s=5.0)[0]
    names = {s.name for s in diag.status}
    assert {"headctl: servo pan", "headctl: servo loop", "headctl: camera left", "headctl: gaze map",
            "headctl: faults"} <= names
    pan = next(s for s in diag.status if s.name == "headctl: servo pan")
    assert {kv.key for kv in pan.values} >= {"temperature_c", "input_voltage_v", "hardware_errors"}


@pytest.mark.ros2(commands=True)
def test_look_at_angles_moves_the_head_and_gaze_state_tells(running: tuple[Daemon, Peer]) -> None:
    daemon, peer = running
    peer.subscribe(GAZE_STATE)
    peer.subscribe(JOINT_STATES)
    writer = peer.publisher(LOOK_AT_ANGLES)
    wait_until(lambda: writer.get_publication_matched_status().current_count == 1, 10.0, "the command matched")
    goal = (10.0, 5.0, 6.0)
    writer.write(m.JointState(name=["pan", "tilt", "vergence"], position=[math.radians(a) for a in goal]))
    queued = peer.wait_for("/head/gaze_state", where=lambda s: s.name == "look_queued")[0]
    look_id = next(kv.value for kv in queued.values if kv.key == "id")
    done = peer.wait_for("/head/gaze_state", where=lambda s: s.name == "look_done", timeout_s=15.0)[0]
    values = {kv.key: kv.value for kv in done.values}
    assert values["id"] == look_id and values["state"] == "done", values
    pose = daemon.control.snapshot().pose
    assert pose is not None and pose["pan"] == pytest.approx(10.0, abs=0.5) and pose["tilt"] == pytest.approx(5.0, abs=0.5)


@pytest.mark.ros2(commands=True)
def test_look_at_a_pixel_makes_the_head_look(running: tuple[Daemon, Peer]) -> None:
    daemon, peer = running
    peer.subscribe(GAZE_STATE)
    writer = peer.publisher(LOOK_AT)
    wait_until(lambda: writer.get_publication_matched_status().current_count == 1, 10.0, "the command matched")
    wait_until(lambda: has_recent_pair(daemon), 10.0, "a recent stereo pair to measure d in")
    writer.write(m.PointStamped(header=m.Header(frame_id="left_camera_optical_frame"),
                                point=m.Point(x=230.0, y=120.0, z=math.nan)))
    started = peer.wait_for("/head/gaze_state", where=lambda s: s.name == "look_started", timeout_s=15.0)[0]
    request = {kv.key: kv.value for kv in started.values}
    assert (request["kind"], request["x"], request["y"]) == ("target", "230.0", "120.0")
    done = peer.wait_for("/head/gaze_state", where=lambda s: s.name == "look_done", timeout_s=30.0)[0]
    values = {kv.key: kv.value for kv in done.values}
    job = daemon.control.get_look(int(values["id"]))
    assert values["state"] == str(job.state) and done.message.startswith(job.outcome)
    # The look ran as an HTTP one does: a saccade planned by the (still random) map, then the
    # search for the target; whether it lands is the map's business, not the interface's.
    assert job.state.finished and job.result["pose_before"] != job.result["pose_after"]
    assert job.result["head_moved_deg"] > 0.5 and job.result["fixations"], job.result


@pytest.mark.ros2(commands=True)
def test_bad_commands_get_the_http_reasons_and_never_move_the_head(running: tuple[Daemon, Peer]) -> None:
    daemon, peer = running
    peer.subscribe(GAZE_STATE)
    look_at, angles, track = peer.publisher(LOOK_AT), peer.publisher(LOOK_AT_ANGLES), peer.publisher(TRACK)
    for w in (look_at, angles, track):
        wait_until(lambda: w.get_publication_matched_status().current_count == 1, 10.0, "the command matched")
    wait_until(lambda: daemon.control.joint_state() is not None, 10.0, "a servo state")
    angles.write(m.JointState(name=["pan", "tilt", "vergence"], position=[math.radians(80.0), 0.0, math.radians(6.0)]))
    look_at.write(m.PointStamped(point=m.Point(x=1000.0, y=10.0, z=math.nan)))
    track.write(m.PointStamped(point=m.Point(x=math.inf, y=10.0)))
    angles.write(m.JointState(name=["pan"], position=[0.1]))
    refused = peer.wait_for("/head/gaze_state", 4, where=lambda s: s.name.endswith("_refused"))
    assert all(s.level == m.Level.ERROR for s in refused)
    reasons = sorted({kv.key: kv.value for kv in s.values}["reason"] for s in refused)
    # the same words as the HTTP API's 422 answers (ServiceControl.look, .track)
    assert reasons[0].startswith("pan: 80 deg is outside the limits [-40, 40] deg"), reasons
    assert reasons[1].startswith("tilt, vergence missing: an absolute look needs pan, tilt and vergence"), reasons
    assert reasons[2] == "x = 1000 is outside the image's columns, [0, 319]", reasons
    assert reasons[3] == "x: got inf, expected a finite number", reasons
    fields = sorted({kv.key: kv.value for kv in s.values}["field"] for s in refused)
    assert fields == ["pan", "tilt", "x", "x"]
    goals = daemon.control.snapshot().joints
    assert all(abs(j.goal_deg or 0.0) <= 40 for j in goals.values())
    assert daemon.parts.looks.pending() == 0


def test_commands_are_not_taken_unless_the_config_says_so(running: tuple[Daemon, Peer]) -> None:
    daemon, peer = running
    assert interface(daemon).commands is None
    peer.subscribe(GAZE_STATE)
    writer = peer.publisher(LOOK_AT_ANGLES)
    wait_until(lambda: peer.matched("/head/gaze_state") == 1, 10.0, "gaze_state matched")
    # nobody reads the command topic: the writer never matches, the head never moves
    assert writer.get_publication_matched_status().current_count == 0
    writer.write(m.JointState(name=["pan", "tilt", "vergence"], position=[0.2, 0.1, 0.1]))
    assert daemon.parts.looks.pending() == 0 and not peer.samples["/head/gaze_state"]


def test_the_api_still_serves_beside_ros2(running: tuple[Daemon, Peer]) -> None:
    daemon, _ = running
    assert daemon.api_url is not None and daemon.api_url.startswith("http://127.0.0.1:")
    assert interface(daemon).is_alive() and daemon.front_end is not None and daemon.front_end.is_alive()
    assert "api" not in daemon.control.snapshot().faults


@pytest.mark.ros2(commands=True)
def test_a_peer_in_another_process_over_loopback(running: tuple[Daemon, Peer]) -> None:
    """The same over the wire: another process, loopback only, unicast discovery."""
    import json
    import subprocess
    import sys

    daemon, _ = running
    out = subprocess.run([sys.executable, "-m", "tests.headctl.ros2.wire_peer", str(DOMAIN)], capture_output=True,
                         text=True, timeout=90, env={**os.environ, "PYTHONPATH": os.getcwd()})
    assert out.returncode == 0, out.stderr[-3000:]
    seen = json.loads(out.stdout.strip().splitlines()[-1])
    assert 80 <= seen["joint_states_hz"] <= 110, seen
    assert 24 <= seen["images_fps"] <= 33 and seen["image_bytes"] in (320 * 240, 320 * 240 * 3), seen
    assert seen["look_done"]["state"] == "done", seen["look_done"]
    # ros_discovery_info: the node, its writers and readers (what `ros2 node list` / `topic info -v` read)
    namespace, name, writers, readers = seen["node"]
    assert (namespace, name) == ("/", "headctl") and writers == 11 and readers == 3


@pytest.mark.ros2(commands=True)
def test_track_the_fovea_then_stop(running: tuple[Daemon, Peer]) -> None:
    daemon, peer = running
    peer.subscribe(GAZE_STATE)
    track = peer.publisher(TRACK)
    wait_until(lambda: track.get_publication_matched_status().current_count == 1, 10.0, "the command matched")
    wait_until(lambda: daemon.control.latest_frame("left") is not None, 10.0, "a frame")
    track.write(m.PointStamped(point=m.Point(x=math.nan, y=math.nan)))
    queued = peer.wait_for("/head/gaze_state", where=lambda s: s.name == "track_queued")[0]
    track_id = {kv.key: kv.value for kv in queued.values}["id"]
    peer.wait_for("/head/gaze_state", where=lambda s: s.name in ("track_started", "track_stopped"), timeout_s=15.0)
    track.write(m.PointStamped(header=m.Header(frame_id="stop")))
    stopped = peer.wait_for("/head/gaze_state", where=lambda s: s.name == "track_stopped", timeout_s=15.0)[0]
    assert {kv.key: kv.value for kv in stopped.values}["id"] == track_id
    wait_until(lambda: daemon.control.get_track()["state"].finished, 5.0, "the track finished")
