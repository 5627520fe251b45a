"""A second DDS participant, as a ROS 2 node on the other end would be: readers and writers on
the ROS 2 names, types and QoS (`headctl.ros2.node`), collecting what arrives."""
from __future__ import annotations

import collections
import threading
import time
from typing import Any

from cyclonedds.core import Listener
from cyclonedds.domain import DomainParticipant
from cyclonedds.pub import DataWriter
from cyclonedds.sub import DataReader
from cyclonedds.topic import Topic

from headctl.config.ros2 import Ros2Config
from headctl.ros2.node import QosKind, TopicSpec, qos_of


class Peer:
    """Readers that keep every sample with its arrival time; `wait_for(topic, n)`."""

    def __init__(self, config: Ros2Config) -> None:
        self.config = config
        self.participant = DomainParticipant(config.domain_id)
        self.samples: dict[str, list[tuple[float, Any]]] = collections.defaultdict(list)
        self._cond = threading.Condition()
        self._topics: dict[str, Topic[Any]] = {}
        self.readers: dict[str, DataReader[Any]] = {}
        self.writers: dict[str, DataWriter[Any]] = {}

    def _topic(self, spec: TopicSpec[Any], qos: QosKind, dds_name: str | None = None) -> Topic[Any]:
        name = dds_name or spec.dds_name(self.config)
        if name not in self._topics:
            self._topics[name] = Topic(self.participant, name, spec.type, qos=qos_of(qos, self.config))
        return self._topics[name]

    def subscribe(self, spec: TopicSpec[Any], qos: QosKind | None = None, dds_name: str | None = None) -> DataReader[Any]:
        """Read `spec` (its samples kept under its ROS 2 name, or `dds_name` for a topic outside
        ROS 2's names, such as ros_discovery_info)."""
        qos = qos or spec.qos
        name = dds_name or spec.ros_name(self.config)

        def on_data_available(reader: DataReader[Any] | None) -> None:
            if reader is None:  # data while the reader is made (transient local): taken below
                return
            got = reader.take(N=100)
            now = time.monotonic()
            with self._cond:
                self.samples[name].extend((now, s) for s in got)
                self._cond.notify_all()

        reader = DataReader(self.participant, self._topic(spec, qos, dds_name), qos=qos_of(qos, self.config),
                            listener=Listener(on_data_available=on_data_available))
        self.readers[name] = reader
        on_data_available(reader)
        return reader

    def publisher(self, spec: TopicSpec[Any]) -> DataWriter[Any]:
        writer = DataWriter(self.participant, self._topic(spec, spec.qos), qos=qos_of(spec.qos, self.config))
        self.writers[spec.ros_name(self.config)] = writer
        return writer

    def wait_for(self, name: str, n: int = 1, timeout_s: float = 10.0, where: Any = None) -> list[Any]:
        """The first `n` samples on `name` (matching `where`, if given), waiting up to `timeout_s`."""
        deadline = time.monotonic() + timeout_s
        with self._cond:
            while True:
                got = [s for _, s in self.samples[name] if where is None or where(s)]
                if len(got) >= n:
                    return got[:n]
                left = deadline - time.monotonic()
                if left <= 0:
                    raise AssertionError(f"{name}: {len(got)} samples of {n} in {timeout_s} s")
                self._cond.wait(left)

    def rate_hz(self, name: str, n: int) -> float:
        """The rate of the next `n` samples on `name` (after 2 to settle), by the median interval
        of their header stamps: the instants of the reads and exposures they carry. Arrival times
        would measure this machine's load as well; a median still reads one period when a busy
        machine lets the publisher miss a read now and then, and two when it publishes every
        other one."""
        self.wait_for(name, 2)
        start = len(self.samples[name])
        self.wait_for(name, start + n)
        stamps = [s.header.stamp.seconds for _, s in self.samples[name][start - 1:start + n]]
        intervals_s = sorted(b - a for a, b in zip(stamps, stamps[1:]))
        return 1.0 / intervals_s[len(intervals_s) // 2]

    def matched(self, name: str) -> int:
        return int(self.readers[name].get_subscription_matched_status().current_count)

    def incompatible(self, name: str) -> int:
        return int(self.readers[name].get_requested_incompatible_qos_status().total_count)

    def close(self) -> None:
        from headctl.ros2.node import delete

        for entity in [*self.readers.values(), *self.writers.values(), *self._topics.values(), self.participant]:
            delete(entity)
        self.readers, self.writers, self._topics = {}, {}, {}
