"""Every message headctl publishes serialises to the bytes rosbags gives the same message, in
each supported distro's typestore (the CDR a ROS 2 node sends and a rosbag2 bag stores)."""
from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np
import pytest

from tests.headctl.ros2.support import need

need("cyclonedds")
need("rosbags")

from rosbags.typesys import Stores, get_typestore  # noqa: E402

from headctl.ros2 import messages as m  # noqa: E402

STORES = {"humble": Stores.ROS2_HUMBLE, "jazzy": Stores.ROS2_JAZZY, "kilted": Stores.ROS2_KILTED}


def _header(frame: str = "head/left_camera_optical_frame") -> m.Header:
    return m.Header(stamp=m.Time.of_seconds(1764609000.123456789), frame_id=frame)


def samples(distro: str) -> list[Any]:
    """One sample of every type, with values in every field (odd lengths, to test alignment)."""
    tf = m.TransformStamped(header=_header("base_link"), child_frame_id="head_pan_link",
                            transform=m.Transform(m.Vector3(0.1, -0.2, 0.3), m.Quaternion(0.0, 0.0, 0.3826834, 0.9238795)))
    status = m.DiagnosticStatus(level=m.Level.WARN, name="headctl: servo pan", message="hot",
                                hardware_id="id 1 on /dev/ttyUSB0",
                                values=[m.KeyValue("temperature_c", "61"), m.KeyValue("voltage_v", "11.9")])
    info_type, node_type, gid_type, size = m.discovery_types(distro)
    gid = gid_type(data=list(range(1, size + 1)))
    return [
        m.Time(sec=5, nanosec=7), _header(),
        m.JointState(header=_header(""), name=["pan", "tilt", "left_eye"], position=[0.1, -0.2, 0.3],
                     velocity=[1.0, 2.0, 3.0], effort=[]),
        m.Image(header=_header(), height=3, width=5, encoding="bgr8", is_bigendian=0, step=15,
                data=bytes(range(45))),
        m.CompressedImage(header=_header(), format="jpeg", data=b"\xff\xd8\xff\xe0abc"),
        m.CameraInfo(header=_header(), height=240, width=320, distortion_model="", d=[],
                     k=[0.0] * 9, r=[1.0, 0, 0, 0, 1.0, 0, 0, 0, 1.0], p=[0.0] * 12, binning_x=0, binning_y=0,
                     roi=m.RegionOfInterest(1, 2, 3, 4, True)),
        tf, m.TFMessage(transforms=[tf, tf]),
        m.PointStamped(header=_header(), point=m.Point(159.5, 119.5, math.nan)),
        m.Point(1.0, 2.0, 3.0), m.Vector3(-1.0, 0.5, 2.0), m.Quaternion(0.5, 0.5, 0.5, 0.5), tf.transform,
        m.RegionOfInterest(5, 6, 7, 8, False), m.KeyValue("a", "b"), status, m.DiagnosticArray(header=_header(""), status=[status, status]),
        gid, info_type(gid=gid, node_entities_info_seq=[node_type("/", "headctl", [gid], [gid, gid])]),
    ]


def to_rosbags(store: Any, sample: Any, ros_type: str) -> Any:
    """The same message as the typestore's class."""
    cls = store.types[ros_type]
    values = {}
    for name, (kind, detail) in store.fielddefs[ros_type][1]:
        value = getattr(sample, name)
        if kind.name == "NAME":
            values[name] = to_rosbags(store, value, detail)
        elif kind.name in ("SEQUENCE", "ARRAY"):
            (sub_kind, sub_detail), _ = detail
            if sub_kind.name == "NAME":
                values[name] = [to_rosbags(store, v, sub_detail) for v in value]
            elif sub_detail[0] == "string":
                values[name] = list(value)
            else:
                dtype = {"float64": np.float64, "uint8": np.uint8, "char": np.uint8, "octet": np.uint8}[sub_detail[0]]
                values[name] = np.frombuffer(value, dtype) if isinstance(value, bytes) else np.array(value, dtype)
        else:
            values[name] = value
    return cls(**values)


@pytest.mark.parametrize("distro", sorted(STORES))
def test_cdr_bytes_equal_rosbags(distro: str) -> None:
    store = get_typestore(STORES[distro])
    checked = set()
    for sample in samples(distro):
        ros_type = m.ROS_TYPES[type(sample)]
        ours = sample.serialize()
        theirs = bytes(store.serialize_cdr(to_rosbags(store, sample, ros_type), ros_type))
        assert ours == theirs, f"{distro} {ros_type}: {ours.hex()} != {theirs.hex()}"
        checked.add(type(sample))
        # and rosbags reads ours back as the same message
        assert store.deserialize_cdr(ours, ros_type) is not None
    wanted = {t for t in m.ROS_TYPES if not t.__name__.startswith(("Gid", "NodeEntities", "ParticipantEntities"))}
    assert wanted <= checked


def test_dds_type_names_follow_rmw_conventions() -> None:
    for cls, ros_type in m.ROS_TYPES.items():
        pkg, kind, name = ros_type.split("/")
        assert cls.__idl_typename__ == f"{pkg}::{kind}::dds_::{name}_"


def test_time_of_seconds() -> None:
    t = m.Time.of_seconds(12.25)
    assert (t.sec, t.nanosec) == (12, 250_000_000)
    assert dataclasses.asdict(m.Time.of_seconds(0.999999999999)) == {"sec": 1, "nanosec": 0}
