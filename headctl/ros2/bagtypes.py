"""The messages of `headctl.ros2.messages` without Cyclone DDS: the same names and fields,
made from rosbags' typestore (`rosbags.typesys`) and serialised by it.

`convert` and `frames` build their messages from these when `cyclonedds` is not installed
(an ARM board without the `ros2` extra), so a recording (`headctl.ros2.recorder`) needs no
DDS. Each class is a dataclass of the ROS 2 type's fields with ROS's defaults (zero, empty,
the nested type's default), `serialize(msg)` its CDR bytes as a ROS 2 publisher sends them;
the tests check the bytes equal those of `messages`. The fields of the types used here are
the same in Humble, Jazzy and Kilted, so Humble's store serves every distro.
"""
from __future__ import annotations

import dataclasses
import functools
from typing import Any

import numpy as np
from rosbags.typesys import Stores, get_typestore
from rosbags.typesys.store import Typestore

# A primitive's numpy dtype where rosbags wants an array (sequences and arrays of numbers).
_DTYPES = {"bool": np.bool_, "byte": np.uint8, "char": np.uint8, "int8": np.int8, "uint8": np.uint8,
           "int16": np.int16, "uint16": np.uint16, "int32": np.int32, "uint32": np.uint32,
           "int64": np.int64, "uint64": np.uint64, "float32": np.float32, "float64": np.float64}
_BASE, _NAME, _ARRAY, _SEQUENCE = 1, 2, 3, 4  # rosbags' Nodetype values


@functools.cache
def typestore() -> Typestore:
    return get_typestore(Stores.ROS2_HUMBLE)


def _default(desc: tuple[int, Any]) -> Any:
    kind, detail = desc
    if kind == _BASE:
        name = detail[0]
        return "" if name in ("string", "wstring") else (False if name == "bool" else 0)
    if kind == _NAME:
        return dataclasses.field(default_factory=_CLASSES[detail])
    (sub_kind, sub_detail), size = detail
    if sub_kind == _BASE and sub_detail[0] in _DTYPES:
        dtype = _DTYPES[sub_detail[0]]
        return dataclasses.field(default_factory=lambda: np.zeros(size if kind == _ARRAY else 0, dtype))
    return dataclasses.field(default_factory=list)


def _numeric_fields(ros_type: str) -> dict[str, type[np.generic]]:
    out = {}
    for name, (kind, detail) in typestore().fielddefs[ros_type][1]:
        if kind in (_ARRAY, _SEQUENCE) and detail[0][0] == _BASE and detail[0][1][0] in _DTYPES:
            out[name] = _DTYPES[detail[0][1][0]]
    return out


def _post_init(self: Any) -> None:
    for name, dtype in self._numeric.items():
        value = getattr(self, name)
        if isinstance(value, (bytes, bytearray, memoryview)):
            setattr(self, name, np.frombuffer(value, dtype))
        elif not isinstance(value, np.ndarray):
            setattr(self, name, np.asarray(value, dtype))


_CLASSES: dict[str, type[Any]] = {}


def _make(ros_type: str) -> type[Any]:
    """The dataclass of `ros_type` (its nested types made first)."""
    if ros_type in _CLASSES:
        return _CLASSES[ros_type]
    fields: list[tuple[str, Any]] = list(typestore().fielddefs[ros_type][1])
    for _, (kind, detail) in fields:
        if kind == _NAME:
            _make(str(detail))
        elif kind in (_ARRAY, _SEQUENCE) and detail[0][0] == _NAME:
            _make(str(detail[0][1]))
    cls = dataclasses.make_dataclass(
        ros_type.rsplit("/", 1)[1], [(name, Any, _default(desc)) for name, desc in fields],
        namespace={"__msgtype__": ros_type, "_numeric": _numeric_fields(ros_type), "__post_init__": _post_init})
    _CLASSES[ros_type] = cls
    return cls


def serialize(msg: Any) -> bytes:
    """The CDR bytes of a message of this module (its type in `__msgtype__`)."""
    return bytes(typestore().serialize_cdr(msg, msg.__msgtype__))


class Time(_make("builtin_interfaces/msg/Time")):  # type: ignore[misc]
    @classmethod
    def of_seconds(cls, t_s: float) -> "Time":
        """A ROS time (seconds since the epoch) from a float of seconds."""
        ns = int(round(t_s * 1e9))
        return cls(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)


_CLASSES["builtin_interfaces/msg/Time"] = Time


class Level:
    """DiagnosticStatus levels (a byte in the message)."""

    OK = 0
    WARN = 1
    ERROR = 2
    STALE = 3


Header = _make("std_msgs/msg/Header")
Vector3 = _make("geometry_msgs/msg/Vector3")
Quaternion = _make("geometry_msgs/msg/Quaternion")
Point = _make("geometry_msgs/msg/Point")
PointStamped = _make("geometry_msgs/msg/PointStamped")
Transform = _make("geometry_msgs/msg/Transform")
TransformStamped = _make("geometry_msgs/msg/TransformStamped")
TFMessage = _make("tf2_msgs/msg/TFMessage")
JointState = _make("sensor_msgs/msg/JointState")
Image = _make("sensor_msgs/msg/Image")
CompressedImage = _make("sensor_msgs/msg/CompressedImage")
RegionOfInterest = _make("sensor_msgs/msg/RegionOfInterest")
CameraInfo = _make("sensor_msgs/msg/CameraInfo")
KeyValue = _make("diagnostic_msgs/msg/KeyValue")
DiagnosticStatus = _make("diagnostic_msgs/msg/DiagnosticStatus")
DiagnosticArray = _make("diagnostic_msgs/msg/DiagnosticArray")
String = _make("std_msgs/msg/String")
