"""One DDS participant that ROS 2 sees as a node: its topics, their QoS, its discovery info.

What rmw_cyclonedds does for a ROS 2 node, done with Cyclone DDS's Python binding:
- a topic `/a/b` is the DDS topic `rt/a/b` of the message's DDS type (`headctl.ros2.messages`);
- QoS as ROS 2's profiles give them (`QosKind`): sensor data (best effort, volatile, keep last
  5) for images, the default profile (reliable, volatile, keep last 10) for the rest, `/tf`
  with depth 100, `/tf_static` reliable and transient local with depth 1, so that a late
  subscriber gets the static frames;
- the participant's user data `enclave=/;` and, on `ros_discovery_info` (reliable,
  transient local, keep last 1), the participant's Gid with the node's name, namespace and
  the Gids of its readers and writers (each the entity's 16-byte GUID; zero-padded to 24 bytes
  in Humble): what `ros2 node list` and `ros2 topic info -v` read;
- `localhost_only`: a domain configured on the loopback interface without multicast, its
  peers on 127.0.0.1 (what `ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST` makes rmw_cyclonedds do).
  Otherwise Cyclone's own configuration applies (`CYCLONEDDS_URI`, as for any ROS 2 node).
"""
from __future__ import annotations

import enum
import logging
import threading
from dataclasses import dataclass
from typing import Any, Generic, TypeVar

from cyclonedds.core import Entity, Policy, Qos
from cyclonedds.domain import Domain, DomainParticipant
from cyclonedds.idl import IdlStruct
from cyclonedds.pub import DataWriter
from cyclonedds.sub import DataReader
from cyclonedds.topic import Topic
from cyclonedds.util import duration

from headctl.config.ros2 import Ros2Config
from headctl.ros2 import messages as m

log = logging.getLogger(__name__)

M = TypeVar("M", bound=IdlStruct)
DISCOVERY_TOPIC = "ros_discovery_info"
MAX_BLOCKING_S = 0.1  # a reliable writer whose readers lag waits at most this long, then drops the sample

LOCALHOST_XML = """<?xml version="1.0" encoding="UTF-8"?>
<CycloneDDS xmlns="https://cdds.io/config">
  <Domain id="any">
    <General>
      <Interfaces><NetworkInterface address="127.0.0.1" multicast="false"/></Interfaces>
      <AllowMulticast>false</AllowMulticast>
    </General>
    <Discovery>
      <ParticipantIndex>auto</ParticipantIndex>
      <MaxAutoParticipantIndex>32</MaxAutoParticipantIndex>
      <Peers><Peer address="127.0.0.1"/></Peers>
    </Discovery>
  </Domain>
</CycloneDDS>
"""


class QosKind(enum.StrEnum):
    SENSOR_DATA = "sensor_data"  # images: best effort (ros2.qos.images), keep last ros2.qos.images_depth
    DEFAULT = "default"  # reliable, volatile, keep last ros2.qos.depth
    TF = "tf"  # reliable, volatile, keep last ros2.qos.tf_depth
    TF_STATIC = "tf_static"  # reliable, transient local, keep last 1
    DISCOVERY = "discovery"  # ros_discovery_info: reliable, transient local, keep last 1


def qos_of(kind: QosKind, config: Ros2Config) -> Qos:
    """The DDS QoS of a ROS 2 profile, as rmw_cyclonedds sets it."""
    reliable = Policy.Reliability.Reliable(max_blocking_time=duration(seconds=MAX_BLOCKING_S))
    if kind is QosKind.SENSOR_DATA:
        reliability = reliable if config.qos.images == "reliable" else Policy.Reliability.BestEffort
        return Qos(reliability, Policy.Durability.Volatile, Policy.History.KeepLast(config.qos.images_depth))
    if kind is QosKind.DEFAULT:
        return Qos(reliable, Policy.Durability.Volatile, Policy.History.KeepLast(config.qos.depth))
    if kind is QosKind.TF:
        return Qos(reliable, Policy.Durability.Volatile, Policy.History.KeepLast(config.qos.tf_depth))
    return Qos(reliable, Policy.Durability.TransientLocal, Policy.History.KeepLast(1))


