"""The service's data as Foxglove messages (the `foxglove` schemas of foxglove-sdk).

Units as Foxglove's schemas want them: radians and radians a second for joints, metres for
transforms, nanoseconds of the wall clock for times (`Stamps` converts the service's monotonic
times). Image annotations are in the image's pixels with the origin at the top-left corner of
the top-left pixel, as the ImageAnnotations schema defines them; the service's pixel
coordinates have their origin at the top-left pixel's centre (OpenCV's), hence `PIXEL_CENTRE`.
"""
from __future__ import annotations

import math
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import cv2
from foxglove.messages import (CircleAnnotation, Color, CompressedImage, FrameTransform, FrameTransforms,
                               ImageAnnotations, JointState, JointStates, Point2, PointsAnnotation,
                               PointsAnnotationType, Quaternion, TextAnnotation, Timestamp, Vector3)

from drivers.cameras.camera import Frame
from drivers.clock import Clock
from drivers.servo.bus import BusState
from headctl.json_types import JSONObject
from headctl.ros2.geometry import Transform

PIXEL_CENTRE = 0.5  # service pixel (x, y) -> Foxglove image coordinates (x + 0.5, y + 0.5)
FOVEA = Color(r=0.0, g=1.0, b=0.0, a=1.0)  # green, as the dashboard's cross
TARGET = Color(r=1.0, g=0.0, b=1.0, a=1.0)  # magenta, as the dashboard's tracked patch
MATCH = Color(r=1.0, g=0.86, b=0.0, a=1.0)  # yellow, as the dashboard's last correspondence
TEXT_BACKGROUND = Color(r=0.0, g=0.0, b=0.0, a=0.5)
OUTPUT_AXES = ("pan", "tilt", "vergence")


class Stamps:
    """Wall-clock times of the service clock's monotonic times: the offset read at each
    conversion, so a step of the wall clock moves the stamps with it."""

    def __init__(self, clock: Clock) -> None:
        self.clock = clock

    def ns(self, monotonic_s: float) -> int:
        return int(round((time.time() - self.clock.monotonic() + monotonic_s) * 1e9))


