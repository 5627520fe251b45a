"""The command topics, each what its HTTP route does, and `/head/gaze_state`.

- `/head/look_at` (geometry_msgs/PointStamped): `POST /api/v1/look/target` with x, y a pixel of
  the left image and z its disparity in pixels (NaN: measured, as an HTTP look without d);
  `header.frame_id` '' or the left camera's optical frame.
- `/head/look_at_angles` (sensor_msgs/JointState): `POST /api/v1/look/angles` with the names
  `pan`, `tilt`, `vergence` and their positions in radians (ROS's unit; the service's degrees
  inside); `header.frame_id` `relative` makes them relative to the pose (a missing name: 0),
  else all three are needed.
- `/head/track` (geometry_msgs/PointStamped): `POST /api/v1/track` at pixel (x, y) (both NaN:
  what is on the fovea now); `header.frame_id` `stop` is `DELETE /api/v1/track`.

Every command goes through `HeadService` (`look`, `track`, `stop_track`), so it is checked
as the HTTP one is, against the image, the map's disparity range and the joint limits, and
refused with the same reason; nothing here moves a servo. `/head/gaze_state`
(diagnostic_msgs/DiagnosticStatus) carries, for every command, `look_queued` / `track_queued`
with its id, or `look_refused` / `track_refused` with the field and the reason, then the
service's own `look_*` and `track_*` events as the SSE stream gives them. With
`ros2.commands: false` the command topics are not subscribed to at all.
"""
from __future__ import annotations

import logging
import math
import threading
from collections.abc import Callable
from typing import Any

from cyclonedds.core import GuardCondition, InstanceState, ReadCondition, SampleState, ViewState, WaitSet
from cyclonedds.pub import DataWriter
from cyclonedds.sub import DataReader
from cyclonedds.util import duration

from headctl.errors import ControlError, InvalidRequestError
from headctl.json_types import JSON, JSONObject
from headctl.ros2 import convert
from headctl.ros2 import messages as m
from headctl.ros2.node import QosKind, Ros2Node, TopicSpec, delete
from headctl.service.control import HeadService
from headctl.service.events import Event, plain
from headctl.service.looks import LookJob, LookKind, LookRequest

log = logging.getLogger(__name__)

LOOK_AT = TopicSpec("head/look_at", m.PointStamped, QosKind.DEFAULT)
LOOK_AT_ANGLES = TopicSpec("head/look_at_angles", m.JointState, QosKind.DEFAULT)
TRACK = TopicSpec("head/track", m.PointStamped, QosKind.DEFAULT)
GAZE_STATE = TopicSpec("head/gaze_state", m.DiagnosticStatus, QosKind.DEFAULT)
COMMANDS = (LOOK_AT, LOOK_AT_ANGLES, TRACK)
ANGLES = ("pan", "tilt", "vergence")
WAKE_S = 0.25  # the command thread looks at its stop flag at least this often


class Refused(InvalidRequestError):
    """A command that cannot become a request (what the HTTP API's body checks refuse)."""


def _finite(name: str, value: float) -> float:
    if not math.isfinite(value):
        raise Refused(f"{name}: got {value}, expected a finite number", name)
    return value


def look_request(msg: m.PointStamped, left_frame: str) -> LookRequest:
    if msg.header.frame_id not in ("", left_frame):
        raise Refused(f"header.frame_id: got {msg.header.frame_id!r}, expected '' or {left_frame!r} "
                      "(x, y are a pixel of the left image)", "frame_id")
    x, y, z = _finite("x", msg.point.x), _finite("y", msg.point.y), msg.point.z
    d = None if math.isnan(z) else _finite("d", z)
    return LookRequest(LookKind.TARGET, (x, y, d))  # type: ignore[arg-type]  # d None: measured, as over HTTP


def angles_request(msg: m.JointState) -> LookRequest:
    relative = msg.header.frame_id == "relative"
    if msg.header.frame_id not in ("", "relative"):
        raise Refused(f"header.frame_id: got {msg.header.frame_id!r}, expected '' (absolute) or 'relative'",
                      "frame_id")
    if len(msg.position) != len(msg.name):
        raise Refused(f"position: {len(msg.position)} values for {len(msg.name)} names", "position")
    given: dict[str, float] = {}
    for name, value in zip(msg.name, msg.position):
        if name not in ANGLES:
            raise Refused(f"name: got {name!r}, expected pan, tilt or vergence", "name")
        if name in given:
            raise Refused(f"name: {name!r} twice", "name")
        given[name] = math.degrees(_finite(name, value))
    missing = [a for a in ANGLES if a not in given]
    if missing and not relative:
        raise Refused(f"{', '.join(missing)} missing: an absolute look needs pan, tilt and vergence "
                      "(or send header.frame_id 'relative', where a missing angle means 0)", missing[0])
    values = tuple(given.get(a, 0.0) for a in ANGLES)
    return LookRequest(LookKind.ANGLES, (values[0], values[1], values[2]), relative)


