"""The published streams, each a named thread: joint states with the moving frames, the
eyes' images, the diagnostics.

- `ros2-joint-states`: each new state of the servo loop (looked for twice a servo period),
  at most `ros2.rates.joint_states_hz` a second (default the servo loop's rate):
  `/joint_states` stamped at the read, and `/tf`.
- `ros2-images`: each new frame of each eye (at most `ros2.rates.images_fps`):
  `image_raw`, `image_raw/compressed`, `camera_info`, stamped at the exposure. The service
  offers the newest frame; it is looked at every `IMAGE_POLL_S`.
- `ros2-diagnostics`: `/diagnostics` from the status snapshot at `ros2.rates.diagnostics_hz`.

What each publish costs after the data's own time is kept (`latencies_s`) for the figures.
A write that fails (a reader that lags a reliable writer past its blocking time) drops that
sample and is counted; it never stops the stream.
"""
from __future__ import annotations

import collections
import logging
import threading
from collections.abc import Callable
from typing import Any

from cyclonedds.pub import DataWriter

from drivers.clock import Clock
from headctl.config.ros2 import Ros2Config
from headctl.ros2 import convert
from headctl.ros2 import messages as m
from headctl.ros2.frames import SIDES, HeadFrames
from headctl.ros2.node import QosKind, Ros2Node, TopicSpec
from headctl.service.control import HeadService

log = logging.getLogger(__name__)

JOINT_STATES = TopicSpec("joint_states", m.JointState, QosKind.DEFAULT)
TF = TopicSpec("tf", m.TFMessage, QosKind.TF)
TF_STATIC = TopicSpec("tf_static", m.TFMessage, QosKind.TF_STATIC)
DIAGNOSTICS = TopicSpec("diagnostics", m.DiagnosticArray, QosKind.DEFAULT)
IMAGE_POLL_S = 0.003
LATENCIES_KEPT = 2000


def image_topics(side: str) -> tuple[TopicSpec[m.Image], TopicSpec[m.CompressedImage], TopicSpec[m.CameraInfo]]:
    base = f"head/{side}"
    return (TopicSpec(f"{base}/image_raw", m.Image, QosKind.SENSOR_DATA),
            TopicSpec(f"{base}/image_raw/compressed", m.CompressedImage, QosKind.SENSOR_DATA),
            TopicSpec(f"{base}/camera_info", m.CameraInfo, QosKind.SENSOR_DATA))


class Periodic(threading.Thread):
    """A named thread calling `step()` every `period_s` until `stop()`; a step's exception is
    logged and counted, never the end of the thread."""

    def __init__(self, name: str, period_s: float, step: Callable[[], None], clock: Clock) -> None:
        super().__init__(name=name, daemon=True)
        self.period_s = period_s
        self.step = step
        self.clock = clock
        self.failures = 0
        self.error: BaseException | None = None
        self._stop_flag = threading.Event()

    def run(self) -> None:
        next_s = self.clock.monotonic()
        while not self._stop_flag.is_set():
            try:
                self.step()
            except Exception as err:
                self.failures += 1
                if self.failures % 100 == 1:
                    log.warning("ros2: %s: %s (%d failures)", self.name, err, self.failures)
            next_s += self.period_s
            now = self.clock.monotonic()
            if next_s < now - self.period_s:  # fell behind (a stall): start afresh, no burst
                next_s = now
            self._stop_flag.wait(max(0.0, next_s - now))

    def stop(self, timeout_s: float = 1.0) -> None:
        self._stop_flag.set()
        if self.is_alive() and threading.current_thread() is not self:
            self.join(timeout_s)


