"""The service's data as ROS 2 messages: joint states, images, camera info, diagnostics, gaze state.

Units as ROS wants them (REP 103): radians and radians a second; stamps are ROS time (the
wall clock), converted from the service's monotonic times by `Stamps`. The servos report no
load, so `effort` is empty (JointState allows each array to be empty).
"""
from __future__ import annotations

import json
import math
import time
from collections.abc import Mapping

import cv2
import numpy as np

from drivers.cameras.camera import Frame
from drivers.clock import Clock
from drivers.servo.bus import BusState
from headctl.json_types import JSON
try:
    from headctl.ros2 import messages as m
except ImportError:  # no cyclonedds: the same messages from rosbags' typestore (a recording needs no DDS)
    from headctl.ros2 import bagtypes as m  # type: ignore[no-redef]
from headctl.service.status import StatusSnapshot

GAZE_EVENTS = ("look_", "track_")  # the event types /head/gaze_state carries (the SSE events' own)


class Stamps:
    """ROS times of the service clock's monotonic times: the wall clock's offset read at each
    conversion, so a step of the wall clock moves the stamps with it, as ROS time does."""

    def __init__(self, clock: Clock) -> None:
        self.clock = clock

    def of(self, monotonic_s: float) -> m.Time:
        return m.Time.of_seconds(time.time() - self.clock.monotonic() + monotonic_s)

    def now(self) -> m.Time:
        return m.Time.of_seconds(time.time())


def joint_state(state: BusState, stamp: m.Time, prefix: str = "") -> m.JointState:
    names = list(state.joints)
    return m.JointState(header=m.Header(stamp=stamp, frame_id=""), name=[prefix + n for n in names],
                        position=[math.radians(state.joints[n].position) for n in names],
                        velocity=[math.radians(state.joints[n].velocity) for n in names], effort=[])


def encoding_of(image: np.ndarray) -> tuple[str, int]:
    """The ROS encoding of an OpenCV image and its bytes per pixel."""
    depth = {np.dtype(np.uint8): 8, np.dtype(np.uint16): 16}.get(image.dtype)
    if depth is None:
        raise ValueError(f"images of {image.dtype} have no ROS encoding here (uint8 or uint16)")
    if image.ndim == 2:
        return f"mono{depth}", depth // 8
    channels = image.shape[2]
    if channels == 3:
        return ("bgr8" if depth == 8 else "bgr16"), 3 * depth // 8
    raise ValueError(f"images of {channels} channels have no ROS encoding here (1 or 3)")


def image(frame: Frame, stamp: m.Time, frame_id: str) -> m.Image:
    img = np.ascontiguousarray(frame.image)
    encoding, bpp = encoding_of(img)
    height, width = img.shape[:2]
    return m.Image(header=m.Header(stamp=stamp, frame_id=frame_id), height=height, width=width,
                   encoding=encoding, is_bigendian=0, step=width * bpp, data=img.tobytes())


def compressed(frame: Frame, stamp: m.Time, frame_id: str, quality: int) -> m.CompressedImage:
    ok, jpeg = cv2.imencode(".jpg", frame.image, [cv2.IMWRITE_JPEG_QUALITY, quality])
    if not ok:
        raise ValueError(f"camera {frame.camera}: JPEG encoding failed")
    encoding, _ = encoding_of(frame.image)
    return m.CompressedImage(header=m.Header(stamp=stamp, frame_id=frame_id),
                             format=f"{encoding}; jpeg compressed {encoding}", data=jpeg.tobytes())


def camera_info(width: int, height: int, stamp: m.Time, frame_id: str) -> m.CameraInfo:
    """An uncalibrated camera (K all zero, as ROS marks one), its size and frame."""
    return m.CameraInfo(header=m.Header(stamp=stamp, frame_id=frame_id), height=height, width=width)


def _text(value: JSON) -> str:
    return value if isinstance(value, str) else json.dumps(value, separators=(",", ":"))


def _values(fields: Mapping[str, JSON]) -> list[m.KeyValue]:
    return [m.KeyValue(key=k, value=_text(v)) for k, v in fields.items()]


