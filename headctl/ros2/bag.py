"""One rosbag2 bag in numbered MCAP files: `SplitBag`.

A bag is a directory: `<name>_0.mcap`, `<name>_1.mcap`, ... and one `metadata.yaml` listing
them, as `ros2 bag record --max-bag-size/--max-bag-duration` writes it; `ros2 bag`, Foxglove,
Rerun and `rosbags` read it. Each file is written by `rosbags.rosbag2.Writer` (MCAP storage,
metadata version 9) in a directory of its own, then moved into the bag, and the bag's
`metadata.yaml` is rewritten from every finished file's: a bag cut short (a full disk, a
killed service) still lists the files that were closed. A file is closed when its data
reaches `max_bytes` or its messages span `max_duration_ns`.
"""
from __future__ import annotations

import dataclasses
import logging
import shutil
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import yaml
from rosbags.interfaces import Qos, QosDurability, QosHistory, QosLiveliness, QosReliability, QosTime
from rosbags.rosbag2 import StoragePlugin, Writer

from headctl.ros2 import bagtypes

log = logging.getLogger(__name__)

METADATA = "metadata.yaml"
_FOREVER = QosTime(sec=9223372036, nsec=854775807)  # rmw's "infinite" duration


def qos(reliable: bool = True, transient_local: bool = False, depth: int = 10) -> Qos:
    """The offered QoS profile a recorded topic is stored with (`ros2 bag play` offers it again)."""
    return Qos(history=QosHistory.KEEP_LAST, depth=depth,
               reliability=QosReliability.RELIABLE if reliable else QosReliability.BEST_EFFORT,
               durability=QosDurability.TRANSIENT_LOCAL if transient_local else QosDurability.VOLATILE,
               deadline=_FOREVER, lifespan=_FOREVER, liveliness=QosLiveliness.AUTOMATIC,
               liveliness_lease_duration=_FOREVER, avoid_ros_namespace_conventions=False)


@dataclasses.dataclass(frozen=True)
class BagTopic:
    """A recorded topic: its full ROS 2 name, type (`sensor_msgs/msg/JointState`) and QoS."""

    name: str
    ros_type: str
    qos: Qos = dataclasses.field(default_factory=qos)


WriterFactory = Callable[[Path], Writer]


def mcap_writer(path: Path) -> Writer:
    return Writer(path, version=9, storage_plugin=StoragePlugin.MCAP)


class SplitBag:
    """The bag at `path` (which must not exist), written file by file; see the module docstring.
    `write` raises what the storage raises (an `OSError` for a full disk); `close` is idempotent."""

    def __init__(self, path: Path, topics: Sequence[BagTopic], max_bytes: int, max_duration_ns: int,
                 writer: WriterFactory = mcap_writer) -> None:
        self.path = path
        self.topics = {t.name: t for t in topics}
        self.max_bytes = max_bytes
        self.max_duration_ns = max_duration_ns
        self._new_writer = writer
        self.files: list[dict[str, Any]] = []  # each finished file's own metadata
        self.bytes_written = 0
        self._writer: Writer | None = None
        self._connections: dict[str, Any] = {}
        self._file_bytes = 0
        self._file_start_ns: int | None = None
        self.on_new_file: Callable[[], None] | None = None  # called when a file opens (re-send latched topics)
        path.mkdir(parents=True)

    @property
    def file_index(self) -> int:
        return len(self.files)

    def _open(self) -> Writer:
        writer = self._new_writer(self.path / f"{self.path.name}_{self.file_index}")
        writer.open()
        store = bagtypes.typestore()
        self._connections = {t.name: writer.add_connection(t.name, t.ros_type, typestore=store,
                                                           offered_qos_profiles=[t.qos])
                             for t in self.topics.values()}
        self._writer, self._file_bytes, self._file_start_ns = writer, 0, None
        if self.on_new_file is not None:
            self.on_new_file()
        return writer

    def write(self, topic: str, timestamp_ns: int, data: bytes) -> None:
        writer = self._writer or self._open()
        if self._file_start_ns is None:
            self._file_start_ns = timestamp_ns
        elif (self._file_bytes >= self.max_bytes or timestamp_ns - self._file_start_ns >= self.max_duration_ns):
            self._finish()
            writer = self._open()
            self._file_start_ns = timestamp_ns
        writer.write(self._connections[topic], timestamp_ns, data)
        self._file_bytes += len(data)
        self.bytes_written += len(data)

    def _finish(self) -> None:
        """Close the open file, move it into the bag, rewrite the bag's metadata."""
        writer, self._writer = self._writer, None
        if writer is None:
            return
        writer.close()
        folder = writer.path
        info = yaml.safe_load((folder / METADATA).read_text())["rosbag2_bagfile_information"]
        for name in info["relative_file_paths"]:
            (folder / name).replace(self.path / name)
        shutil.rmtree(folder)
        self.files.append(info)
        self.write_metadata()

    def abort(self) -> None:
        """Give up the open file (its storage failed); what was finished stays listed."""
        writer, self._writer = self._writer, None
        if writer is not None:
            try:
                writer.abort()
            except OSError as err:
                log.warning("record: %s: %s", writer.path, err)

    def close(self) -> None:
        self._finish()
        if not self.files and not (self.path / METADATA).exists():
            self.write_metadata()

    def write_metadata(self) -> None:
        """`metadata.yaml` of every finished file, as rosbag2 writes a split bag's."""
        files = self.files
        starts = [f["starting_time"]["nanoseconds_since_epoch"] for f in files]
        ends = [s + f["duration"]["nanoseconds"] for s, f in zip(starts, files)]
        counts: dict[str, int] = {}
        for info in files:
            for entry in info["topics_with_message_count"]:
                name = entry["topic_metadata"]["name"]
                counts[name] = counts.get(name, 0) + entry["message_count"]
        topics = files[-1]["topics_with_message_count"] if files else []
        merged = {**(files[-1] if files else {"version": 9, "storage_identifier": "mcap",
                                              "compression_format": "", "compression_mode": "",
                                              "custom_data": None, "ros_distro": "rosbags"}),
                  "relative_file_paths": [p for f in files for p in f["relative_file_paths"]],
                  "duration": {"nanoseconds": (max(ends) - min(starts)) if files else 0},
                  "starting_time": {"nanoseconds_since_epoch": min(starts) if files else 0},
                  "message_count": sum(f["message_count"] for f in files),
                  "topics_with_message_count": [
                      {**t, "message_count": counts.get(t["topic_metadata"]["name"], 0)} for t in topics],
                  "files": [file for f in files for file in f["files"]]}
        tmp = self.path / (METADATA + ".tmp")
        tmp.write_text(yaml.safe_dump({"rosbag2_bagfile_information": merged}, sort_keys=False))
        tmp.replace(self.path / METADATA)
