"""The Foxglove WebSocket server of the view and the thread that feeds it (needs foxglove-sdk).

One `foxglove.Context` and its server (`foxglove.start_server`, the SDK's own implementation of
Foxglove's WebSocket protocol) per view, so that views in one process stay apart. One thread,
`foxglove-view`, looks every `poll_s` for what is new and publishes it on the channels a
client subscribes to (`has_sinks`): nothing is encoded while no one watches.

| topic | schema | what |
| --- | --- | --- |
| `/joint_states` | foxglove.JointStates | each new state of the servo loop, radians |
| `/tf` | foxglove.FrameTransforms | with each joint state: the joints' and the optical frames' transforms (`headctl.ros2.geometry`) |
| `/head/{left,right}/image` | foxglove.CompressedImage | each new frame, JPEG, stamped at its exposure |
| `/head/{left,right}/annotations` | foxglove.ImageAnnotations | with each frame: the fovea, the target, the last match |
| `/head/learning` | headctl.Learning (JSON) | each accepted adaptation (`headctl.foxglove.convert.LEARNING_SCHEMA`) |

A step's exception is logged and counted, never the end of the thread.
"""
from __future__ import annotations

import collections
import json
import logging
import threading
from collections.abc import Mapping, Sequence
from typing import Protocol

import foxglove
from foxglove.channels import CompressedImageChannel, FrameTransformsChannel, ImageAnnotationsChannel, \
    JointStatesChannel

from drivers.clock import Clock
from headctl.config.head import HeadConfig
from headctl.errors import HeadctlError
from headctl.foxglove import convert
from headctl.ros2.geometry import SIDES, FrameTree
from headctl.service.control import HeadService

log = logging.getLogger(__name__)

JOINT_STATES = "/joint_states"
TF = "/tf"
LEARNING = "/head/learning"
IMAGE_POLL_S = 0.003  # how often the newest frames are looked at (a 100 fps camera's third of a period)
LEARNING_POLL_S = 0.25
STATUS_MAX_AGE_S = 1.0  # the learning messages' taught count: from a status snapshot at most this old


class _Channel(Protocol):
    """What every channel of the SDK has, whatever it carries."""

    def topic(self) -> str: ...

    def schema_name(self) -> str | None: ...

    def has_sinks(self) -> bool: ...


def image_topic(side: str) -> str:
    return f"/head/{side}/image"


def annotations_topic(side: str) -> str:
    return f"/head/{side}/annotations"


