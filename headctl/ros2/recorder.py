"""Recordings of the running service as rosbag2 bags (`headctl record`, `/api/v1/record`).

`Recordings` starts and stops one `Recording` at a time; a `Recording` is a named thread
(`ros2-record`) that reads the service through `HeadService` as the ROS 2 streams do (the
servo loop's latest state, the cameras' newest frames, the status snapshot, the event hub)
and writes the same messages (`convert`, `frames`) to a `SplitBag`: `/joint_states` and
`/tf` at `ros2.rates.joint_states_hz` (default the servo rate), `/tf_static` at the start of
each file, each eye's `image_raw/compressed` and `camera_info` at each new frame,
`/diagnostics`, `/head/gaze_state` (looks and tracks) and `/head/events` (every other event:
fixations, saccades, the map's saves and resets, faults; and each new point of the learning
curve as a `learning` event), each a `diagnostic_msgs/DiagnosticStatus` named by the event's
type with its fields as KeyValues; and what a replay of the fixations needs (`fixation_log`:
each fixation's stereo pairs as PNG, its record and head calls, the config it ran with). It
needs no DDS: without `cyclonedds` the messages are `bagtypes`'. The event hub's and the
fixation traces' subscribers only append to bounded deques, so the fixation thread never
waits for the disk; a recording that cannot write as fast as they arrive still ends on time
(what it had queued is written for at most `FLUSH_S` more), and its status counts what it
dropped (`events_dropped`, `fixations_dropped`). A write that fails (ENOSPC, EDQUOT, any
`OSError`) ends the recording as `failed` with the reason in its status, a `recording_failed`
event and the service's `recording` fault, which the next recording that starts clears; the
service runs on.
"""
from __future__ import annotations

import collections
import enum
import logging
import threading
import time
from pathlib import Path
from typing import Any

from drivers.clock import SYSTEM_CLOCK, Clock
from headctl.config.head import HeadConfig
from headctl.errors import ControlError, InvalidRequestError
from headctl.json_types import JSONObject
from headctl.ros2 import bagtypes, convert
from headctl.ros2.bag import BagTopic, SplitBag, WriterFactory, mcap_writer, qos
from headctl.ros2.fixation_log import FixationWriter, fixation_topics, replay_config
from headctl.ros2.frames import SIDES, HeadFrames
from headctl.service.control import HeadService
from headctl.service.events import Event
from headctl.service.fixation_trace import FixationTrace

log = logging.getLogger(__name__)

POLL_S = 0.003
EVENTS_KEPT = 10000
FLUSH_S = 0.5  # the longest a recording writes what was still queued when it ended
TRACES_KEPT = 32  # fixations waiting for the disk (each holds its pairs: about 0.6 MB at 320 x 240)
FAULT = "recording"  # the service's fault while the last recording failed
DIAGNOSTIC_STATUS = "diagnostic_msgs/msg/DiagnosticStatus"


class RecordState(enum.StrEnum):
    RECORDING = "recording"
    STOPPED = "stopped"
    FAILED = "failed"


def cdr(msg: Any) -> bytes:
    """A message's CDR bytes, whether Cyclone DDS's (`messages`) or rosbags' (`bagtypes`)."""
    return bagtypes.serialize(msg) if hasattr(msg, "__msgtype__") else bytes(msg.serialize())


def bag_topics(config: HeadConfig) -> list[BagTopic]:
    t = config.ros2.topic
    sensor = qos(reliable=False, depth=config.ros2.qos.images_depth)
    topics = [BagTopic(t("joint_states"), "sensor_msgs/msg/JointState"),
              BagTopic(t("tf"), "tf2_msgs/msg/TFMessage", qos(depth=config.ros2.qos.tf_depth)),
              BagTopic(t("tf_static"), "tf2_msgs/msg/TFMessage", qos(transient_local=True, depth=1)),
              BagTopic(t("diagnostics"), "diagnostic_msgs/msg/DiagnosticArray"),
              BagTopic(t("head/gaze_state"), DIAGNOSTIC_STATUS),
              BagTopic(t("head/events"), DIAGNOSTIC_STATUS, qos(depth=100))]
    for side in SIDES:
        topics += [BagTopic(t(f"head/{side}/image_raw/compressed"), "sensor_msgs/msg/CompressedImage", sensor),
                   BagTopic(t(f"head/{side}/camera_info"), "sensor_msgs/msg/CameraInfo", sensor)]
    return topics + fixation_topics(t)


def _int(value: object, default: int = 0) -> int:
    return value if isinstance(value, int) else default


