"""The ROS 2 messages headctl speaks, as Cyclone DDS types under their ROS 2 DDS names.

A ROS 2 message `pkg/msg/Name` is the DDS type `pkg::msg::dds_::Name_` (rosidl's IDL with
rmw_cyclonedds's mangling); on the wire plain little-endian CDR (XCDR1, the encapsulation
header 00 01 00 00), which these final structs serialise to. Field order and types follow
common_interfaces, tf2_msgs and rmw_dds_common, the same in Humble, Jazzy and Kilted but for
rmw_dds_common's Gid (24 bytes in Humble, 16 from Iron on). `sample.serialize()` is the
sample's CDR bytes as a ROS 2 publisher sends them and a rosbag2 bag stores them (a
recorder reuses them as they are); `ROS_TYPES` names each type as ROS 2 does
(`sensor_msgs/msg/JointState`).
"""

from dataclasses import dataclass, field

from typing import Any

from cyclonedds.idl import IdlStruct
from cyclonedds.idl._machinery import PlainCdrV2SequenceOfPrimitiveMachine
from cyclonedds.idl.types import array, float64, int32, sequence, uint8, uint32


def _name(ros_type: str) -> str:
    pkg, kind, name = ros_type.split("/")
    return f"{pkg}::{kind}::dds_::{name}_"


# --- builtin_interfaces, std_msgs --------------------------------------------------------------
@dataclass
class Time(IdlStruct):
    __idl_typename__ = _name("builtin_interfaces/msg/Time")
    sec: int32 = 0
    nanosec: uint32 = 0

    @classmethod
    def of_seconds(cls, t_s: float) -> "Time":
        """A ROS time (seconds since the epoch) from a float of seconds."""
        ns = int(round(t_s * 1e9))
        return cls(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)

    @property
    def seconds(self) -> float:
        """This time as a float of seconds (`of_seconds`'s inverse, to the float's precision)."""
        return float(self.sec) + float(self.nanosec) * 1e-9


@dataclass
class Header(IdlStruct):
    __idl_typename__ = _name("std_msgs/msg/Header")
    stamp: Time = field(default_factory=Time)
    frame_id: str = ""


# --- geometry_msgs -----------------------------------------------------------------------------
@dataclass
class Vector3(IdlStruct):
    __idl_typename__ = _name("geometry_msgs/msg/Vector3")
    x: float64 = 0.0
    y: float64 = 0.0
    z: float64 = 0.0


@dataclass
class Quaternion(IdlStruct):
    __idl_typename__ = _name("geometry_msgs/msg/Quaternion")
    x: float64 = 0.0
    y: float64 = 0.0
    z: float64 = 0.0
    w: float64 = 1.0


@dataclass
class Point(IdlStruct):
    __idl_typename__ = _name("geometry_msgs/msg/Point")
    x: float64 = 0.0
    y: float64 = 0.0
    z: float64 = 0.0


@dataclass
class PointStamped(IdlStruct):
    __idl_typename__ = _name("geometry_msgs/msg/PointStamped")
    header: Header = field(default_factory=Header)
    point: Point = field(default_factory=Point)


@dataclass
class Transform(IdlStruct):
    __idl_typename__ = _name("geometry_msgs/msg/Transform")
    translation: Vector3 = field(default_factory=Vector3)
    rotation: Quaternion = field(default_factory=Quaternion)


@dataclass
class TransformStamped(IdlStruct):
    __idl_typename__ = _name("geometry_msgs/msg/TransformStamped")
    header: Header = field(default_factory=Header)
    child_frame_id: str = ""
    transform: Transform = field(default_factory=Transform)


@dataclass
class TFMessage(IdlStruct):
    __idl_typename__ = _name("tf2_msgs/msg/TFMessage")
    transforms: sequence[TransformStamped] = field(default_factory=list)


# --- sensor_msgs -------------------------------------------------------------------------------
@dataclass
class JointState(IdlStruct):
    __idl_typename__ = _name("sensor_msgs/msg/JointState")
    header: Header = field(default_factory=Header)
    name: sequence[str] = field(default_factory=list)
    position: sequence[float64] = field(default_factory=list)
    velocity: sequence[float64] = field(default_factory=list)
    effort: sequence[float64] = field(default_factory=list)