def timestamp(ns: int) -> Timestamp:
    return Timestamp(ns // 1_000_000_000, ns % 1_000_000_000)


def joint_states(state: BusState, ns: int, prefix: str = "") -> JointStates:
    return JointStates(timestamp=timestamp(ns), joints=[
        JointState(name=prefix + name, position=math.radians(j.position), velocity=math.radians(j.velocity))
        for name, j in state.joints.items()])


def frame_transforms(transforms: Sequence[Transform], ns: int) -> FrameTransforms:
    stamp = timestamp(ns)
    return FrameTransforms(transforms=[
        FrameTransform(timestamp=stamp, parent_frame_id=t.parent, child_frame_id=t.child,
                       translation=Vector3(x=t.translation_m[0], y=t.translation_m[1], z=t.translation_m[2]),
                       rotation=Quaternion(x=t.rotation[0], y=t.rotation[1], z=t.rotation[2], w=t.rotation[3]))
        for t in transforms])


def compressed_image(frame: Frame, ns: int, frame_id: str, quality: int) -> CompressedImage:
    """The frame as a JPEG (`format` "jpeg", as the CompressedImage schema names it)."""
    ok, data = cv2.imencode(".jpg", frame.image, [cv2.IMWRITE_JPEG_QUALITY, quality])
    if not ok:
        raise ValueError(f"{frame.camera}: frame {frame.counter} could not be encoded as JPEG")
    return CompressedImage(timestamp=timestamp(ns), frame_id=frame_id, data=data.tobytes(), format="jpeg")


@dataclass(frozen=True)
class Marks:
    """What one eye's image is annotated with, in the service's pixels: the fovea (the image's
    centre), the target of the track or of the last fixation, the last fixation's match and
    its confidence."""

    size: tuple[int, int]  # (width, height)
    target: tuple[float, float] | None = None
    match: tuple[float, float] | None = None
    confidence: float | None = None


def _point(x: float, y: float) -> Point2:
    return Point2(x=x + PIXEL_CENTRE, y=y + PIXEL_CENTRE)


def image_annotations(marks: Marks, ns: int) -> ImageAnnotations:
    """The fovea as a cross in a circle, the target as a circle with a dot, the match as a circle
    labelled with its confidence."""
    stamp = timestamp(ns)
    width, height = marks.size
    arm = max(6.0, width / 40)  # the dashboard's marker size
    cx, cy = (width - 1) / 2, (height - 1) / 2
    circles = [CircleAnnotation(timestamp=stamp, position=_point(cx, cy), diameter=2 * arm, thickness=1.0,
                                outline_color=FOVEA)]
    points = [PointsAnnotation(timestamp=stamp, type=PointsAnnotationType.LineList, thickness=2.0,
                               outline_color=FOVEA, points=[_point(cx - arm, cy), _point(cx + arm, cy),
                                                            _point(cx, cy - arm), _point(cx, cy + arm)])]
    texts = []
    if marks.target is not None:
        circles.append(CircleAnnotation(timestamp=stamp, position=_point(*marks.target), diameter=1.5 * arm,
                                        thickness=2.0, outline_color=TARGET))
        points.append(PointsAnnotation(timestamp=stamp, type=PointsAnnotationType.Points, thickness=4.0,
                                       outline_color=TARGET, points=[_point(*marks.target)]))
    if marks.match is not None:
        circles.append(CircleAnnotation(timestamp=stamp, position=_point(*marks.match), diameter=2 * arm,
                                        thickness=1.0, outline_color=MATCH))
        if marks.confidence is not None:
            mx, my = marks.match
            texts.append(TextAnnotation(timestamp=stamp, position=_point(mx + arm + 2, my + 4),
                                        text=f"c={marks.confidence:.2f}", font_size=10.0, text_color=MATCH,
                                        background_color=TEXT_BACKGROUND))
    return ImageAnnotations(circles=circles, points=points, texts=texts)


def _number(value: object) -> float | None:
    return float(value) if isinstance(value, (int, float)) and math.isfinite(value) else None


def learning(point: Mapping[str, object], taught: int | None, recent_mean_retinal_error: float | None) -> JSONObject:
    """One point of the learning curve as the `/head/learning` JSON (`LEARNING_SCHEMA`)."""
    out_err = point.get("output_error_deg")
    errors = list(out_err) if isinstance(out_err, (list, tuple)) else []
    return {"n": point.get("n"), "adaptations": point.get("adaptations"),
            "retinal_error": _number(point.get("retinal_error")), "confidence": _number(point.get("confidence")),
            "output_error_deg": {axis: _number(errors[i]) if i < len(errors) else None
                                 for i, axis in enumerate(OUTPUT_AXES)},
            "taught": taught, "recent_mean_retinal_error": recent_mean_retinal_error}


_NUMBER_OR_NULL = {"type": ["number", "null"]}
LEARNING_SCHEMA: JSONObject = {
    "title": "headctl.Learning",
    "description": "One accepted adaptation of the gaze map (docs/foxglove.md)",
    "type": "object",
    "properties": {
        "n": {"type": "integer", "description": "the point's index in this run's learning log"},
        "adaptations": {"type": "integer", "description": "the map's adaptations so far"},
        "retinal_error": {**_NUMBER_OR_NULL, "description": "the adaptation's retinal error (eq. 9), a fraction"},
        "confidence": {**_NUMBER_OR_NULL, "description": "the taught sample's confidence (eq. 7), 0 to 1"},
        "output_error_deg": {"type": "object", "description": "the map's output error per axis, degrees",
                             "properties": {axis: _NUMBER_OR_NULL for axis in OUTPUT_AXES}},
        "taught": {"type": ["integer", "null"], "description": "fixations taught since the service started"},
        "recent_mean_retinal_error": {**_NUMBER_OR_NULL,
                                      "description": "mean retinal error over the last 100 adaptations"},
    },
}


def marks_of(size: tuple[int, int], side: str, target: Sequence[float] | None,
             match: tuple[float, float] | None, confidence: float | None) -> Marks:
    """One eye's marks from a left-image target (x, y, d: the right eye's at x + d) and that eye's match."""
    where = None
    if target is not None and len(target) >= 2:
        x, y = target[0], target[1]
        d = target[2] if len(target) >= 3 and math.isfinite(target[2]) else 0.0
        where = (x + d, y) if side == "right" else (x, y)
    return Marks(size=size, target=where, match=match, confidence=confidence)
