"""V4L2 controls by id (`drivers.cameras.v4l2_controls`) on a scripted ioctl answering as a
driver with an automatic gain does (the gspca ov534 of the PS3 Eye names it "Gain, Automatic")."""
from __future__ import annotations

import errno

import pytest

from drivers.cameras import v4l2_controls as vc
from drivers.errors import CameraError


class ScriptedDriver:
    """Answers VIDIOC_QUERYCTRL / G_CTRL / S_CTRL for the controls it holds, EINVAL otherwise."""

    def __init__(self, controls: dict[int, int]) -> None:
        self.controls = controls

    def __call__(self, fd, request, buf):
        if request == vc._VIDIOC_QUERYCTRL:
            cid = vc._QUERYCTRL.unpack(buf)[0]
            if cid not in self.controls:
                raise OSError(errno.EINVAL, "Invalid argument")
            buf[:] = vc._QUERYCTRL.pack(cid, 2, b"Gain, Automatic", 0, 1, 1, 1, 0, 0, 0)
        elif request in (vc._VIDIOC_G_CTRL, vc._VIDIOC_S_CTRL):
            cid, value = vc._CONTROL.unpack(buf)
            if cid not in self.controls:
                raise OSError(errno.EINVAL, "Invalid argument")
            if request == vc._VIDIOC_S_CTRL:
                self.controls[cid] = value
            else:
                buf[:] = vc._CONTROL.pack(cid, self.controls[cid])
        else:
            raise AssertionError(f"unexpected ioctl 0x{request:08x}")


@pytest.fixture
def node(tmp_path):
    path = tmp_path / "video0"
    path.write_bytes(b"")
    return str(path)


def test_a_control_is_queried_read_and_set(node):
    driver = ScriptedDriver({vc.AUTOGAIN: 1})
    controls = vc.V4L2Controls(node, ioctl=driver)
    info = controls.query(vc.AUTOGAIN)
    assert info is not None and info.name == "Gain, Automatic" and (info.minimum, info.maximum) == (0, 1)
    assert not info.disabled and controls.get(vc.AUTOGAIN) == 1
    controls.set(vc.AUTOGAIN, 0)
    assert driver.controls[vc.AUTOGAIN] == 0 and controls.get(vc.AUTOGAIN) == 0


def test_a_missing_control_or_a_node_that_is_not_v4l2(node):
    controls = vc.V4L2Controls(node, ioctl=ScriptedDriver({}))
    assert controls.query(vc.AUTOGAIN) is None
    with pytest.raises(CameraError, match=r"video0: setting V4L2 control 0x00980912 to 0 failed: Invalid argument"):
        controls.set(vc.AUTOGAIN, 0)
    # A real ioctl on a file that is no V4L2 device (ENOTTY): no such control either.
    assert vc.V4L2Controls(node).query(vc.AUTOGAIN) is None
