"""The live view of a simulated head in Foxglove, seen by a Foxglove WebSocket client over
loopback (`tests/support/foxglove_client.py`): the channels and their schemas as advertised,
joint states decoded by the advertised schema and equal to the servo loop's, the eyes' JPEGs
with their annotations, the frames, the learning curve; nothing encoded while no one watches."""
from __future__ import annotations

import dataclasses
import json
import math
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest

from tests.headctl.foxglove.support import need_foxglove

need_foxglove()

from headctl.api.compose import serve  # noqa: E402
from headctl.config.foxglove import FoxgloveConfig  # noqa: E402
from headctl.config.head import HeadConfig  # noqa: E402
from headctl.errors import HeadctlError  # noqa: E402
from headctl.foxglove.view import FoxgloveView  # noqa: E402
from headctl.service.daemon import Daemon  # noqa: E402
from tests.conftest import sim_head_config, wait_until  # noqa: E402
from tests.support.foxglove_client import SUBPROTOCOLS, FoxgloveClient  # noqa: E402
from tests.support.protobuf_wire import decode, descriptors  # noqa: E402

pytestmark = pytest.mark.timeout(120)

SCHEMAS = {"/joint_states": "foxglove.JointStates", "/tf": "foxglove.FrameTransforms",
           "/head/left/image": "foxglove.CompressedImage", "/head/right/image": "foxglove.CompressedImage",
           "/head/left/annotations": "foxglove.ImageAnnotations",
           "/head/right/annotations": "foxglove.ImageAnnotations", "/head/learning": "headctl.Learning"}
JOINTS = ("pan", "tilt", "left_eye", "right_eye")


def foxglove_config(state_dir: Path, **foxglove: Any) -> HeadConfig:
    return dataclasses.replace(sim_head_config(state_dir), foxglove=FoxgloveConfig(enabled=True, port=0, **foxglove))


@pytest.fixture(scope="module")
def daemon(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Daemon]:
    with serve(foxglove_config(tmp_path_factory.mktemp("fox") / "state")) as running:
        yield running


def view_of(daemon: Daemon) -> FoxgloveView:
    parts = getattr(daemon.front_end, "parts", ())
    found = [p for p in parts if isinstance(p, FoxgloveView)]
    assert found, f"no Foxglove view among the front ends: {parts!r}"
    return found[0]


class Session:
    """A connected client with the server's channels by topic."""

    def __init__(self, port: int) -> None:
        self.client = FoxgloveClient("127.0.0.1", port)
        self.info = self.client.receive_json("serverInfo")
        self.channels: dict[str, dict[str, Any]] = {}
        while set(self.channels) < set(SCHEMAS):  # the SDK may advertise in several messages
            for channel in self.client.receive_json("advertise")["channels"]:
                self.channels[channel["topic"]] = channel
        self.topics: dict[int, str] = {}

    def subscribe(self, *topics: str) -> None:
        start = len(self.topics) + 1
        subs = {start + i: self.channels[t]["id"] for i, t in enumerate(topics)}
        self.topics.update({s: t for s, t in zip(subs, topics)})
        self.client.subscribe(subs)

    def next(self, topic: str, limit: int = 5000) -> tuple[int, bytes]:
        """The next message on `topic` (log time, payload)."""
        for _ in range(limit):
            data = self.client.receive_data()
            if self.topics.get(data.subscription) == topic:
                return data.log_time_ns, data.payload
        raise AssertionError(f"no message on {topic} in {limit} messages")

    def decoded(self, topic: str) -> tuple[int, dict[str, Any]]:
        channel = self.channels[topic]
        log_time, payload = self.next(topic)
        return log_time, decode(descriptors(channel["schema"]), channel["schemaName"], payload)

    def close(self) -> None:
        self.client.close()


@pytest.fixture
def session(daemon: Daemon) -> Iterator[Session]:
    s = Session(view_of(daemon).publisher.port)  # type: ignore[union-attr]
    try:
        yield s
    finally:
        s.close()


def seconds(stamp: dict[str, Any]) -> float:
    return stamp.get("seconds", 0) + stamp.get("nanos", 0) / 1e9


def test_the_channels_and_their_schemas_are_advertised(daemon: Daemon, session: Session) -> None:
    assert session.client.subprotocol in SUBPROTOCOLS
    assert view_of(daemon).url == f"ws://127.0.0.1:{view_of(daemon).publisher.port}"  # type: ignore[union-attr]
    assert {t: c["schemaName"] for t, c in session.channels.items()} == SCHEMAS
    for topic, name in SCHEMAS.items():
        channel = session.channels[topic]
        if topic == "/head/learning":
            assert (channel["encoding"], channel["schemaEncoding"]) == ("json", "jsonschema")
            schema = json.loads(channel["schema"])
            assert {"retinal_error", "confidence", "taught", "adaptations", "output_error_deg"} <= set(
                schema["properties"]), schema
        else:
            assert (channel["encoding"], channel["schemaEncoding"]) == ("protobuf", "protobuf"), channel
            assert name in descriptors(channel["schema"]), f"{topic}: {name} not in its FileDescriptorSet"