class Streams:
    """The publishing threads of one node over one service."""

    def __init__(self, node: Ros2Node, service: HeadService, config: Ros2Config, servo_rate_hz: float,
                 clock: Clock) -> None:
        self.service = service
        self.config = config
        self.stamps = convert.Stamps(clock)
        self.frames = HeadFrames(config)
        self.clock = clock
        self.latencies_s: dict[str, collections.deque[float]] = {
            k: collections.deque(maxlen=LATENCIES_KEPT) for k in ("joint_states", "images", "images_seen")}
        self.published: collections.Counter[str] = collections.Counter()
        self._joint_states = node.writer(JOINT_STATES)
        self._tf = node.writer(TF)
        self._tf_static = node.writer(TF_STATIC)
        self._diagnostics = node.writer(DIAGNOSTICS)
        self._images: dict[str, tuple[DataWriter[Any] | None, DataWriter[Any] | None, DataWriter[Any]]] = {}
        for side in SIDES:
            raw, jpeg, info = image_topics(side)
            self._images[side] = (node.writer(raw) if config.images.raw else None,
                                  node.writer(jpeg) if config.images.compressed else None, node.writer(info))
        self._last_read_s: float | None = None
        self._last_frame: dict[str, tuple[int, float]] = {}
        self.joints_hz = config.rates.joint_states_hz or servo_rate_hz
        # Each new state, looked for twice a servo period (the loop's phase is not ours).
        poll_s = min(0.5 / servo_rate_hz, 1.0 / self.joints_hz)
        self.threads = [Periodic("ros2-joint-states", poll_s, self.publish_joints, clock),
                        Periodic("ros2-images", IMAGE_POLL_S, self.publish_images, clock),
                        Periodic("ros2-diagnostics", 1.0 / config.rates.diagnostics_hz, self.publish_diagnostics,
                                 clock)]

    def start(self) -> None:
        self._write(self._tf_static, self.frames.static(self.stamps.now()), "tf_static")
        for thread in self.threads:
            thread.start()

    def stop(self, timeout_s: float = 1.0) -> None:
        for thread in self.threads:
            thread.stop(timeout_s)

    def _write(self, writer: DataWriter[Any], msg: Any, what: str, stamp: m.Time | None = None) -> None:
        ns = None if stamp is None else stamp.sec * 1_000_000_000 + stamp.nanosec
        writer.write(msg, timestamp=ns)
        self.published[what] += 1

    def publish_joints(self) -> None:
        state = self.service.joint_state()
        if state is None or not convert.due(state.time_s, self._last_read_s, self.joints_hz):
            return
        self._last_read_s = state.time_s
        stamp = self.stamps.of(state.time_s)
        self._write(self._joint_states, convert.joint_state(state, stamp, self.config.frame_prefix), "joint_states",
                    stamp)
        self.latencies_s["joint_states"].append(self.clock.monotonic() - state.time_s)
        self._write(self._tf, self.frames.moving(state.positions, stamp), "tf", stamp)

    def publish_images(self) -> None:
        fps = self.config.rates.images_fps
        for side in SIDES:
            frame = self.service.latest_frame(side)
            if frame is None:
                continue
            last = self._last_frame.get(side)
            if last is not None and (frame.counter == last[0] or
                                     (fps is not None and frame.time_s - last[1] < 0.9 / fps)):
                continue
            self._last_frame[side] = (frame.counter, frame.time_s)
            seen_s = self.clock.monotonic()
            stamp = self.stamps.of(frame.time_s)
            frame_id = self.frames.optical[side]
            raw, jpeg, info = self._images[side]
            if raw is not None:
                self._write(raw, convert.image(frame, stamp, frame_id), f"{side}/image_raw", stamp)
            if jpeg is not None:
                self._write(jpeg, convert.compressed(frame, stamp, frame_id, self.config.images.jpeg_quality),
                            f"{side}/image_raw/compressed", stamp)
            height, width = frame.image.shape[:2]
            self._write(info, convert.camera_info(width, height, stamp, frame_id), f"{side}/camera_info", stamp)
            done_s = self.clock.monotonic()
            self.latencies_s["images"].append(done_s - frame.time_s)
            self.latencies_s["images_seen"].append(done_s - seen_s)

    def publish_diagnostics(self) -> None:
        self._write(self._diagnostics, convert.diagnostics(self.service.snapshot(), self.stamps.now(),
                                                           self.config.frame_prefix), "diagnostics")

    @property
    def failures(self) -> int:
        return sum(t.failures for t in self.threads)