@dataclass(frozen=True)
class TopicSpec(Generic[M]):
    """A ROS 2 topic: its name (relative to the namespace), message type and QoS profile."""

    name: str
    type: type[M]
    qos: QosKind

    def ros_name(self, config: Ros2Config) -> str:
        return config.topic(self.name)

    def dds_name(self, config: Ros2Config) -> str:
        return "rt" + self.ros_name(config)

    @property
    def ros_type(self) -> str:
        return m.ROS_TYPES[self.type]


def gid_of(entity: Entity, size: int) -> list[int]:
    """An entity's ROS 2 Gid: its DDS GUID, zero-padded to `size` bytes."""
    guid = entity.get_guid().bytes
    return list(guid.ljust(size, b"\0"))


def delete(entity: Entity) -> None:
    """Delete a DDS entity now, not when Python collects it (idempotent; the binding's own
    finaliser, which forgets the entity once deleted)."""
    entity.__del__()


class Ros2Node:
    """The participant, its writers and readers (thread-safe to write from several threads).
    A context manager: entering creates the participant, leaving deletes it and everything in it."""

    def __init__(self, config: Ros2Config) -> None:
        self.config = config
        self._lock = threading.Lock()
        self._domain: Domain | None = None
        self.participant: DomainParticipant | None = None
        self._topics: dict[str, Topic[Any]] = {}
        self._writers: list[DataWriter[Any]] = []
        self._readers: list[DataReader[Any]] = []
        self._discovery: DataWriter[Any] | None = None

    def __enter__(self) -> "Ros2Node":
        self.open()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def open(self) -> None:
        cfg = self.config
        if cfg.localhost_only:
            self._domain = Domain(cfg.domain_id, LOCALHOST_XML)
        self.participant = DomainParticipant(cfg.domain_id, qos=Qos(Policy.Userdata(b"enclave=/;")))
        info_type = m.discovery_types(cfg.distro)[0]
        topic = self._topics[DISCOVERY_TOPIC] = Topic(self.participant, DISCOVERY_TOPIC, info_type,
                                                      qos=qos_of(QosKind.DISCOVERY, cfg))
        self._discovery = DataWriter(self.participant, topic, qos=qos_of(QosKind.DISCOVERY, cfg))
        log.info("ros2: node %s/%s on DDS domain %d (%s%s)", cfg.namespace, cfg.node_name, cfg.domain_id,
                 cfg.distro, ", localhost only" if cfg.localhost_only else "")

    def _topic(self, spec: TopicSpec[M]) -> Topic[M]:
        assert self.participant is not None, "the node is not open"
        name = spec.dds_name(self.config)
        topic = self._topics.get(name)
        if topic is None:
            topic = self._topics[name] = Topic(self.participant, name, spec.type, qos=qos_of(spec.qos, self.config))
        return topic

    def writer(self, spec: TopicSpec[M]) -> DataWriter[M]:
        with self._lock:
            writer = DataWriter(self.participant, self._topic(spec), qos=qos_of(spec.qos, self.config))
            self._writers.append(writer)
            return writer

    def reader(self, spec: TopicSpec[M]) -> DataReader[M]:
        """A reader of `spec` (its samples taken by the caller)."""
        with self._lock:
            reader = DataReader(self.participant, self._topic(spec), qos=qos_of(spec.qos, self.config))
            self._readers.append(reader)
            return reader

    def announce(self) -> None:
        """Publish the node on `ros_discovery_info` with its readers and writers (call once they exist)."""
        info_type, node_type, gid_type, size = m.discovery_types(self.config.distro)
        with self._lock:
            assert self.participant is not None and self._discovery is not None, "the node is not open"
            info = info_type(gid=gid_type(data=gid_of(self.participant, size)), node_entities_info_seq=[node_type(
                node_namespace=self.config.namespace or "/", node_name=self.config.node_name,
                reader_gid_seq=[gid_type(data=gid_of(r, size)) for r in self._readers],
                writer_gid_seq=[gid_type(data=gid_of(w, size)) for w in self._writers])])
            self._discovery.write(info)

    def close(self) -> None:
        """Delete the participant and all in it (idempotent)."""
        with self._lock:
            participant, domain, discovery = self.participant, self._domain, self._discovery
            self.participant = self._domain = self._discovery = None
            entities: list[Entity] = [*self._readers, *self._writers, *([discovery] if discovery else []),
                                      *self._topics.values()]
            self._readers, self._writers, self._topics = [], [], {}
        for entity in entities:
            delete(entity)
        if participant is not None:
            delete(participant)
        if domain is not None:
            delete(domain)
