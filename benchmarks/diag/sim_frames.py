"""Diagnostic: what the simulated cameras show with the ideal sensor and the UVC webcam's.

Writes `sim-frames.png` into `--out`: both eyes of the generated room at pan 8 deg, tilt -6
deg, vergence 5 deg (320 x 240 grey, seed 0), with the `ideal` sensor (top row) and the
`uvc_webcam` one once its auto exposure has settled (middle row), and the webcam's left eye
while the head pans at 120 deg/s through that pose (bottom left: motion blur and
rolling-shutter skew) beside the ideal camera's still frame there (bottom right).

    .venv/bin/python -m benchmarks.diag.sim_frames --out docs/figures/
"""
from __future__ import annotations

import argparse
from pathlib import Path

import cv2
import numpy as np

from calib_free.sim.head_model import HeadModel
from drivers.cameras.camera import create_camera
from drivers.cameras.config import CameraConfig
from drivers.clock import ManualClock
from drivers.sim.camera import PoseSource, SimulatedCamera, fixed_pose
from drivers.sim.scene import shared_scene

JOINTS = {"pan": 8.0, "tilt": -6.0, "left_eye": 2.5, "right_eye": -2.5}
FPS = 30.0
PAN_RATE_DEG_S = 120.0
SETTLE_FRAMES = 30


class _PanThrough:
    """A timed pose source: the head pans at PAN_RATE_DEG_S, through JOINTS at `at_s`."""

    def __init__(self, at_s: float) -> None:
        self.at_s = at_s

    def at(self, time_s: float) -> dict[str, float]:
        return {**JOINTS, "pan": JOINTS["pan"] + PAN_RATE_DEG_S * (time_s - self.at_s)}

    def __call__(self) -> dict[str, float]:
        return self.at(self.at_s)


def _camera(eye: str, model: str, pose: PoseSource) -> SimulatedCamera:
    config = CameraConfig.from_mapping({"backend": "sim", "eye": eye, "width": 320, "height": 240, "fps": FPS,
                                        "sensor": {"model": model}})
    camera = create_camera(config, head=HeadModel.default(320, 240), pose_source=pose,
                           scene=shared_scene(0, False), clock=ManualClock())
    assert isinstance(camera, SimulatedCamera)
    return camera


def frames() -> dict[str, np.ndarray]:
    """The figure's panels by name."""
    moving_s = SETTLE_FRAMES / FPS
    panels = {}
    for model in ("ideal", "uvc_webcam"):
        for eye in ("left", "right"):
            with _camera(eye, model, fixed_pose(**JOINTS)) as camera:
                image = camera.render(JOINTS, 0.0)
                for n in range(1, SETTLE_FRAMES):  # the auto exposure settles on the still view
                    image = camera.render(JOINTS, n / FPS)
                panels[f"{model}, {eye} eye"] = image
    pose = _PanThrough(moving_s)
    with _camera("left", "uvc_webcam", pose) as camera:
        for n in range(SETTLE_FRAMES):  # settled on the view it pans through
            camera.render(pose.at(moving_s), n / FPS)
        panels[f"uvc_webcam, left, panning {PAN_RATE_DEG_S:.0f} deg/s"] = camera.render(pose.at(moving_s), moving_s)
    with _camera("left", "ideal", fixed_pose(**JOINTS)) as camera:
        panels["ideal, left, still"] = camera.render(JOINTS, moving_s)
    return panels


def montage(panels: dict[str, np.ndarray]) -> np.ndarray:
    """The panels two to a row, each with its name above it."""
    tiles = []
    for name, image in panels.items():
        label = np.full((22, image.shape[1]), 255, np.uint8)
        cv2.putText(label, name, (4, 16), cv2.FONT_HERSHEY_SIMPLEX, 0.45, 0, 1, cv2.LINE_AA)
        tiles.append(cv2.copyMakeBorder(np.vstack([label, image]), 3, 3, 3, 3, cv2.BORDER_CONSTANT, value=255))
    rows = [np.hstack(tiles[i:i + 2]) for i in range(0, len(tiles), 2)]
    return np.vstack(rows)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--out", type=Path, default=Path("docs/figures"), help="folder for sim-frames.png")
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    path = args.out / "sim-frames.png"
    cv2.imwrite(str(path), montage(frames()))
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
