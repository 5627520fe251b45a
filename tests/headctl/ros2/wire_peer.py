"""A ROS 2 peer in a process of its own, over the loopback interface (no multicast): run as
`python -m tests.headctl.ros2.wire_peer DOMAIN`; prints one JSON line of what it saw."""
from __future__ import annotations

import json
import math
import sys
import time

from cyclonedds.domain import Domain

from headctl.config.ros2 import Ros2Config
from headctl.ros2 import messages as m
from headctl.ros2.commands import GAZE_STATE, LOOK_AT_ANGLES
from headctl.ros2.node import DISCOVERY_TOPIC, LOCALHOST_XML, QosKind, TopicSpec
from headctl.ros2.streams import JOINT_STATES, image_topics
from tests.headctl.ros2.peer import Peer


def main(domain_id: int) -> None:
    config = Ros2Config(enabled=True, domain_id=domain_id, localhost_only=True, commands=True)
    domain = Domain(domain_id, LOCALHOST_XML)
    peer = Peer(config)
    peer.subscribe(JOINT_STATES)
    peer.subscribe(image_topics("left")[0])
    peer.subscribe(GAZE_STATE)
    discovery = TopicSpec(DISCOVERY_TOPIC, m.ParticipantEntitiesInfo, QosKind.DISCOVERY)
    peer.subscribe(discovery, dds_name=DISCOVERY_TOPIC)
    writer = peer.publisher(LOOK_AT_ANGLES)
    deadline = time.monotonic() + 20
    while writer.get_publication_matched_status().current_count < 1 and time.monotonic() < deadline:
        time.sleep(0.01)
    peer.wait_for("/joint_states", 50, timeout_s=20)
    peer.wait_for("/head/left/image_raw", 10, timeout_s=20)
    writer.write(m.JointState(name=["pan", "tilt", "vergence"], position=[math.radians(a) for a in (-8.0, 4.0, 6.0)]))
    done = peer.wait_for("/head/gaze_state", where=lambda s: s.name == "look_done", timeout_s=20)[0]
    info = peer.wait_for("ros_discovery_info", timeout_s=20)[-1]
    # The rates by the messages' own stamps: arrival times bunch up on a loaded machine.
    joints = [s.header.stamp.seconds for _, s in peer.samples["/joint_states"]]
    images = [s.header.stamp.seconds for _, s in peer.samples["/head/left/image_raw"]]
    node = info.node_entities_info_seq[0]
    print(json.dumps({
        "joint_states_hz": (len(joints) - 1) / (joints[-1] - joints[0]),
        "images_fps": (len(images) - 1) / (images[-1] - images[0]),
        "image_bytes": len(peer.samples["/head/left/image_raw"][-1][1].data),
        "look_done": {kv.key: kv.value for kv in done.values},
        "node": [node.node_namespace, node.node_name, len(node.writer_gid_seq), len(node.reader_gid_seq)],
    }))
    peer.close()
    del domain


if __name__ == "__main__":
    main(int(sys.argv[1]))