class Publisher:
    """The server, its channels and the `foxglove-view` thread over one service."""

    def __init__(self, service: HeadService, config: HeadConfig, clock: Clock) -> None:
        self.service = service
        self.config = config.foxglove
        self.prefix = config.ros2.frame_prefix
        self.tree = FrameTree(config.ros2)
        self.clock = clock
        self.stamps = convert.Stamps(clock)
        self.poll_s = min(IMAGE_POLL_S, 0.5 / config.service.servo_rate_hz)
        self.published: collections.Counter[str] = collections.Counter()
        self.failures = 0
        self.context = foxglove.Context()
        cfg = self.config
        try:
            self.server = foxglove.start_server(name=f"headctl {config.path.stem}", host=cfg.host, port=cfg.port,
                                                context=self.context)
        except RuntimeError as err:
            raise HeadctlError(f"foxglove: cannot serve on {cfg.host}:{cfg.port} (foxglove.host, foxglove.port): "
                               f"{err}") from None
        ctx = self.context
        self._joints = JointStatesChannel(JOINT_STATES, context=ctx)
        self._tf = FrameTransformsChannel(TF, context=ctx)
        self._images = {side: CompressedImageChannel(image_topic(side), context=ctx) for side in SIDES}
        self._annotations = {side: ImageAnnotationsChannel(annotations_topic(side), context=ctx) for side in SIDES}
        schema = foxglove.Schema(name="headctl.Learning", encoding="jsonschema",
                                 data=json.dumps(convert.LEARNING_SCHEMA).encode())
        self._learning = foxglove.Channel(LEARNING, schema=schema, message_encoding="json", context=ctx)
        self._last_read_s: float | None = None
        self._last_frame: dict[str, int] = {}
        self._learning_next = self._next_point(service.learning_since(0, 0))
        self._learning_due_s = clock.monotonic()
        self._status: tuple[float, int | None, float | None] | None = None
        self._stop = threading.Event()
        self.thread = threading.Thread(target=self._run, name="foxglove-view", daemon=True)

    @property
    def port(self) -> int:
        return self.server.port

    def _channels(self) -> list[_Channel]:
        return [self._joints, self._tf, self._learning, *self._images.values(), *self._annotations.values()]

    def channels(self) -> dict[str, str]:
        """The schema name of each topic."""
        return {c.topic(): c.schema_name() or "" for c in self._channels()}

    def watched(self) -> set[str]:
        """The topics some client subscribes to."""
        return {c.topic() for c in self._channels() if c.has_sinks()}

    def start(self) -> None:
        self.thread.start()

    def stop(self, timeout_s: float = 1.0) -> None:
        self._stop.set()
        if self.thread.is_alive():
            self.thread.join(timeout_s)
        self.server.stop()

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                self.step()
            except Exception as err:
                self.failures += 1
                if self.failures % 100 == 1:
                    log.warning("foxglove: %s (%d failures)", err, self.failures)
            self._stop.wait(self.poll_s)

    def step(self) -> None:
        self.publish_joints()
        self.publish_images()
        if self.clock.monotonic() >= self._learning_due_s:
            self._learning_due_s = self.clock.monotonic() + LEARNING_POLL_S
            self.publish_learning()

    def publish_joints(self) -> None:
        state = self.service.joint_state()
        if state is None or state.time_s == self._last_read_s:
            return
        self._last_read_s = state.time_s
        ns = self.stamps.ns(state.time_s)
        if self._joints.has_sinks():
            self._joints.log(convert.joint_states(state, ns, self.prefix), log_time=ns)
            self.published[JOINT_STATES] += 1
        if self._tf.has_sinks() and not state.missing:  # the tree needs all four joints
            transforms = self.tree.moving(state.positions) + self.tree.static()
            self._tf.log(convert.frame_transforms(transforms, ns), log_time=ns)
            self.published[TF] += 1

    def publish_images(self) -> None:
        for side in SIDES:
            frame = self.service.latest_frame(side)
            if frame is None or self._last_frame.get(side) == frame.counter:
                continue
            self._last_frame[side] = frame.counter
            ns = self.stamps.ns(frame.time_s)
            images, notes = self._images[side], self._annotations[side]
            if images.has_sinks():
                images.log(convert.compressed_image(frame, ns, self.tree.optical[side], self.config.jpeg_quality),
                           log_time=ns)
                self.published[image_topic(side)] += 1
            if notes.has_sinks():
                height, width = frame.image.shape[:2]
                notes.log(convert.image_annotations(self._marks(side, (width, height)), ns), log_time=ns)
                self.published[annotations_topic(side)] += 1

    def _marks(self, side: str, size: tuple[int, int]) -> convert.Marks:
        """The tracked patch while a track runs, else the last fixation's target; its match."""
        track = self.service.tracking_now()
        last = self.service.last_fixation()
        target: Sequence[float] | None = track["position"] if track is not None else None
        if target is None and last is not None:
            chosen = last.target if last.target is not None else last.explore_target
            target = None if chosen is None else [float(v) for v in chosen]
        match = confidence = None
        if last is not None and last.match is not None:
            eye = last.match.left if side == "left" else last.match.right
            match, confidence = (eye.x, eye.y), last.confidence
        return convert.marks_of(size, side, target, match, confidence)

    def publish_learning(self) -> None:
        answer = self.service.learning_since(self._learning_next)
        self._learning_next = self._next_point(answer, self._learning_next)
        points = answer.get("points")
        if not isinstance(points, list) or not points or not self._learning.has_sinks():
            return
        taught, recent = self._taught()
        for point in points:
            if isinstance(point, dict):
                ns = int(round(float(point.get("t") or 0.0) * 1e9)) or None
                self._learning.log(convert.learning(point, taught, recent), log_time=ns)
                self.published[LEARNING] += 1

    def _taught(self) -> tuple[int | None, float | None]:
        now = self.clock.monotonic()
        if self._status is None or now - self._status[0] > STATUS_MAX_AGE_S:
            snap = self.service.snapshot()
            learning = snap.learning
            self._status = (now, snap.fixation.taught, None if learning is None else learning.recent_mean_retinal_error)
        return self._status[1], self._status[2]

    @staticmethod
    def _next_point(answer: Mapping[str, object], default: int = 0) -> int:
        value = answer.get("next")
        return value if isinstance(value, int) else default
