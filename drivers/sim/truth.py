"""What benchmarks and tests may ask of the simulated world: the first surface a ray meets, the
texture at a point, what is on an eye's fovea, and whether a point is hidden from an eye.

The renderer knows the room only as boxes; a single ray's first surface is a slab test per
box, done here for one ray at a time (the callers need a few hundred to a few thousand).
Eye frames are those of `HeadGeometry.eye_frames_from_joints`: world-to-camera rotation and
optical centre.
"""
from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from drivers.sim.scene import HeadGeometry, Lens, Scene

OPTICAL_AXIS = np.array([0.0, 0.0, 1.0])  # in camera coordinates


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
    point: np.ndarray = origin + best * direction
    return point


def texture_at(scene: Scene, point: np.ndarray) -> str:
    """The texture kind of the (innermost) box whose surface holds `point`."""
    for i in range(len(scene.boxes) - 1, -1, -1):
        if np.all(point >= scene.lo[i] - 1e-6) and np.all(point <= scene.hi[i] + 1e-6):
            return scene.boxes[i].texture
    return scene.boxes[0].texture


def axis_point(scene: Scene, rotation: np.ndarray, centre: np.ndarray) -> np.ndarray:
    """The world point on an eye's fovea: its optical axis' first surface, for the eye frame
    (`rotation`, `centre`)."""
    return first_surface(scene, centre, rotation.T @ OPTICAL_AXIS)


def centre_point(scene: Scene, lens: Lens, rotation: np.ndarray, centre: np.ndarray) -> np.ndarray:
    """The world point on the image centre of an eye that sees through `lens` (where
    correspondence takes its foveal patch), for the eye frame (`rotation`, `centre`): the
    optical axis' first surface when the lens's principal point is the image centre, elsewhere
    for a unit's lens off it (`drivers.sim.camera_effects.lens_error`)."""
    middle = np.array([[(lens.width - 1) / 2.0, (lens.height - 1) / 2.0]])
    return first_surface(scene, centre, rotation.T @ lens.unproject(middle)[0])


def foveal_point(geometry: HeadGeometry, scene: Scene, joints: Mapping[str, float], eye: int = 0) -> np.ndarray:
    """The world point on an eye's fovea (0 left, 1 right) at joint angles {pan, tilt,
    left_eye, right_eye} (degrees)."""
    frames = geometry.eye_frames_from_joints(joints["pan"], joints["tilt"], joints["left_eye"], joints["right_eye"])
    return axis_point(scene, *frames[eye])


def hidden_from(scene: Scene, centre: np.ndarray, point: np.ndarray, tolerance_m: float) -> bool:
    """Whether a surface more than `tolerance_m` nearer than `point` lies between `centre` and it."""
    distance = float(np.linalg.norm(point - centre))
    hit = first_surface(scene, centre, (point - centre) / distance)
    return float(np.linalg.norm(hit - centre)) < distance - tolerance_m