def track_target(msg: m.PointStamped) -> tuple[float | None, float | None] | None:
    """(x, y), (None, None) for the fovea, or None to stop the track."""
    if msg.header.frame_id == "stop":
        return None
    if msg.header.frame_id != "":
        raise Refused(f"header.frame_id: got {msg.header.frame_id!r}, expected '' (track) or 'stop'", "frame_id")
    x, y = msg.point.x, msg.point.y
    if math.isnan(x) and math.isnan(y):
        return None, None
    return _finite("x", x), _finite("y", y)


class GazeState:
    """Publishes on `/head/gaze_state` what the commands and the service's looks and tracks did."""

    def __init__(self, writer: DataWriter[m.DiagnosticStatus], prefix: str) -> None:
        self._writer = writer
        self._prefix = prefix
        self._lock = threading.Lock()

    def tell(self, event: Event | JSONObject) -> None:
        msg = convert.gaze_state(event, self._prefix)
        with self._lock:
            try:
                self._writer.write(msg)
            except Exception as err:  # a DDS error must not reach the event's publisher (the fixation thread)
                log.warning("ros2: /head/gaze_state: %s", err)

    def on_event(self, event: Event) -> None:
        if str(event.get("type", "")).startswith(convert.GAZE_EVENTS):
            self.tell(event)


def _job_event(kind: str, job: LookJob) -> JSONObject:
    request: JSON = plain(job.request.as_dict())
    return {"type": f"{kind}_queued", "id": job.id, "state": str(job.state), "request": request}


class CommandThread(threading.Thread):
    """`ros2-commands`: takes the command topics' samples and hands each to the service."""

    def __init__(self, node: Ros2Node, service: HeadService, gaze: GazeState, left_frame: str) -> None:
        super().__init__(name="ros2-commands", daemon=True)
        assert node.participant is not None
        self.service = service
        self.gaze = gaze
        self.left_frame = left_frame
        self.handled = 0
        self.error: BaseException | None = None
        self._stop_flag = threading.Event()
        handlers: list[tuple[TopicSpec[Any], Callable[[Any], None]]] = [
            (LOOK_AT, self._look_at), (LOOK_AT_ANGLES, self._look_at_angles), (TRACK, self._track)]
        self._readers: list[tuple[DataReader[Any], type[Any], Callable[[Any], None]]] = [
            (node.reader(spec), spec.type, handle) for spec, handle in handlers]
        self._waitset = WaitSet(node.participant)
        self._guard = GuardCondition(node.participant)
        self._conditions = [ReadCondition(r, SampleState.Any | ViewState.Any | InstanceState.Any)
                            for r, _, _ in self._readers]
        for entity in (*self._conditions, self._guard):
            self._waitset.attach(entity)

    def run(self) -> None:
        try:
            while not self._stop_flag.is_set():
                self._waitset.wait(duration(seconds=WAKE_S))
                for reader, kind, handle in self._readers:
                    for sample in reader.take(N=16):
                        if isinstance(sample, kind):  # not a writer's disposal or unregistration
                            self._handle(handle, sample)
        except BaseException as err:
            self.error = err
            log.exception("ros2: the command thread failed")

    def _handle(self, handle: Callable[[Any], None], sample: Any) -> None:
        self.handled += 1
        try:
            handle(sample)
        except ControlError as err:
            kind = "track" if handle == self._track else "look"
            log.info("ros2: %s refused: %s", kind, err)
            self.gaze.tell({"type": f"{kind}_refused", "state": "refused", "field": err.field,
                            "reason": str(err)})

    def _look_at(self, msg: m.PointStamped) -> None:
        job = self.service.look(look_request(msg, self.left_frame))
        self.gaze.tell(_job_event("look", job))

    def _look_at_angles(self, msg: m.JointState) -> None:
        job = self.service.look(angles_request(msg))
        self.gaze.tell(_job_event("look", job))

    def _track(self, msg: m.PointStamped) -> None:
        target = track_target(msg)
        job = self.service.stop_track() if target is None else self.service.track(*target)
        self.gaze.tell(_job_event("track", job) if target is not None else
                       {"type": "track_stop_requested", "id": job.id, "state": str(job.state)})

    def stop(self, timeout_s: float = 1.0) -> None:
        self._stop_flag.set()
        self._guard.set(True)
        if self.is_alive() and threading.current_thread() is not self:
            self.join(timeout_s)
        for entity in (*self._conditions, self._guard, self._waitset):
            delete(entity)