def diagnostics(snap: StatusSnapshot, stamp: m.Time, prefix: str = "") -> m.DiagnosticArray:
    """Servos, the servo loop, the cameras, the map and the faults, one status each."""
    hw = prefix + "headctl"
    status: list[m.DiagnosticStatus] = []
    for joint, js in snap.joints.items():
        level = m.Level.ERROR if js.hardware_errors else m.Level.OK
        status.append(m.DiagnosticStatus(
            level=level, name=f"headctl: servo {joint}", hardware_id=f"{hw}/{joint}",
            message=", ".join(js.hardware_errors) or "ok",
            values=_values({"position_deg": js.position_deg, "temperature_c": js.temperature_c,
                            "input_voltage_v": js.input_voltage_v, "torque_on": js.torque_on,
                            "hardware_errors": list(js.hardware_errors)})))
    if not snap.joints:
        status.append(m.DiagnosticStatus(level=m.Level.STALE, name="headctl: servos", hardware_id=hw,
                                         message="no servo state read yet"))
    loop = snap.servo_loop or {}
    status.append(m.DiagnosticStatus(
        level=m.Level.ERROR if snap.bus_down else (m.Level.OK if snap.servo_loop is not None else m.Level.STALE),
        name="headctl: servo loop", hardware_id=hw,
        message="bus down" if snap.bus_down else ("running" if snap.servo_loop is not None else "not running"),
        values=_values({**loop, "torque": snap.torque})))
    for side, cam in snap.cameras.items():
        status.append(m.DiagnosticStatus(
            level=m.Level.OK if cam.health == "streaming" else m.Level.WARN, name=f"headctl: camera {side}",
            hardware_id=f"{hw}/{cam.name}", message=cam.last_error or cam.health,
            values=_values({"health": cam.health, "frame_age_s": cam.frame_age_s, "restarts": cam.restarts,
                            **{k: v for k, v in cam.stats.items()}})))
    learning = snap.learning
    status.append(m.DiagnosticStatus(
        level=m.Level.WARN if snap.map.problems else m.Level.OK, name="headctl: gaze map", hardware_id=hw,
        message="; ".join(snap.map.problems) or f"restored from {snap.map.restored_from}",
        values=_values({"path": snap.map.path, "adaptations": learning.adaptations if learning else None,
                        "mean_retinal_error": learning.mean_retinal_error if learning else None,
                        "checkpoints": snap.map.checkpoints})))
    status.append(m.DiagnosticStatus(
        level=m.Level.ERROR if snap.faults else m.Level.OK, name="headctl: faults", hardware_id=hw,
        message="; ".join(snap.faults.values()) or f"none ({snap.state})",
        values=_values(dict(snap.faults))))
    return m.DiagnosticArray(header=m.Header(stamp=stamp, frame_id=""), status=status)


def gaze_state(event: Mapping[str, JSON], prefix: str = "") -> m.DiagnosticStatus:
    """A look's or track's event (as the SSE stream gives it) as a DiagnosticStatus: `name` the
    event's type, `message` its outcome or detail, `level` ERROR for a refusal or a failure,
    WARN for a cancel or a lost track, every field a KeyValue (JSON for what is not a string)."""
    kind = str(event.get("type", ""))
    state, outcome = str(event.get("state", "")), str(event.get("outcome", ""))
    if kind.endswith("_refused") or state == "failed":
        level = m.Level.ERROR
    elif state == "cancelled" or kind == "track_lost":
        level = m.Level.WARN
    else:
        level = m.Level.OK
    detail = str(event.get("detail") or event.get("reason") or "")
    message = ": ".join(p for p in (outcome, detail) if p) or state or kind
    return m.DiagnosticStatus(level=level, name=kind, message=message, hardware_id=prefix + "headctl",
                              values=_values(event))


def due(time_s: float, last_s: float | None, rate_hz: float) -> bool:
    """Whether a joint state read at `time_s` is one to send at `rate_hz`, the last sent read
    at `last_s`: a new read, at least 0.9 of a period after it."""
    return time_s != last_s and (last_s is None or time_s - last_s >= 0.9 / rate_hz)
