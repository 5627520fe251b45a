"""V4L2 controls that OpenCV's VideoCapture cannot reach, read and set by id on the device node.

OpenCV's V4L2 backend maps its properties to V4L2 controls through a fixed table
(`capPropertyToV4L2` in modules/videoio/src/cap_v4l.cpp): `CAP_PROP_AUTO_EXPOSURE` is
V4L2_CID_EXPOSURE_AUTO, `CAP_PROP_EXPOSURE` V4L2_CID_EXPOSURE_ABSOLUTE, `CAP_PROP_GAIN`
V4L2_CID_GAIN, `CAP_PROP_AUTO_WB` the automatic white balance; V4L2_CID_AUTOGAIN is not in
it. Drivers that have an automatic gain (gspca's, such as ov534 for the PS3 Eye) are reached
here. UVC cameras have none: the UVC 1.5 Processing Unit's Gain control has no automatic
mode, and uvcvideo exposes no V4L2_CID_AUTOGAIN; what a UVC camera does with its gain
while its auto exposure runs is its firmware's business, and switching that auto exposure
off (manual) holds both.

The node is opened beside OpenCV's own descriptor for each call (V4L2 lets any open file
handle of a device read and set its controls), with VIDIOC_QUERYCTRL, VIDIOC_G_CTRL and
VIDIOC_S_CTRL; the numbers are those of linux/videodev2.h and linux/v4l2-controls.h.
"""
from __future__ import annotations

import fcntl
import os
import struct
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from drivers.errors import CameraError

AUTOGAIN = 0x00980912  # V4L2_CID_AUTOGAIN (V4L2_CID_BASE + 18): boolean

_VIDIOC_QUERYCTRL = 0xC0445624  # _IOWR('V', 36, struct v4l2_queryctrl), 68 bytes
_VIDIOC_G_CTRL = 0xC008561B  # _IOWR('V', 27, struct v4l2_control), 8 bytes
_VIDIOC_S_CTRL = 0xC008561C  # _IOWR('V', 28, struct v4l2_control)
_QUERYCTRL = struct.Struct("=II32siiiiI2I")  # id, type, name, minimum, maximum, step, default, flags, reserved
_CONTROL = struct.Struct("=Ii")  # id, value
_FLAG_DISABLED = 0x0001

Ioctl = Callable[..., Any]


@dataclass(frozen=True)
class ControlInfo:
    """What VIDIOC_QUERYCTRL tells of one control."""

    control_id: int
    name: str
    minimum: int
    maximum: int
    default: int
    flags: int

    @property
    def disabled(self) -> bool:
        return bool(self.flags & _FLAG_DISABLED)


class V4L2Controls:
    """The controls of the V4L2 device at `path`; `ioctl` is injectable for tests."""

    def __init__(self, path: str, ioctl: Ioctl = fcntl.ioctl) -> None:
        self.path = path
        self._ioctl = ioctl

    def _call(self, request: int, buffer: bytearray) -> None:
        fd = os.open(self.path, os.O_RDWR | os.O_NONBLOCK)
        try:
            self._ioctl(fd, request, buffer)
        finally:
            os.close(fd)

    def query(self, control_id: int) -> ControlInfo | None:
        """The control, or None when the device has no such control (or is no V4L2 device)."""
        buffer = bytearray(_QUERYCTRL.pack(control_id, 0, b"", 0, 0, 0, 0, 0, 0, 0))
        try:
            self._call(_VIDIOC_QUERYCTRL, buffer)
        except OSError:  # EINVAL: no such control; ENOTTY: not a V4L2 node
            return None
        cid, _, name, minimum, maximum, _, default, flags, _, _ = _QUERYCTRL.unpack(buffer)
        if cid != control_id:
            return None
        return ControlInfo(cid, name.split(b"\0", 1)[0].decode(errors="replace"), minimum, maximum, default, flags)

    def get(self, control_id: int) -> int:
        buffer = bytearray(_CONTROL.pack(control_id, 0))
        try:
            self._call(_VIDIOC_G_CTRL, buffer)
        except OSError as err:
            raise CameraError(f"{self.path}: reading V4L2 control 0x{control_id:08x} failed: {err.strerror}") from err
        value: int = _CONTROL.unpack(buffer)[1]
        return value

    def set(self, control_id: int, value: int) -> None:
        try:
            self._call(_VIDIOC_S_CTRL, bytearray(_CONTROL.pack(control_id, int(value))))
        except OSError as err:
            raise CameraError(f"{self.path}: setting V4L2 control 0x{control_id:08x} to {value} failed: "
                              f"{err.strerror}") from err
