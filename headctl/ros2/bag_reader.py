"""A recorded bag's messages in the order they were written, the readable part of a cut-short one too.

A bag of `headctl.ros2.bag.SplitBag` is `<bag>_0.mcap`, `<bag>_1.mcap`, ... listed in its
`metadata.yaml` as each closes. A recording killed (or stopped by a full disk) leaves its open
file unlisted, in the folder it was being written in (`<bag>_N/<bag>_N.mcap`), without the
summary and footer an MCAP reader seeks to, and perhaps ending inside a record. `BagReader`
reads every file in index order, listed or not, record by record with the MCAP reference
reader's stream reader (`mcap.stream_reader`: no summary needed), and stops at the first
record that does not read; `problems` says which files were cut short and where.
"""
from __future__ import annotations

import dataclasses
import logging
import re
import struct
from collections.abc import Iterator
from pathlib import Path

import yaml
from mcap.exceptions import McapError
from mcap.records import Channel, Message, Schema
from mcap.stream_reader import StreamReader

from headctl.errors import HeadctlError
from headctl.ros2.bag import METADATA
from headctl.ros2.fixation_log import BagMessage

log = logging.getLogger(__name__)


class BagReadError(HeadctlError, ValueError):
    """Not a bag, or nothing in it reads."""


def _index(path: Path) -> int:
    found = re.search(r"_(\d+)\.mcap$", path.name)
    return int(found.group(1)) if found else 0


def bag_files(path: Path) -> list[Path]:
    """The MCAP files of the bag at `path` (a bag's directory or one `.mcap` file), in index
    order: those its metadata lists, then any it does not (a file being written when the
    recording ended)."""
    if path.is_file():
        return [path]
    if not path.is_dir():
        raise BagReadError(f"{path}: no such bag (a directory with metadata.yaml, or an .mcap file)")
    listed: list[Path] = []
    meta = path / METADATA
    if meta.exists():
        try:
            info = yaml.safe_load(meta.read_text())["rosbag2_bagfile_information"]
            listed = [path / name for name in info.get("relative_file_paths") or []]
        except (yaml.YAMLError, KeyError, TypeError) as err:
            log.warning("%s: unreadable (%s); reading every .mcap file of the bag", meta, err)
    found = set(path.glob("*.mcap")) | set(path.glob("*/*.mcap"))
    files = [p for p in listed if p.exists()] + sorted(found - set(listed), key=_index)
    if not files:
        raise BagReadError(f"{path}: no .mcap file in it")
    return sorted(files, key=_index)


@dataclasses.dataclass
class BagReader:
    """`messages()` of the bag at `path`; after it, `problems` (files cut short) and `files`."""

    path: Path
    problems: list[str] = dataclasses.field(default_factory=list)
    files: list[Path] = dataclasses.field(default_factory=list)

    def messages(self) -> Iterator[BagMessage]:
        self.files = bag_files(self.path)
        for file in self.files:
            yield from self._file(file)

    def _file(self, file: Path) -> Iterator[BagMessage]:
        schemas: dict[int, str] = {}
        channels: dict[int, tuple[str, str]] = {}
        count = 0
        try:
            with file.open("rb") as f:
                for record in StreamReader(f, record_size_limit=1 << 30).records:
                    if isinstance(record, Schema):
                        schemas[record.id] = record.name
                    elif isinstance(record, Channel):
                        channels[record.id] = (record.topic, schemas.get(record.schema_id, ""))
                    elif isinstance(record, Message) and record.channel_id in channels:
                        topic, msgtype = channels[record.channel_id]
                        count += 1
                        yield BagMessage(topic, msgtype, record.log_time, bytes(record.data))
        except (McapError, EOFError, struct.error, ValueError, OSError) as err:
            problem = f"{file.name}: cut short after {count} messages ({type(err).__name__}: {err or 'end of file'})"
            log.warning("%s", problem)
            self.problems.append(problem)
