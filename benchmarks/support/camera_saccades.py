"""Rendered saccade cases whose images the simulated cameras make, with their whole pipeline.

`camera_cases` gives the cases of `headctl.experiments.saccades.saccade_cases` (the same
saccades for a seed, the same truth), each image taken by a pair of simulated cameras
(`drivers.sim.camera.SimulatedCamera.render`, the function the service's and the online
experiments' images come from): through each unit's lens, lit by the room's light, exposed
at the auto exposure's (or a locked, or a manual) exposure and gain, through the sensor
(vignetting, noise, the unit's response) and the MJPEG round trip, as a `CameraSetup`
configures them. `noise_std` grey levels are added to every image as the online experiments
add them to the cameras' renders (`headctl.service.head.RenderedPairSource`), after the MJPEG
round trip.

Timeline, on a manual clock at 30 fps: saccade n's pre-fixation images are exposed at
2 n + 1 s (plus up to a flicker period, so that the flicker's phase varies), its post-fixation
images `GAP_S` later, drawn per saccade (a saccade of up to 15 deg at 240 deg/s, the servos
settling and a step or two of fine vergence; `headctl.experiments.online` spends about that
on a fixation). The 2 s between saccades let a running auto exposure settle on each
pre-fixation view (60 frames, which it runs as if it had seen that view, as a streaming
camera's would; the frame before the pre-fixation image is rendered, so that even the first
saccade's is taken settled). With `lamp_steps` the room's lamp is switched between the two images of
every saccade (on, off, on...).
"""
from __future__ import annotations

import enum
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from calib_free.sim.head_model import HeadModel
from drivers.cameras.camera import create_camera
from drivers.cameras.config import CameraConfig, SceneConfig
from drivers.clock import ManualClock
from drivers.config.reader import read_config
from drivers.sim.camera import SimulatedCamera, fixed_pose
from drivers.sim.room import room_scene
from drivers.sim.scene import Lens, shared_scene
from headctl.experiments.saccades import Images, SaccadeCase, saccade_cases

FPS = 30.0
SACCADE_PERIOD_S = 2.0  # one saccade every 2 s of the cameras' clock
FLICKER_SPREAD_S = 0.01  # the pre image's start jittered by one flicker period (100 Hz)
GAP_S = (0.15, 0.4)  # pre to post image, uniform in this range
_TIMELINE_STREAM = 0x7133  # the timeline's and the exposure changes' random stream


class Exposure(enum.Enum):
    """What the cameras' exposure does between a saccade's two images."""

    RUNNING = "running"  # the auto exposure follows the view (`exposure_control: auto`)
    LOCKED = "locked"  # held from the frame before the pre image to the post image (`lock_per_fixation`)


@dataclass(frozen=True)
class CameraSetup:
    """How both cameras make a saccade's images."""

    sensor: Mapping[str, Any] = field(default_factory=lambda: {"model": "ideal"})  # `cameras.<eye>.sensor`
    noise_std: float = 2.0  # grey levels added to each image (configs/sim-ideal.yaml's cameras')
    exposure: Exposure = Exposure.RUNNING
    light: Mapping[str, Any] | None = None  # `cameras.scene.light` (None: constant)
    lamp_steps: bool = False  # the lamp switched between the two images of every saccade
    exposure_us: float | None = None  # a manual exposure (`cameras.<eye>.exposure_us`) ...
    gain_db: float | None = None  # ... and gain
    # With a manual exposure: the post image's exposure over the pre image's, drawn per saccade
    # and eye log-uniformly within (low, high), as an auto exposure that moved between them.
    exposure_change: tuple[float, float] | None = None

    def __post_init__(self) -> None:
        if self.exposure_change is not None and self.exposure_us is None:
            raise ValueError("exposure_change needs a manual exposure_us to change")


