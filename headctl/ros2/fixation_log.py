"""The fixations of a recording, as a bag holds them for replay (`headctl experiment relearn`).

Three topics, standard message types, readable by any rosbag2 tool:

- `head/fixation/{left,right}/image/compressed` (sensor_msgs/CompressedImage, PNG: lossless,
  so a replay sees the very pixels the fixation saw): every stereo pair a fixation used (the
  pre-saccade pair, the pair after the saccade and after each vergence step), stamped at its
  exposure; a pair two fixations share is written once;
- `head/fixations` (diagnostic_msgs/DiagnosticStatus named `fixation`, written after its
  pairs): the `FixationRecord` (outcome, detail, confidence, position, planned and executed
  commands, poses, vergence steps), each field a KeyValue of JSON, and `calls`: the head calls
  the fixation made in order (`headctl.service.fixation_trace.Call`), a pair named by its stamp
  in nanoseconds;
- `head/fixation/config` (std_msgs/String, at the start of each file): YAML of the image size,
  the `gaze_map` section and the `fixation` section as the service ran with them.

`FixationWriter` writes traces; `read_fixations` turns a bag's messages back into
`RecordedFixation`s, in order.
"""
from __future__ import annotations

import collections
import dataclasses
import json
from collections.abc import Callable, Iterable, Iterator
from typing import Any

import cv2
import numpy as np
import yaml

from headctl.config.head import HeadConfig
from headctl.json_types import JSON, JSONObject
from headctl.ros2 import bagtypes as b
from headctl.ros2.bag import BagTopic, qos
from headctl.ros2.frames import SIDES
from headctl.service.events import plain
from headctl.service.fixation_trace import Call, FixationTrace, Raised, StereoShot

FIXATIONS = "head/fixations"
CONFIG = "head/fixation/config"
DIAGNOSTIC_STATUS = "diagnostic_msgs/msg/DiagnosticStatus"
PAIRS_KEPT = 64  # pairs remembered to write a shared one once


def pair_topic(side: str) -> str:
    return f"head/fixation/{side}/image/compressed"


def fixation_topics(topic: Callable[[str], str]) -> list[BagTopic]:
    """The topics of this module, named by `topic` (the namespace's)."""
    return [BagTopic(topic(FIXATIONS), DIAGNOSTIC_STATUS, qos(depth=100)),
            BagTopic(topic(CONFIG), "std_msgs/msg/String", qos(transient_local=True, depth=1)),
            *(BagTopic(topic(pair_topic(side)), "sensor_msgs/msg/CompressedImage", qos(depth=100)) for side in SIDES)]


def replay_config(config: HeadConfig) -> str:
    """The YAML of what a replay needs of `config`: the image size, its `gaze_map` and `fixation` sections."""
    g, f = config.gaze_map, config.fixation
    gaze_map: dict[str, object] = {"profile": g.profile, "seed": g.seed}
    gaze_map.update(g.overrides)
    fixation: dict[str, object] = dataclasses.asdict(f.params)
    fixation.update(explore=f.explore, rate_hz=f.rate_hz, vergence_range=f.vergence_range)
    return yaml.safe_dump(plain({"image_size": list(config.image_size), "gaze_map": gaze_map, "fixation": fixation},
                                digits=None), sort_keys=False)


def _png(image: np.ndarray, stamp: Any, frame_id: str) -> Any:
    ok, png = cv2.imencode(".png", image, [cv2.IMWRITE_PNG_COMPRESSION, 1])
    if not ok:
        raise ValueError(f"{frame_id}: PNG encoding failed")
    encoding = "mono8" if image.ndim == 2 else "bgr8"
    return b.CompressedImage(header=b.Header(stamp=stamp, frame_id=frame_id),
                             format=f"{encoding}; png compressed {encoding}", data=png.tobytes())


def _ns(stamp: Any) -> int:
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


def _stamp(ns: int) -> Any:
    return b.Time(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)


# A message to write: its topic (before the namespace), ROS time in ns, and the message.
Write = Callable[[str, int, Any], None]


class FixationWriter:
    """Writes each `FixationTrace` as its pairs then its record, through `write`; `stamp_of`
    gives the ROS time in ns of a monotonic time (None: now)."""

    def __init__(self, write: Write, stamp_of: Callable[[float | None], int], frames: dict[str, str],
                 prefix: str = "") -> None:
        self.write, self.stamp_of, self.frames, self.prefix = write, stamp_of, frames, prefix
        self._written: collections.OrderedDict[int, StereoShot] = collections.OrderedDict()  # stamp -> pair

    def config(self, text: str) -> None:
        self.write(CONFIG, self.stamp_of(None), b.String(data=text))

    def _pair(self, shot: StereoShot) -> int:
        """The pair's stamp (ns), writing it unless it was written already."""
        ns = self.stamp_of(shot.exposure_s)
        for stamp, seen in reversed(self._written.items()):
            if seen.exposure_s == shot.exposure_s and np.array_equal(seen.left, shot.left) \
                    and np.array_equal(seen.right, shot.right):
                return stamp
        while ns in self._written:
            ns += 1
        for side, image in (("left", shot.left), ("right", shot.right)):
            self.write(pair_topic(side), ns, _png(image, _stamp(ns), self.frames[side]))
        self._written[ns] = shot
        while len(self._written) > PAIRS_KEPT:
            self._written.popitem(last=False)
        return ns

    def trace(self, trace: FixationTrace) -> None:
        calls: list[JSON] = []
        for call, value in trace.calls:
            if call is Call.PAIR and isinstance(value, int):
                calls.append([str(call), self._pair(trace.pairs[value])])
            elif isinstance(value, Raised):
                calls.append([str(call), {"call": str(value.call), "error": value.error, "outcome": value.outcome,
                                          "detail": value.detail}])
            else:
                calls.append([str(call), plain(value, digits=None)])
        fields: JSONObject = {**plain(trace.record.as_dict(), digits=None), "taught": trace.record.taught,
                              "pose_low": plain(trace.pose_low, digits=None),
                              "pose_high": plain(trace.pose_high, digits=None), "calls": calls}
        fields["kind"], fields["outcome"] = str(trace.record.kind), str(trace.record.outcome)
        values = [b.KeyValue(key=k, value=v if isinstance(v, str) else json.dumps(v)) for k, v in fields.items()]
        status = b.DiagnosticStatus(level=0 if trace.record.taught else 1, name="fixation",
                                    message=f"{trace.record.outcome}: {trace.record.detail}".rstrip(": "),
                                    hardware_id=self.prefix + "headctl", values=values)
        self.write(FIXATIONS, self.stamp_of(None), status)