def test_a_joint_state_received_is_the_servo_loop_s(daemon: Daemon, session: Session) -> None:
    daemon.control.set_exploration(False)
    try:
        wait_until(lambda: (s := daemon.control.joint_state()) is not None and not s.moving
                   and daemon.control.snapshot().fixation.state.startswith("idle"), 30.0,
                   "the head at rest, not exploring")
        session.subscribe("/joint_states")
        log_time, message = session.decoded("/joint_states")
        state = daemon.control.joint_state()
        assert state is not None
        joints = {j["name"]: j for j in message["joints"]}
        assert tuple(joints) == JOINTS
        for name in JOINTS:
            assert math.isclose(joints[name].get("position", 0.0), math.radians(state.joints[name].position),
                                abs_tol=math.radians(0.05)), (name, joints[name], state.joints[name])
        assert abs(seconds(message["timestamp"]) - log_time / 1e9) < 1e-6  # stamped at the read, as logged
    finally:
        daemon.control.set_exploration(True)


def test_each_eye_s_jpeg_comes_with_its_annotations(daemon: Daemon, session: Session) -> None:
    width, height = daemon.config.image_size
    for side in ("left", "right"):
        session.subscribe(f"/head/{side}/image", f"/head/{side}/annotations")
        image_time, image = session.decoded(f"/head/{side}/image")
        assert image["format"] == "jpeg" and image["frame_id"] == f"{side}_camera_optical_frame"
        pixels = cv2.imdecode(np.frombuffer(image["data"], np.uint8), cv2.IMREAD_UNCHANGED)
        assert pixels is not None and pixels.shape[:2] == (height, width)
        notes_time, notes = session.decoded(f"/head/{side}/annotations")
        # the fovea, a circle at the image's centre: Foxglove's origin is the top-left pixel's corner
        fovea = notes["circles"][0]
        assert (fovea["position"]["x"], fovea["position"]["y"]) == (width / 2, height / 2)
        # and a cross on it: two segments through the centre, one across, one down
        cross = [(p.get("x", 0.0), p.get("y", 0.0)) for p in notes["points"][0]["points"]]
        assert len(cross) == 4 and cross[0][1] == cross[1][1] == height / 2 and cross[2][0] == cross[3][0] == width / 2
        assert cross[0][0] + cross[1][0] == width and cross[2][1] + cross[3][1] == height, cross
        assert notes_time >= image_time - 1_000_000_000  # the annotations of a frame no older than 1 s


def test_the_frames_hang_from_the_base_to_both_optical_frames(session: Session) -> None:
    session.subscribe("/tf")
    _, message = session.decoded("/tf")
    parent = {t["child_frame_id"]: t["parent_frame_id"] for t in message["transforms"]}
    for side in ("left", "right"):
        chain, frame = [], f"{side}_camera_optical_frame"
        while frame in parent:
            chain.append(frame)
            frame = parent[frame]
        assert frame == "base_link" and chain[1:] == [f"{side}_eye_link", "neck_tilt_link", "neck_pan_link"], chain
    for t in message["transforms"]:
        q = t["rotation"]
        assert math.isclose(sum(q.get(k, 0.0) ** 2 for k in "xyzw"), 1.0, rel_tol=1e-9), t


def test_the_learning_curve_arrives_point_by_point(daemon: Daemon, session: Session) -> None:
    session.subscribe("/head/learning")
    first = json.loads(session.next("/head/learning")[1])
    second = json.loads(session.next("/head/learning")[1])
    assert second["n"] > first["n"] and second["adaptations"] > first["adaptations"]
    points = {p["n"]: p for p in daemon.control.learning_since(0)["points"]}  # type: ignore[union-attr]
    assert math.isclose(first["retinal_error"], points[first["n"]]["retinal_error"])
    assert isinstance(first["taught"], int) and first["taught"] >= 1
    assert set(first["output_error_deg"]) == {"pan", "tilt", "vergence"}


def test_nothing_is_encoded_while_no_client_subscribes(daemon: Daemon) -> None:
    publisher = view_of(daemon).publisher
    assert publisher is not None
    with FoxgloveClient("127.0.0.1", publisher.port) as client:
        client.receive_json("advertise")  # connected, subscribed to nothing
        wait_until(lambda: not publisher.watched(), 10.0, "no subscriber left from the tests before")
        before = dict(publisher.published)
        frame = daemon.control.latest_frame("left")
        assert frame is not None
        wait_until(lambda: (f := daemon.control.latest_frame("left")) is not None and f.counter >= frame.counter + 5,
                   10.0, "five new frames")
        assert {k: v for k, v in publisher.published.items() if "image" in k} == \
            {k: v for k, v in before.items() if "image" in k}


def test_a_port_in_use_is_refused_naming_the_key(daemon: Daemon, tmp_path: Path) -> None:
    taken = view_of(daemon).publisher.port  # type: ignore[union-attr]
    config = dataclasses.replace(foxglove_config(tmp_path / "state"),
                                 foxglove=FoxgloveConfig(enabled=True, port=taken))
    with pytest.raises(HeadctlError, match=rf"foxglove: cannot serve on 127.0.0.1:{taken} \(foxglove.host, "
                                           r"foxglove.port\)"):
        FoxgloveView(daemon.control, config).__enter__()