@dataclass(frozen=True)
class Timeline:
    """When each saccade's pre- and post-fixation images are exposed (clock seconds)."""

    pre_s: np.ndarray
    post_s: np.ndarray
    exposure_ratio: np.ndarray  # (saccades, 2): the post image's exposure over the pre image's, per eye

    @classmethod
    def draw(cls, count: int, seed: int, exposure_change: tuple[float, float] | None = None) -> "Timeline":
        rng = np.random.default_rng((seed, _TIMELINE_STREAM))
        pre_s = SACCADE_PERIOD_S * np.arange(count) + 1.0 + rng.uniform(0.0, FLICKER_SPREAD_S, count)
        post_s = pre_s + rng.uniform(*GAP_S, count)
        low, high = exposure_change or (1.0, 1.0)
        ratio = np.exp(rng.uniform(math.log(low), math.log(high), (count, 2)))
        return cls(pre_s, post_s, ratio)

    @property
    def between_s(self) -> tuple[float, ...]:
        """Halfway between each saccade's two images."""
        return tuple(float(t) for t in (self.pre_s + self.post_s) / 2)


class CameraShots:
    """Two simulated cameras (a `SaccadeShots`) taking each saccade's images on `timeline`."""

    def __init__(self, setup: CameraSetup, model: HeadModel, seed: int, timeline: Timeline,
                 room: str = "photos") -> None:
        self.setup, self.timeline = setup, timeline
        self.clock = ManualClock()
        light = dict(setup.light or {})
        if setup.lamp_steps:
            light["lamp_switch_times_s"] = list(timeline.between_s)
        scene_config = read_config(SceneConfig, {"room": room, "light": light}, "cameras.scene")
        self.scene = room_scene(scene_config, seed, colour=False, clock=self.clock)
        self.cameras: list[SimulatedCamera] = []
        self._streamed = False  # whether the cameras have taken a frame
        for eye in ("left", "right"):
            keys: dict[str, Any] = {"backend": "sim", "eye": eye, "width": model.width, "height": model.height,
                                    "fps": FPS, "image": "grey", "seed": seed, "sensor": dict(setup.sensor)}
            keys.update({k: v for k, v in (("exposure_us", setup.exposure_us), ("gain_db", setup.gain_db))
                         if v is not None})
            config = CameraConfig.from_mapping(keys, key_path=f"cameras.{eye}")
            camera = create_camera(config, head=model, pose_source=fixed_pose(), scene=self.scene,
                                   clock=self.clock, paced_by_clock=False)
            assert isinstance(camera, SimulatedCamera)
            self.cameras.append(camera)

    @property
    def lenses(self) -> tuple[Lens, Lens]:
        return self.cameras[0].unit_lens, self.cameras[1].unit_lens

    def __enter__(self) -> "CameraShots":
        for camera in self.cameras:
            camera.open()
        return self

    def __exit__(self, *exc: object) -> None:
        for camera in self.cameras:
            camera.close()

    def shoot(self, index: int, pre: Mapping[str, float], post: Mapping[str, float]) -> tuple[Images, Images]:
        t_pre, t_post = float(self.timeline.pre_s[index]), float(self.timeline.post_s[index])
        taken: list[tuple[np.ndarray, np.ndarray]] = []
        for eye, camera in enumerate(self.cameras):
            if camera.sensor.auto_exposure:  # the frame before, which its auto exposure meters: settled on this view
                if not self._streamed:  # its first frame: the auto exposure starts from there
                    camera.render(pre, t_pre - SACCADE_PERIOD_S / 2)
                camera.render(pre, t_pre - 1.0 / FPS)
            if self.setup.exposure is Exposure.LOCKED:
                camera.lock_exposure()
            base_us = self.setup.exposure_us
            if base_us is not None:
                camera.set_exposure_us(base_us)
            before = camera.render(pre, t_pre)
            if base_us is not None:
                camera.set_exposure_us(base_us * float(self.timeline.exposure_ratio[index, eye]))
            after = camera.render(post, t_post)
            if self.setup.exposure is Exposure.LOCKED:
                camera.unlock_exposure()
            taken.append((before, after))
        self._streamed = True
        (pre_l, post_l), (pre_r, post_r) = taken
        return (pre_l, pre_r), (post_l, post_r)


def camera_cases(setup: CameraSetup, model: HeadModel, seed: int, count: int, room: str = "photos") -> list[SaccadeCase]:
    """Scene seed `seed`'s `count` saccades (those of `photometric`'s and `saccade_cases`'
    seed 100 + `seed`), their images made by the cameras of `setup` (camera seed `seed`)."""
    timeline = Timeline.draw(count, seed, setup.exposure_change)
    with CameraShots(setup, model, seed, timeline, room) as shots:
        return saccade_cases(shared_scene(seed, False, room), model, count, seed=100 + seed,
                             noise_std=setup.noise_std, shots=shots)
