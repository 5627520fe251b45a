"""Diagnostic: how much a target's own-view ambiguity margin moves between two exposures.

A look judges its target's patch again in its own image before the saccade
(`calib_free.gaze.look`): another exposure than the one the client's target was accepted in,
of a view within `LookController.SAME_VIEW_DEG` of it. The judgement that the patch does not
repeat is a margin: its best own-view NCC less its second place's (`own_view_peaks`).

This renders the generated room through a simulated camera model (`--sensor`, default
`uvc_webcam`: auto exposure, noise, MJPEG) at random poses: a first frame once the auto
exposure has settled, and a second `--gap-frames` later with the head up to `--view-deg`
(default SAME_VIEW_DEG) away on pan and tilt. For random textured pixels whose margin in the
first frame is below 0.2 (the patches the default threshold of 0.1 decides), it prints how far
the margin moved in the second: median, p90, p99, max.

    .venv/bin/python -m benchmarks.diag.own_view_margin [--poses 40] [--pixels 40] [--view-deg 0.25]
        [--sensor uvc_webcam] [--seed 0]
"""
from __future__ import annotations

import argparse

import cv2
import numpy as np

from calib_free.gaze.fixation import LookParams
from calib_free.gaze.look import LookController
from calib_free.gaze.target_patch import own_view_peaks
from calib_free.sim.head_model import HeadModel
from drivers.cameras.camera import create_camera
from drivers.cameras.config import CameraConfig
from drivers.clock import ManualClock
from drivers.sim.camera import SimulatedCamera, fixed_pose
from drivers.sim.scene import shared_scene

FPS = 30.0
SETTLE_FRAMES = 30
NEAR_THRESHOLD = 0.2  # first-frame margins below this are the patches the threshold decides
FIND_RADIUS_PX = 6  # the target's texel is looked for this far about its first-frame place


def _where_now(first: np.ndarray, second: np.ndarray, xy: tuple[float, float], size: int = 41,
               ) -> tuple[float, float] | None:
    """The place in `second` of the `size` patch around `xy` of `first`: `xy` moved by the
    whole pixels the patch moved (to a pixel); None near the border."""
    half, r = size // 2, FIND_RADIUS_PX
    x, y = int(round(xy[0])), int(round(xy[1]))
    if not (half + r <= x < first.shape[1] - half - r and half + r <= y < first.shape[0] - half - r):
        return None
    template = first[y - half:y + half + 1, x - half:x + half + 1]
    window = second[y - half - r:y + half + r + 1, x - half - r:x + half + r + 1]
    _, _, _, (ix, iy) = cv2.minMaxLoc(cv2.matchTemplate(window, template, cv2.TM_CCOEFF_NORMED))
    return xy[0] + ix - r, xy[1] + iy - r


def random_joints(rng: np.random.Generator) -> dict[str, float]:
    """A pose of the head fixating the room: pan and tilt drawn within most of their range."""
    return {"pan": float(rng.uniform(-30, 30)), "tilt": float(rng.uniform(-18, 18)), "left_eye": 2.5,
            "right_eye": -2.5}


def frames_at(sensor: str, joints: dict[str, float], seed: int, later: dict[str, float] | None = None,
              gap_frames: int = 0) -> tuple[np.ndarray, np.ndarray | None]:
    """The left eye's frame at `joints` once the auto exposure settled there (SETTLE_FRAMES), and,
    with `later`, the frame `gap_frames` after it at those joints (grey float)."""
    config = CameraConfig.from_mapping({"backend": "sim", "eye": "left", "width": 320, "height": 240,
                                        "fps": FPS, "sensor": {"model": sensor}})
    camera = create_camera(config, head=HeadModel.default(320, 240), pose_source=fixed_pose(**joints),
                           scene=shared_scene(seed, False), clock=ManualClock())
    assert isinstance(camera, SimulatedCamera)
    with camera:
        for n in range(SETTLE_FRAMES):
            first = camera.render(joints, n / FPS)
        second = None if later is None else camera.render(later, (SETTLE_FRAMES - 1 + gap_frames) / FPS)
    return first.astype(np.float32), None if second is None else second.astype(np.float32)


def settled_frame(sensor: str, rng: np.random.Generator, seed: int) -> np.ndarray:
    """The left eye's settled frame at a random pose (`random_joints`)."""
    return frames_at(sensor, random_joints(rng), seed)[0]


def margin_changes(sensor: str, poses: int, pixels: int, seed: int, gap_frames: int,
                   view_deg: float = LookController.SAME_VIEW_DEG) -> np.ndarray:
    """|margin in the second frame - margin in the first| for the patches near the threshold."""
    rng = np.random.default_rng(seed)
    params = LookParams()
    changes: list[float] = []
    for _ in range(poses):
        joints = random_joints(rng)
        moved = {**joints, "pan": joints["pan"] + float(rng.uniform(-view_deg, view_deg)),
                 "tilt": joints["tilt"] + float(rng.uniform(-view_deg, view_deg))}
        first, second = frames_at(sensor, joints, seed, moved, gap_frames)
        assert second is not None
        for _ in range(pixels):
            xy = (float(rng.uniform(40, 280)), float(rng.uniform(40, 200)))
            peaks, _ = own_view_peaks(first, xy, params)
            if peaks is None or peaks[0] - peaks[1] >= NEAR_THRESHOLD:
                continue
            there = _where_now(first, second, xy)
            if there is None:
                continue
            later, _ = own_view_peaks(second, there, params)
            if later is not None:
                changes.append(abs((later[0] - later[1]) - (peaks[0] - peaks[1])))
    return np.asarray(changes)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--sensor", default="uvc_webcam", help="the simulated camera model (default uvc_webcam)")
    parser.add_argument("--poses", type=int, default=40)
    parser.add_argument("--pixels", type=int, default=40, help="random pixels tried a pose")
    parser.add_argument("--gap-frames", type=int, default=10, help="frames between the two exposures")
    parser.add_argument("--view-deg", type=float, default=LookController.SAME_VIEW_DEG,
                        help="the second frame's pan and tilt within this of the first's (default %(default)s)")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    changes = margin_changes(args.sensor, args.poses, args.pixels, args.seed, args.gap_frames, args.view_deg)
    if changes.size == 0:
        raise SystemExit("no textured pixel near the threshold: try more --poses")
    p50, p90, p99 = np.percentile(changes, [50, 90, 99])
    print(f"{args.sensor}: {changes.size} patches with an own-view margin below {NEAR_THRESHOLD}; the margin moved "
          f"by median {p50:.3f}, p90 {p90:.3f}, p99 {p99:.3f}, max {changes.max():.3f}")


if __name__ == "__main__":
    main()