@dataclass
class Image(IdlStruct):
    __idl_typename__ = _name("sensor_msgs/msg/Image")
    header: Header = field(default_factory=Header)
    height: uint32 = 0
    width: uint32 = 0
    encoding: str = ""
    is_bigendian: uint8 = 0
    step: uint32 = 0
    data: sequence[uint8] = b""  # bytes (`_octets`)


@dataclass
class CompressedImage(IdlStruct):
    __idl_typename__ = _name("sensor_msgs/msg/CompressedImage")
    header: Header = field(default_factory=Header)
    format: str = ""
    data: sequence[uint8] = b""  # bytes (`_octets`)


@dataclass
class RegionOfInterest(IdlStruct):
    __idl_typename__ = _name("sensor_msgs/msg/RegionOfInterest")
    x_offset: uint32 = 0
    y_offset: uint32 = 0
    height: uint32 = 0
    width: uint32 = 0
    do_rectify: bool = False


@dataclass
class CameraInfo(IdlStruct):
    __idl_typename__ = _name("sensor_msgs/msg/CameraInfo")
    header: Header = field(default_factory=Header)
    height: uint32 = 0
    width: uint32 = 0
    distortion_model: str = ""
    d: sequence[float64] = field(default_factory=list)
    k: array[float64, 9] = field(default_factory=lambda: [0.0] * 9)
    r: array[float64, 9] = field(default_factory=lambda: [0.0] * 9)
    p: array[float64, 12] = field(default_factory=lambda: [0.0] * 12)
    binning_x: uint32 = 0
    binning_y: uint32 = 0
    roi: RegionOfInterest = field(default_factory=RegionOfInterest)


class _OctetsMachine(PlainCdrV2SequenceOfPrimitiveMachine):
    """sequence<uint8> from and to `bytes` in one copy. The binding's own machine packs and
    unpacks the bytes one by one (milliseconds for an image); the wire is the same: a length,
    then the bytes."""

    def __init__(self) -> None:
        super().__init__(uint8)

    def serialize(self, buffer: Any, value: bytes, *args: Any, **kwargs: Any) -> None:
        buffer.align(4)
        buffer.write("I", 4, len(value))
        buffer.write_bytes(value)

    def deserialize(self, buffer: Any, *args: Any, **kwargs: Any) -> bytes:
        buffer.align(4)
        data: bytes = buffer.read_bytes(buffer.read("I", 4))
        return data


def _octets(cls: type[IdlStruct], name: str) -> None:
    """Serialise the `sequence[uint8]` field `name` of `cls` as `bytes` (`_OctetsMachine`); the
    type, and so its XTypes description, stays sequence<uint8>, as ROS 2 declares it."""
    idl = cls.__idl__
    idl.populate()
    for machine in (idl.v1_machine, idl.v2_machine):
        machine.members_machines[name] = _OctetsMachine()


_octets(Image, "data")
_octets(CompressedImage, "data")


# --- diagnostic_msgs ---------------------------------------------------------------------------
@dataclass
class KeyValue(IdlStruct):
    __idl_typename__ = _name("diagnostic_msgs/msg/KeyValue")
    key: str = ""
    value: str = ""


class Level:
    """DiagnosticStatus levels (a byte in the message)."""

    OK = 0
    WARN = 1
    ERROR = 2
    STALE = 3


@dataclass
class DiagnosticStatus(IdlStruct):
    __idl_typename__ = _name("diagnostic_msgs/msg/DiagnosticStatus")
    level: uint8 = Level.OK  # `byte` in the .msg: an octet
    name: str = ""
    message: str = ""
    hardware_id: str = ""
    values: sequence[KeyValue] = field(default_factory=list)


@dataclass
class DiagnosticArray(IdlStruct):
    __idl_typename__ = _name("diagnostic_msgs/msg/DiagnosticArray")
    header: Header = field(default_factory=Header)
    status: sequence[DiagnosticStatus] = field(default_factory=list)


