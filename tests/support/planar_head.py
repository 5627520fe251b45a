"""A head that looks at a textured plane, and a linear gaze map for it: closed loops without a renderer.

`PlanarHead` (a `calib_free.gaze.fixation.GazeHead`) shows, at pose (pan, tilt, vergence), the
window of a large texture centred `PX_PER_DEG` pixels per degree away from its middle: pan +
moves the view left, tilt + up. The right image is the left one shifted by the disparity
`DISPARITY_PX_PER_DEG * (vergence - PLANE_VERGENCE_DEG)` (every point of the plane has it),
so fine vergence has something to converge. `LinearMap` (a `MapReader`) commands
`gain` times the exact move: with gain < 1 every saccade falls short, as a young map's do.
Where a texel of the plane is in an image is exact (`image_position`), the truth a test
compares a look's figures with.
"""
from __future__ import annotations

import cv2
import numpy as np

from calib_free.errors import OutOfRangeError

WIDTH, HEIGHT = 320, 240
PX_PER_DEG = 4.0
DISPARITY_PX_PER_DEG = 5.0
PLANE_VERGENCE_DEG = 8.0
PLANE_SIZE = (1000, 800)  # (w, h) texels


def rich_texture(seed: int = 0, size: tuple[int, int] = PLANE_SIZE) -> np.ndarray:
    """Smooth noise of a few scales plus rectangles: texture a patch can be found by."""
    rng = np.random.default_rng(seed)
    w, h = size
    out = np.zeros((h, w), np.float32)
    for cell, amplitude in ((60, 50.0), (20, 40.0), (6, 30.0)):
        small = rng.standard_normal((h // cell + 2, w // cell + 2)).astype(np.float32)
        out += amplitude * cv2.resize(small, (w, h), interpolation=cv2.INTER_CUBIC)
    for _ in range(400):
        x0, y0, s = int(rng.integers(0, w)), int(rng.integers(0, h)), int(rng.integers(3, 14))
        cv2.rectangle(out, (x0, y0), (x0 + s, y0 + int(rng.integers(3, 14))), float(rng.uniform(-80, 80)), -1)
    return np.clip(128 + out, 0, 255).astype(np.float32)


class PlanarHead:
    """A `GazeHead` over a textured plane (see the module doc); records every pose it is sent to."""

    def __init__(self, plane: np.ndarray | None = None, pose: tuple[float, float, float] = (0.0, 0.0, 8.0)) -> None:
        self.plane = rich_texture() if plane is None else plane
        self.pose = np.asarray(pose, dtype=float)
        self.pose_low, self.pose_high = np.array([-40.0, -25.0, 1.0]), np.array([40.0, 25.0, 20.0])
        self.moves: list[np.ndarray] = []
        self.on_move = None  # called with the pose after every move (a test changes the plane there)

    # where the view is
    def view_centre(self, pose: np.ndarray | None = None) -> np.ndarray:
        """The texel on the left fovea at `pose` (default: now)."""
        pose = self.pose if pose is None else pose
        h, w = self.plane.shape
        return np.array([(w - 1) / 2 - PX_PER_DEG * pose[0], (h - 1) / 2 - PX_PER_DEG * pose[1]])

    def image_position(self, texel: np.ndarray, pose: np.ndarray | None = None) -> np.ndarray:
        """Where texel (u, v) of the plane is in the left image at `pose` (default: now)."""
        return np.asarray(texel) - self.view_centre(pose) + np.array([(WIDTH - 1) / 2, (HEIGHT - 1) / 2])

    def texel_at(self, xy: tuple[float, float], pose: np.ndarray | None = None) -> np.ndarray:
        return np.asarray(xy, dtype=float) - np.array([(WIDTH - 1) / 2, (HEIGHT - 1) / 2]) + self.view_centre(pose)

    def disparity_px(self) -> float:
        return DISPARITY_PX_PER_DEG * (self.pose[2] - PLANE_VERGENCE_DEG)

    # GazeHead
    def read_pose(self) -> np.ndarray:
        return self.pose.copy()

    def move_to(self, pose: np.ndarray) -> np.ndarray:
        self.pose = np.clip(np.asarray(pose, dtype=float), self.pose_low, self.pose_high)
        self.moves.append(self.pose.copy())
        if self.on_move is not None:
            self.on_move(self)
        return self.pose.copy()

    def verge_to(self, vergence: float) -> float:
        return float(self.move_to(np.array([self.pose[0], self.pose[1], vergence]))[2])

    def wait_settled(self, timeout_s: float, same_rest: bool = False) -> float:
        return 0.0

    def wait_pair(self, after_s: float, timeout_s: float) -> tuple[np.ndarray, np.ndarray]:
        cx, cy = self.view_centre()
        left = cv2.getRectSubPix(self.plane, (WIDTH, HEIGHT), (float(cx), float(cy)))
        right = cv2.getRectSubPix(self.plane, (WIDTH, HEIGHT), (float(cx - self.disparity_px()), float(cy)))
        return left, right


class LinearMap:
    """A `MapReader` for `PlanarHead`: `gain` times the exact command for (x, y, d)."""

    def __init__(self, gain: float = 1.0) -> None:
        self.gain = gain
        self.asked: list[tuple[float, float, float]] = []

    def command(self, position: tuple[float, float, float] | np.ndarray, pose: object = None) -> np.ndarray:
        x, y, d = (float(v) for v in position)
        problem = self.check_position((x, y, d))
        if problem:
            raise OutOfRangeError(problem)
        self.asked.append((x, y, d))
        # Pan + and tilt + move the view left and up: a target right of or below the fovea needs -.
        exact = np.array([-(x - (WIDTH - 1) / 2) / PX_PER_DEG, -(y - (HEIGHT - 1) / 2) / PX_PER_DEG,
                          -d / DISPARITY_PX_PER_DEG])
        return self.gain * exact

    def check_position(self, position: tuple[float, float, float] | np.ndarray) -> str:
        x, y, d = (float(v) for v in position)
        if not (0 <= x <= WIDTH - 1 and 0 <= y <= HEIGHT - 1 and -60 <= d <= 60):
            return f"position x={x:.1f}, y={y:.1f}, d={d:.1f} is outside the map"
        return ""