class Recording(threading.Thread):
    """One bag being written; see the module docstring. `stop(timeout_s)` closes the bag."""

    def __init__(self, service: HeadService, config: HeadConfig, bag: SplitBag, clock: Clock,
                 seconds: float | None = None) -> None:
        super().__init__(name="ros2-record", daemon=True)
        self.service, self.bag, self.clock = service, bag, clock
        self.ros2 = config.ros2
        self.topic = config.ros2.topic
        self.frames = HeadFrames(config.ros2)
        self.stamps = convert.Stamps(clock)
        self.joints_hz = config.ros2.rates.joint_states_hz or config.service.servo_rate_hz
        self.diagnostics_s = 1.0 / config.ros2.rates.diagnostics_hz
        self.started_s = clock.monotonic()
        self.until_s = None if seconds is None else self.started_s + seconds
        self.state = RecordState.RECORDING
        self.error: str | None = None
        self.counts: collections.Counter[str] = collections.Counter()
        self.events_dropped = 0
        self.fixations_dropped = 0
        self.cpu_s = 0.0  # this thread's CPU time, once it has ended
        self._events: collections.deque[tuple[Any, Event]] = collections.deque(maxlen=EVENTS_KEPT)
        self._stop_flag = threading.Event()
        self._last_read_s: float | None = None
        self._last_frame: dict[str, int] = {}
        self._next_diagnostics_s = self.started_s
        self._learning_next = _int(service.learning_since(0, 0).get("next"))
        self._traces: collections.deque[FixationTrace] = collections.deque(maxlen=TRACES_KEPT)
        self._config_text = replay_config(config)
        self.fixations = FixationWriter(self._write_ns, self._stamp_ns, self.frames.optical, config.ros2.frame_prefix)
        self._unsubscribe = service.events.subscribe(self._on_event)
        self._unsubscribe_fixations = service.subscribe_fixations(self._on_fixation)
        bag.on_new_file = self._write_static

    def _on_event(self, event: Event) -> None:  # on the publisher's thread: never blocks
        if len(self._events) == EVENTS_KEPT:
            self.events_dropped += 1
        self._events.append((self.stamps.now(), event))

    def _on_fixation(self, trace: FixationTrace) -> None:  # on the fixation thread: never blocks
        if len(self._traces) == TRACES_KEPT:
            self.fixations_dropped += 1
        self._traces.append(trace)

    def _stamp_ns(self, monotonic_s: float | None) -> int:
        stamp = self.stamps.now() if monotonic_s is None else self.stamps.of(monotonic_s)
        return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)

    def _write_ns(self, name: str, stamp_ns: int, msg: Any) -> None:
        self.bag.write(self.topic(name), stamp_ns, cdr(msg))
        self.counts[name] += 1

    def _write(self, name: str, msg: Any, stamp: Any) -> None:
        self._write_ns(name, stamp.sec * 1_000_000_000 + stamp.nanosec, msg)

    def _write_static(self) -> None:
        stamp = self.stamps.now()
        self._write("tf_static", self.frames.static(stamp), stamp)
        self.fixations.config(self._config_text)

    def run(self) -> None:
        cpu0_s = time.thread_time()
        try:
            while not self._stop_flag.is_set():
                self.step(self.until_s)
                if self.until_s is not None and self.clock.monotonic() >= self.until_s:
                    break
                self._stop_flag.wait(POLL_S)
            self.step(self.clock.monotonic() + FLUSH_S)
            self.events_dropped += len(self._events)
            self.fixations_dropped += len(self._traces)
            self.bag.close()
            self.state = RecordState.STOPPED
        except OSError as err:  # ENOSPC, EDQUOT, a vanished disk: the recording ends, never the service
            self.bag.abort()
            self.state, self.error = RecordState.FAILED, f"{self.bag.path}: {err.strerror or err}"
            log.error("record: stopped: %s", self.error)
            self.service.report_fault(FAULT, f"recording failed: {self.error}")
            self.service.events.publish("recording_failed", path=str(self.bag.path), reason=self.error)
        finally:
            self._unsubscribe()
            self._unsubscribe_fixations()
            self.cpu_s = time.thread_time() - cpu0_s
        log.info("record: %s: %s, %d messages", self.bag.path, self.state, sum(self.counts.values()))

    def step(self, until_s: float | None = None) -> None:
        self._joints()
        self._images()
        now = self.clock.monotonic()
        if now >= self._next_diagnostics_s:
            self._next_diagnostics_s = now + self.diagnostics_s
            stamp = self.stamps.now()
            self._write("diagnostics", convert.diagnostics(self.service.snapshot(), stamp, self.ros2.frame_prefix),
                        stamp)
            self._learning(stamp)
        self._drain(until_s)

    def _drain(self, until_s: float | None) -> None:
        """Write what was queued when the drain began, until `until_s` at the latest: events
        that arrive faster than they are written must not keep the recording from its end."""
        for _ in range(len(self._events)):
            if until_s is not None and self.clock.monotonic() >= until_s:
                return
            stamp, event = self._events.popleft()
            gaze = str(event.get("type", "")).startswith(convert.GAZE_EVENTS)
            self._write("head/gaze_state" if gaze else "head/events",
                        convert.gaze_state(event, self.ros2.frame_prefix), stamp)
        for _ in range(len(self._traces)):
            if until_s is not None and self.clock.monotonic() >= until_s:
                return
            self.fixations.trace(self._traces.popleft())

    def _learning(self, stamp: Any) -> None:
        """The learning curve's new points, each a `learning` event on `/head/events`."""
        answer = self.service.learning_since(self._learning_next)
        points = answer.get("points")
        for point in points if isinstance(points, list) else []:
            if isinstance(point, dict):
                self._write("head/events", convert.gaze_state({"type": "learning", **point}, self.ros2.frame_prefix),
                            stamp)
        self._learning_next = _int(answer.get("next"), self._learning_next)

    def _joints(self) -> None:
        state = self.service.joint_state()
        if state is None or not convert.due(state.time_s, self._last_read_s, self.joints_hz):
            return
        self._last_read_s = state.time_s
        stamp = self.stamps.of(state.time_s)
        self._write("joint_states", convert.joint_state(state, stamp, self.ros2.frame_prefix), stamp)
        self._write("tf", self.frames.moving(state.positions, stamp), stamp)

    def _images(self) -> None:
        for side in SIDES:
            frame = self.service.latest_frame(side)
            if frame is None or self._last_frame.get(side) == frame.counter:
                continue
            self._last_frame[side] = frame.counter
            stamp = self.stamps.of(frame.time_s)
            frame_id = self.frames.optical[side]
            self._write(f"head/{side}/image_raw/compressed",
                        convert.compressed(frame, stamp, frame_id, self.ros2.images.jpeg_quality), stamp)
            height, width = frame.image.shape[:2]
            self._write(f"head/{side}/camera_info", convert.camera_info(width, height, stamp, frame_id), stamp)

    def stop(self, timeout_s: float = 5.0) -> None:
        self._stop_flag.set()
        if self.is_alive() and threading.current_thread() is not self:
            self.join(timeout_s)

    def status(self) -> JSONObject:
        return {"state": str(self.state), "path": str(self.bag.path), "error": self.error,
                "files": [p for f in self.bag.files for p in f["relative_file_paths"]],
                "file_index": self.bag.file_index, "bytes": self.bag.bytes_written,
                "duration_s": round(self.clock.monotonic() - self.started_s, 3),
                "messages": dict(self.counts), "events_dropped": self.events_dropped,
                "fixations_dropped": self.fixations_dropped,
                "cpu_s": round(self.cpu_s, 3)}


