"""Simulated cameras for the tests of the sensor's effects: a camera with a `sensor:` section,
rooms whose view is a flat wall, and timed pose sources that pan at a steady rate."""
from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

from calib_free.sim.head_model import HeadModel
from drivers.cameras.camera import create_camera
from drivers.cameras.config import CameraConfig
from drivers.clock import ManualClock
from drivers.sim.camera import PoseSource, SimulatedCamera, fixed_pose
from drivers.sim.scene import Box, Marker, Scene

REST = {"pan": 0.0, "tilt": 0.0, "left_eye": 0.0, "right_eye": 0.0}


def sim_camera(sensor: Mapping[str, Any], *, eye: str = "left", size: tuple[int, int] = (160, 120),
               image: str = "grey", fps: float = 30.0, seed: int = 0, scene: Scene | None = None,
               pose: PoseSource | None = None, clock: ManualClock | None = None) -> SimulatedCamera:
    """A simulated camera (not opened) with this `sensor:` section, on a manual clock."""
    config = CameraConfig.from_mapping({"backend": "sim", "eye": eye, "width": size[0], "height": size[1],
                                        "fps": fps, "image": image, "seed": seed, "sensor": dict(sensor)},
                                       key_path=f"cameras.{eye}")
    camera = create_camera(config, head=HeadModel.default(*size), pose_source=pose or fixed_pose(),
                           scene=scene, clock=clock or ManualClock(), paced_by_clock=False)
    assert isinstance(camera, SimulatedCamera)
    return camera


def wall_scene(distance_m: float = 0.4, colour: bool = False, markers: Sequence[Marker] = (),
               texture: str = "uniform", half_width_m: float = 20.0, texels_per_m: float = 50.0) -> Scene:
    """A room whose far wall, `distance_m` ahead of the head, fills every eye's whole view (the
    side walls `half_width_m` away: the view's corners, 75 deg off the axis, meet the wall 3.7
    times its distance off the middle), nearly uniform unless `texture` says otherwise."""
    room = Box("room", (-1.0, -half_width_m, -half_width_m), (distance_m, half_width_m, half_width_m),
               texture, texels_per_m, inside=True)  # type: ignore[arg-type]
    return Scene([room], seed=1, colour=colour, markers=markers)


class PanningPose:
    """A timed pose source: the head pans at `rate_deg_s` from `start_s` (still before)."""

    def __init__(self, rate_deg_s: float, start_s: float = 0.0, base: Mapping[str, float] = REST) -> None:
        self.rate_deg_s, self.start_s, self.base = rate_deg_s, start_s, dict(base)

    def at(self, time_s: float) -> dict[str, float]:
        return {**self.base, "pan": self.base["pan"] + self.rate_deg_s * max(0.0, time_s - self.start_s)}

    def __call__(self) -> dict[str, float]:
        return self.at(self.start_s)