# --- rmw_dds_common: what makes the node show in `ros2 node list` -------------------------------
@dataclass
class GidHumble(IdlStruct):
    __idl_typename__ = _name("rmw_dds_common/msg/Gid")
    data: array[uint8, 24] = field(default_factory=lambda: [0] * 24)


@dataclass
class Gid(IdlStruct):
    __idl_typename__ = _name("rmw_dds_common/msg/Gid")
    data: array[uint8, 16] = field(default_factory=lambda: [0] * 16)


@dataclass
class NodeEntitiesInfoHumble(IdlStruct):
    __idl_typename__ = _name("rmw_dds_common/msg/NodeEntitiesInfo")
    node_namespace: str = ""
    node_name: str = ""
    reader_gid_seq: sequence[GidHumble] = field(default_factory=list)
    writer_gid_seq: sequence[GidHumble] = field(default_factory=list)


@dataclass
class NodeEntitiesInfo(IdlStruct):
    __idl_typename__ = _name("rmw_dds_common/msg/NodeEntitiesInfo")
    node_namespace: str = ""
    node_name: str = ""
    reader_gid_seq: sequence[Gid] = field(default_factory=list)
    writer_gid_seq: sequence[Gid] = field(default_factory=list)


@dataclass
class ParticipantEntitiesInfoHumble(IdlStruct):
    __idl_typename__ = _name("rmw_dds_common/msg/ParticipantEntitiesInfo")
    gid: GidHumble = field(default_factory=GidHumble)
    node_entities_info_seq: sequence[NodeEntitiesInfoHumble] = field(default_factory=list)


@dataclass
class ParticipantEntitiesInfo(IdlStruct):
    __idl_typename__ = _name("rmw_dds_common/msg/ParticipantEntitiesInfo")
    gid: Gid = field(default_factory=Gid)
    node_entities_info_seq: sequence[NodeEntitiesInfo] = field(default_factory=list)


ROS_TYPES: dict[type[IdlStruct], str] = {
    Time: "builtin_interfaces/msg/Time", Header: "std_msgs/msg/Header",
    Vector3: "geometry_msgs/msg/Vector3", Quaternion: "geometry_msgs/msg/Quaternion",
    Point: "geometry_msgs/msg/Point", PointStamped: "geometry_msgs/msg/PointStamped",
    Transform: "geometry_msgs/msg/Transform", TransformStamped: "geometry_msgs/msg/TransformStamped",
    TFMessage: "tf2_msgs/msg/TFMessage", JointState: "sensor_msgs/msg/JointState",
    Image: "sensor_msgs/msg/Image", CompressedImage: "sensor_msgs/msg/CompressedImage",
    RegionOfInterest: "sensor_msgs/msg/RegionOfInterest", CameraInfo: "sensor_msgs/msg/CameraInfo",
    KeyValue: "diagnostic_msgs/msg/KeyValue", DiagnosticStatus: "diagnostic_msgs/msg/DiagnosticStatus",
    DiagnosticArray: "diagnostic_msgs/msg/DiagnosticArray",
    GidHumble: "rmw_dds_common/msg/Gid", Gid: "rmw_dds_common/msg/Gid",
    NodeEntitiesInfoHumble: "rmw_dds_common/msg/NodeEntitiesInfo", NodeEntitiesInfo: "rmw_dds_common/msg/NodeEntitiesInfo",
    ParticipantEntitiesInfoHumble: "rmw_dds_common/msg/ParticipantEntitiesInfo",
    ParticipantEntitiesInfo: "rmw_dds_common/msg/ParticipantEntitiesInfo",
}


def discovery_types(distro: str) -> tuple[type[IdlStruct], type[IdlStruct], type[IdlStruct], int]:
    """(ParticipantEntitiesInfo, NodeEntitiesInfo, Gid, the Gid's size) of a distro's rmw_dds_common."""
    if distro == "humble":
        return ParticipantEntitiesInfoHumble, NodeEntitiesInfoHumble, GidHumble, 24
    return ParticipantEntitiesInfo, NodeEntitiesInfo, Gid, 16