class Recordings:
    """The service's recordings, one at a time: `start`, `stop`, `status`; a context manager
    whose exit stops the one running."""

    def __init__(self, service: HeadService, config: HeadConfig, clock: Clock = SYSTEM_CLOCK,
                 writer: WriterFactory = mcap_writer) -> None:
        self.service, self.config, self.clock, self.writer = service, config, clock, writer
        self.settings = config.ros2.recording
        self.current: Recording | None = None
        self._lock = threading.Lock()

    def default_directory(self) -> Path:
        return Path(self.settings.directory).expanduser() if self.settings.directory else \
            self.config.state_dir / "recordings"

    def start(self, directory: str | None = None, seconds: float | None = None) -> JSONObject:
        """Start a bag in `directory` (an existing directory, absolute; default
        `ros2.recording.directory`, made if missing)."""
        if seconds is not None and not 0 < seconds <= self.settings.max_seconds:
            raise InvalidRequestError(f"seconds: got {seconds}, expected (0, {self.settings.max_seconds:g}] "
                                      "(ros2.recording.max_seconds)", "seconds")
        parent = Path(directory) if directory else self.default_directory()
        if directory and not (parent.is_absolute() and parent.is_dir()):
            raise InvalidRequestError(f"directory: got {directory!r}, expected the absolute path of an existing "
                                      "directory", "directory")
        with self._lock:
            if self.current is not None and self.current.is_alive():
                raise ControlError(f"already recording to {self.current.bag.path}: stop it first")
            path = parent / time.strftime("headctl_%Y%m%d_%H%M%S")
            n = 1
            while path.exists():
                path, n = parent / f"{time.strftime('headctl_%Y%m%d_%H%M%S')}_{n}", n + 1
            try:
                parent.mkdir(parents=True, exist_ok=True)
                bag = SplitBag(path, bag_topics(self.config), int(self.settings.max_bag_size_mb * 1e6),
                               int(self.settings.max_bag_duration_s * 1e9), self.writer)
            except OSError as err:
                raise InvalidRequestError(f"directory: {parent}: {err.strerror or err}", "directory") from err
            self.current = Recording(self.service, self.config, bag, self.clock, seconds)
            self.current.start()
            self.service.report_fault(FAULT, None)  # a recording that failed before is over
            log.info("record: recording to %s", path)
            return self.current.status()

    def stop(self, timeout_s: float = 5.0) -> JSONObject:
        with self._lock:
            current = self.current
            if current is None or not current.is_alive():
                raise ControlError("not recording" + (f" (the last: {current.bag.path}, {current.state})"
                                                      if current is not None else ""))
            current.stop(timeout_s)
            return current.status()

    def status(self) -> JSONObject:
        current = self.current
        return {"state": "idle"} if current is None else current.status()

    def __enter__(self) -> "Recordings":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        current = self.current
        if current is not None:
            current.stop()
