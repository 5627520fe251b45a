"""Subcommands of `headctl` for the cameras: `cameras` (list them) and `snapshot` (save a pair).

`cameras` lists the V4L2 devices and the GenICam (Aravis) devices with their ids, serials
and formats. `snapshot --config F --out DIR` opens the left and right cameras the `cameras:`
section of a head's config (or of a file holding only that section) describes (simulated
ones included: they render the simulated head at `--pose`), waits for the first
synchronised pair taken after the cameras started, and saves it as DIR/left.png and
DIR/right.png.
"""
from __future__ import annotations

import argparse
import contextlib
import logging
import os
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING, TypedDict

from drivers.cameras.camera import create_camera
from drivers.cameras.config import CameraConfig, StereoCamerasConfig
from drivers.cameras.stereo import StereoPair
from drivers.config.reader import read_config
from drivers.errors import BackendImportError, CameraError, ConfigError

if TYPE_CHECKING:
    from calib_free.sim.head_model import HeadModel
    from drivers.sim.camera import PoseSource

log = logging.getLogger(__name__)
_ARAVIS_INSTALL = "apt-get install gir1.2-aravis-0.8 && pip install 'PyGObject<3.51' (./setup.sh does both)"


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Add this module's subcommands to `sub`."""
    cameras = sub.add_parser(
        "cameras",
        help="list V4L2 and GenICam (Aravis) cameras with ids, serials and formats",
        description="List the V4L2 devices (with their /dev/v4l/by-id names) and the GenICam cameras "
                    "Aravis finds (GigE Vision discovery takes about a second).",
    )
    cameras.add_argument("--fake", action="store_true", help="also list Aravis's in-process Fake camera (Fake_1)")
    cameras.add_argument("--no-formats", action="store_true", help="do not open devices to read their formats")
    cameras.set_defaults(func=_list_cameras)

    snapshot = sub.add_parser(
        "snapshot",
        help="save a synchronised left/right PNG pair from the configured cameras",
        description="Open the cameras of a config's `cameras:` section (left and right), wait for the "
                    "first pair taken after they started, and save DIR/left.png and DIR/right.png.",
    )
    snapshot.add_argument("--config", required=True, metavar="FILE",
                          help="a head's YAML file (or one with only a cameras: section)")
    snapshot.add_argument("--out", required=True, metavar="DIR", help="directory for left.png and right.png")
    snapshot.add_argument("--pose", nargs=4, type=float, default=[0.0, 0.0, 0.0, 0.0],
                          metavar=("PAN", "TILT", "LEFT_EYE", "RIGHT_EYE"),
                          help="joint angles in degrees for simulated cameras (default 0 0 0 0)")
    snapshot.add_argument("--timeout", type=float, default=10.0, metavar="S", help="seconds to wait for a pair")
    snapshot.set_defaults(func=_snapshot)


# --- cameras -----------------------------------------------------------------------------
def _list_cameras(args: argparse.Namespace) -> int:
    from drivers.cameras.opencv import list_v4l2_devices

    print("V4L2 devices:")
    devices = list_v4l2_devices()
    for info in devices:
        links = f"  ({', '.join(info['links'])})" if info["links"] else ""
        print(f"  {info['device']}  {info['name'] or '-'}{links}")
        for fmt in info["formats"] if not args.no_formats else []:
            print(f"      {fmt}")
    if not devices:
        print("  none")
    print("GenICam devices (Aravis):")
    try:
        from drivers.cameras import aravis as aravis_camera
    except (ImportError, ValueError) as err:
        print(f"  Aravis is not available ({err}); install: {_ARAVIS_INSTALL}")
        return 1
    if args.fake:
        aravis_camera.enable_fake_interface()
    found = aravis_camera.list_devices(with_formats=not args.no_formats)
    for dev in found:
        print(f"  id {dev.id}  serial {dev.serial}  {dev.vendor} {dev.model}  {dev.protocol} {dev.address}")
        if dev.pixel_formats:
            print(f"      formats: {', '.join(dev.pixel_formats)}")
    if not found:
        print("  none")
    return 0


# --- snapshot ----------------------------------------------------------------------------
def load_cameras_config(path: str) -> StereoCamerasConfig:
    """The `cameras:` section of a YAML file, typed: a whole head config (every section
    validated) or a file holding only `cameras:`."""
    from headctl.config.head import check_cameras, parse_config, read_yaml

    data = read_yaml(path)
    if isinstance(data, dict) and set(data) != {"cameras"}:
        return parse_config(data, Path(path)).cameras
    if not isinstance(data, dict):
        raise ConfigError(key_path="", value=data, file=path,
                          expected="a head config, or a mapping with a cameras: section "
                                   "(cameras: {left: ..., right: ...})")
    try:
        cameras = read_config(StereoCamerasConfig, data["cameras"], "cameras", file=path)
        check_cameras(cameras)
    except ConfigError as err:
        if err.file is None:
            err.file = path
        raise
    return cameras


class SimResources(TypedDict, total=False):
    """What `create_camera` gives a simulated camera beyond its config."""

    head: HeadModel
    pose_source: PoseSource


def sim_resources(config: StereoCamerasConfig, pose: list[float]) -> dict[str, SimResources]:
    """The head model and pose source the simulated cameras need (one head for both eyes;
    `load_cameras_config` has checked that the eyes agree)."""
    from calib_free.sim.head_model import HeadModel
    from drivers.sim.camera import fixed_pose

    sims = {side: c for side, c in (("left", config.left), ("right", config.right)) if c.backend == "sim"}
    if not sims:
        return {}
    first: CameraConfig = next(iter(sims.values()))
    head = HeadModel.default(first.width or 320, first.height or 240, lens=first.lens)
    source = fixed_pose(*pose)
    return {side: {"head": head, "pose_source": source} for side in sims}


def _snapshot(args: argparse.Namespace) -> int:
    import cv2

    try:
        config = load_cameras_config(args.config)
        resources = sim_resources(config, args.pose)
        cameras = [
            create_camera(c, name=side, key_path=f"cameras.{side}", **resources.get(side, {}))
            for side, c in (("left", config.left), ("right", config.right))
        ]
    except ConfigError as err:  # the file's, or a camera's that refuses a setting
        if err.file is None:
            err.file = args.config
        print(f"headctl snapshot: {err}", file=sys.stderr)
        return 2
    except BackendImportError as err:
        print(f"headctl snapshot: {args.config}: {err}", file=sys.stderr)
        return 2
    os.makedirs(args.out, exist_ok=True)
    try:
        with contextlib.ExitStack() as stack:
            for camera in cameras:
                stack.enter_context(camera)
            pair = stack.enter_context(StereoPair(cameras[0], cameras[1], config.tolerance_s))
            started_s = time.monotonic()
            for camera in cameras:
                camera.enable()
            frames = pair.wait_pair(after_s=started_s, timeout_s=args.timeout)
    except CameraError as err:
        print(f"headctl snapshot: {err}", file=sys.stderr)
        return 1
    for frame in (frames.left, frames.right):
        path = os.path.join(args.out, f"{frame.camera}.png")
        if not cv2.imwrite(path, frame.image):
            print(f"headctl snapshot: cannot write {path}", file=sys.stderr)
            return 1
        print(f"{path}  {frame.image.shape[1]} x {frame.image.shape[0]}  frame {frame.counter}  "
              f"t={frame.time_s:.6f} s")
    print(f"pair skew {frames.skew_s * 1e3:.3f} ms")
    return 0
