"""Ground truth for image tests on the simulated head: what is on a fovea, and where it was.

The renderer knows the room only as boxes; a single ray's first surface is a slab test per
box, done here for one ray at a time (tests only need a few hundred).
"""
from __future__ import annotations

import numpy as np

from calib_free.sim.head_model import HeadModel
from drivers.sim.scene import Scene
from headctl.service.head import joints_of as joints  # noqa: F401 (re-exported for the tests)


def first_surface(scene: Scene, origin: np.ndarray, direction: np.ndarray) -> np.ndarray:
    """The first point of the scene a ray from `origin` along `direction` meets."""
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / direction
        room = np.maximum((scene.lo[0] - origin) * inv, (scene.hi[0] - origin) * inv)
        best = float(np.min(room))  # the room is seen from inside: its nearest exit plane
        for b in range(1, len(scene.lo)):
            a1, a2 = (scene.lo[b] - origin) * inv, (scene.hi[b] - origin) * inv
            t_in, t_out = float(np.max(np.minimum(a1, a2))), float(np.min(np.maximum(a1, a2)))
            if 1e-6 < t_in < t_out and t_in < best:
                best = t_in
    return origin + best * direction


def texture_at(scene: Scene, point: np.ndarray) -> str:
    """The texture kind of the (innermost) box whose surface holds `point`."""
    for i in range(len(scene.boxes) - 1, -1, -1):
        if np.all(point >= scene.lo[i] - 1e-6) and np.all(point <= scene.hi[i] + 1e-6):
            return scene.boxes[i].texture
    return scene.boxes[0].texture


def axis_point(scene: Scene, rotation: np.ndarray, centre: np.ndarray) -> np.ndarray:
    """The world point on an eye's fovea: its optical axis' first surface (an eye frame of
    `HeadModel.eye_frames`: world-to-camera rotation and centre)."""
    return first_surface(scene, centre, rotation.T @ np.array([0.0, 0.0, 1.0]))


def foveal_point(model: HeadModel, scene: Scene, pose: np.ndarray) -> np.ndarray:
    """The world point on the left fovea (the left optical axis' first surface) at `pose`."""
    (rotation, centre), _ = model.eye_frames(pose)
    return axis_point(scene, rotation, centre)


def hidden_from(scene: Scene, centre: np.ndarray, point: np.ndarray, tolerance_m: float) -> bool:
    """Whether a surface more than `tolerance_m` nearer than `point` lies between `centre` and it."""
    distance = float(np.linalg.norm(point - centre))
    hit = first_surface(scene, centre, (point - centre) / distance)
    return float(np.linalg.norm(hit - centre)) < distance - tolerance_m


def radial_tangential_error(measured_xy: np.ndarray, true_xy: np.ndarray,
                            centre: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Image positions' errors split about the image centre: (the truth's eccentricity, the
    error along the radius, positive outwards, and across it), each (n,) for (n, 2) inputs."""
    offset = np.atleast_2d(true_xy) - centre
    eccentricity = np.hypot(*offset.T)
    unit = offset / np.maximum(eccentricity, 1e-9)[:, None]
    error = np.atleast_2d(measured_xy) - np.atleast_2d(true_xy)
    radial = np.sum(error * unit, axis=1)
    tangential = error[:, 1] * unit[:, 0] - error[:, 0] * unit[:, 1]
    return eccentricity, radial, tangential