@dataclasses.dataclass
class RecordedFixation:
    """One recorded fixation: the record's fields (`fields`: JSON, as `FixationRecord.as_dict()`
    and `taught`), the head calls with each pair resolved (None: its images are not in the bag)."""

    fields: JSONObject
    calls: list[tuple[Call, Any]]
    pose_low: np.ndarray
    pose_high: np.ndarray
    missing_pairs: int = 0

    @property
    def index(self) -> int:
        value = self.fields.get("index")
        return value if isinstance(value, int) else -1

    @property
    def outcome(self) -> str:
        return str(self.fields.get("outcome", ""))

    @property
    def kind(self) -> str:
        return str(self.fields.get("kind", ""))

    def array(self, name: str) -> np.ndarray | None:
        value = self.fields.get(name)
        return None if value is None else np.asarray(value, dtype=float)


@dataclasses.dataclass
class BagMessage:
    topic: str
    msgtype: str
    log_time_ns: int
    data: bytes


def _image(msg: Any) -> np.ndarray:
    image = cv2.imdecode(np.frombuffer(bytes(msg.data), np.uint8), cv2.IMREAD_UNCHANGED)
    if image is None:
        raise ValueError(f"{msg.header.frame_id}: an image that does not decode ({msg.format})")
    return np.asarray(image)


def _call(name: str, value: Any, pairs: dict[int, StereoShot]) -> tuple[Call, Any]:
    call = Call(name)
    if call is Call.PAIR:
        return call, pairs.get(int(value))
    if call is Call.RAISE:
        return call, Raised(Call(value["call"]), str(value["error"]), str(value["outcome"]), str(value["detail"]))
    if call in (Call.POSE, Call.MOVE):
        return call, np.asarray(value, dtype=float)
    return call, float(value)


class FixationReader:
    """The fixations of a bag's messages, in order (`fixations(messages)`), and what else it
    found: the config recorded (`config`, YAML text or None), the topics seen. Topics are
    known by their names' ends, whatever `ros2.namespace` the bag was recorded under."""

    def __init__(self) -> None:
        self.config: str | None = None
        self.topics: collections.Counter[str] = collections.Counter()
        self._shots: dict[int, dict[str, np.ndarray]] = {}

    def fixations(self, messages: Iterable[BagMessage]) -> Iterator[RecordedFixation]:
        store = b.typestore()
        sides = {"/" + pair_topic(side): side for side in SIDES}
        for message in messages:
            topic = message.topic
            self.topics[topic] += 1
            side = next((s for end, s in sides.items() if topic.endswith(end)), None)
            msg: Any
            if side is not None:
                msg = store.deserialize_cdr(message.data, message.msgtype)
                self._shots.setdefault(_ns(msg.header.stamp), {})[side] = _image(msg)
            elif topic.endswith("/" + CONFIG) and self.config is None:
                msg = store.deserialize_cdr(message.data, message.msgtype)
                self.config = str(msg.data)
            elif topic.endswith("/" + FIXATIONS):
                msg = store.deserialize_cdr(message.data, message.msgtype)
                if msg.name == "fixation":
                    yield self._fixation(msg)

    def _fixation(self, msg: Any) -> RecordedFixation:
        fields: JSONObject = {}
        for kv in msg.values:
            try:
                fields[kv.key] = json.loads(kv.value)
            except ValueError:
                fields[kv.key] = kv.value
        raw = fields.pop("calls", None)
        recorded: list[Any] = raw if isinstance(raw, list) else []
        stamps = [int(value) for name, value in recorded if name == str(Call.PAIR)]
        pairs = {ns: StereoShot(s["left"], s["right"], None) for ns in stamps
                 if len(s := self._shots.get(ns, {})) == 2}
        calls = [_call(str(name), value, pairs) for name, value in recorded]
        # A pair stays while a later fixation may share it: the last fixation's are kept.
        self._shots = {ns: s for ns, s in self._shots.items() if ns not in pairs or ns == max(stamps, default=-1)}
        low, high = fields.pop("pose_low", None), fields.pop("pose_high", None)
        return RecordedFixation(fields, calls, np.asarray(low, dtype=float), np.asarray(high, dtype=float),
                                missing_pairs=len(set(stamps) - pairs.keys()))
