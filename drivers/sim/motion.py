"""Moving objects in the simulated room: textured cubes sweeping around the head.

A `MovingObject` is a cube at a fixed distance from a point of the head's pan axis (at the
eyes' height) that sweeps back and
forth along an arc (a great circle through its centre direction, slanted by `direction_deg`
from the horizontal) at a constant angular speed, slowing down and turning at the arc's ends
with a bounded angular acceleration, so that pursuit can be measured at a known target speed.
`SceneMotion` holds a scene's moving boxes (any `Mover`: these cubes, the room's passers-by of
`drivers.sim.passers_by`) and gives the renderer their translations at a frame's time
(`drivers.sim.scene.SceneMotion`; by default the clock's now); a box keeps its orientation
(boxes are axis-aligned) and carries its texture with it.

World frame as in `drivers.sim.scene`: x forward, y left, z up, metres; azimuth + to the
head's left, elevation + up.
"""
from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Protocol

import cv2
import numpy as np

from drivers.clock import SYSTEM_CLOCK, Clock
from drivers.config.reader import check_settings, setting
from drivers.sim.scene import Box, Scene, TextureKind

# "speckle" (this module's): detail at every scale from 6 mm to 3 cm, so that a small
# object's patch has something to correlate wherever it is taken; the rest: the room's kinds.
TEXTURES = ("speckle", "rich", "checker", "stripes", "uniform")
_BORDER_PX = 2  # as the scene's atlas: replicated texels around each face


class Mover(Protocol):
    """A box that moves through the scene: where it is placed, and how far it has moved."""

    @property
    def name(self) -> str: ...
    @property
    def texture(self) -> str: ...  # one of TEXTURES ("speckle" is painted once the scene is made)

    def box(self) -> Box:
        """The box where the scene places it."""

    def offset(self, t_s: float) -> np.ndarray:
        """(3,) metres it has moved from `box()` at `t_s` seconds of motion; NaN: out of the world."""


def mover_box(name: str, centre: np.ndarray, half_m: np.ndarray, texture: str, texels_per_m: float) -> Box:
    """A mover's box around `centre` (half extents `half_m`); a speckled one is painted over
    once the scene is made (`moving_scene`)."""
    kind: TextureKind = "uniform" if texture == "speckle" else texture  # type: ignore[assignment]
    lo, hi = centre - half_m, centre + half_m
    return Box(name, (float(lo[0]), float(lo[1]), float(lo[2])), (float(hi[0]), float(hi[1]), float(hi[2])),
               kind, texels_per_m)


@dataclass(frozen=True)
class MovingObject:
    """One moving cube (an entry of the config's `sim_objects:` list)."""

    name: str = setting("target", expected="a non-empty name")
    size_m: float = setting(0.12, above=0.0, hi=1.0, expected="a cube side in (0, 1] m")
    distance_m: float = setting(0.45, lo=0.2, hi=3.0, expected="a distance from the arc's centre in [0.2, 3] m")
    # The arc's centre, above the pan axis: the simulated head's eyes are 6 cm up.
    height_m: float = setting(0.06, lo=-1.0, hi=1.0, expected="a height in [-1, 1] m")
    azimuth_deg: float = setting(0.0, lo=-90.0, hi=90.0, expected="the sweep's centre, [-90, 90] deg")
    elevation_deg: float = setting(0.0, lo=-60.0, hi=60.0, expected="the sweep's centre, [-60, 60] deg")
    sweep_deg: float = setting(50.0, lo=0.0, hi=120.0, expected="the sweep's full extent, [0, 120] deg")
    direction_deg: float = setting(0.0, lo=-90.0, hi=90.0,
                                   expected="the sweep's slant from the horizontal, [-90, 90] deg")
    speed_deg_s: float = setting(10.0, lo=0.0, hi=360.0, expected="an angular speed in [0, 360] deg/s")
    turn_deg_s2: float = setting(400.0, above=0.0, hi=1e6, expected="an angular acceleration in (0, 1e6] deg/s^2")
    texture: str = setting("speckle", choices=TEXTURES, expected=" or ".join(TEXTURES))
    texels_per_m: float = setting(600.0, lo=50.0, hi=5000.0, expected="a texture density in [50, 5000] texels/m")

    def __post_init__(self) -> None:
        check_settings(self)

    # -- the path ---------------------------------------------------------------------------
    def _profile(self) -> tuple[float, float, float, float]:
        """(half-sweep A, top speed, time to reach it, time of one pass from -A to +A)."""
        half = self.sweep_deg / 2.0
        accel = self.turn_deg_s2
        top = min(self.speed_deg_s, math.sqrt(accel * 2 * half)) if half > 0 else 0.0
        if top <= 0:
            return half, 0.0, 0.0, math.inf
        ramp_s = top / accel
        cruise_s = (2 * half - top * ramp_s) / top
        return half, top, ramp_s, 2 * ramp_s + cruise_s

    def _along_pass(self, tau: float) -> float:
        """The position along the arc (deg from -A) `tau` seconds into a pass from -A to +A."""
        half, top, ramp_s, pass_s = self._profile()
        accel = self.turn_deg_s2
        if tau <= ramp_s:
            return 0.5 * accel * tau * tau
        if tau <= pass_s - ramp_s:
            return 0.5 * top * ramp_s + top * (tau - ramp_s)
        rest = pass_s - tau
        return 2 * half - 0.5 * accel * rest * rest

    def angle_along(self, t_s: float) -> float:
        """Deg along the arc from its centre at `t_s` seconds after the start (at the centre,
        moving toward + azimuth / elevation), within +-sweep/2."""
        half, top, _, pass_s = self._profile()
        if top <= 0 or not math.isfinite(pass_s):
            return 0.0
        # The pass from -A to +A is symmetric: it crosses the centre half-way through.
        phase = (t_s + pass_s / 2.0) % (2 * pass_s)
        if phase < pass_s:
            return self._along_pass(phase) - half
        return half - self._along_pass(phase - pass_s)

    def direction(self, t_s: float) -> tuple[float, float]:
        """(azimuth, elevation) deg of the cube's centre, seen from the pan axis, at `t_s`."""
        s = self.angle_along(t_s)
        slant = math.radians(self.direction_deg)
        return self.azimuth_deg + s * math.cos(slant), self.elevation_deg + s * math.sin(slant)

    def centre(self, t_s: float) -> np.ndarray:
        """The cube's centre (world, m) at `t_s`."""
        azimuth, elevation = (math.radians(a) for a in self.direction(t_s))
        return np.array([0.0, 0.0, self.height_m]) + self.distance_m * np.array(
            [math.cos(elevation) * math.cos(azimuth), math.cos(elevation) * math.sin(azimuth), math.sin(elevation)])

    def box(self) -> Box:
        """The cube where it starts (the arc's centre); `SceneMotion` moves it from there."""
        return mover_box(self.name, self.centre(0.0), np.full(3, self.size_m / 2.0), self.texture, self.texels_per_m)

    def offset(self, t_s: float) -> np.ndarray:
        """How far the cube has moved from where it starts at `t_s`."""
        moved: np.ndarray = self.centre(t_s) - self.centre(0.0)
        return moved


class SceneMotion:
    """The moving boxes of a scene: `box_offsets(time_s)` is each box's translation at a time
    of the clock (default: now), counted from `start_s` (default: the clock's time when made);
    before `start_s` every object rests where it is at 0 s of motion (a later `start_s` holds
    them there). A row of NaN: that box is out of the world (a passer-by between crossings)."""

    def __init__(self, objects: Sequence[tuple[int, Mover]], n_boxes: int, clock: Clock = SYSTEM_CLOCK,
                 start_s: float | None = None) -> None:
        for index, obj in objects:
            if not 0 < index < n_boxes:
                raise ValueError(f"moving object {obj.name!r}: box index {index} is not a box of the scene "
                                 f"(1 to {n_boxes - 1}; the room cannot move)")
        self.objects = list(objects)
        self.n_boxes = n_boxes
        self.clock = clock
        self.start_s = clock.monotonic() if start_s is None else start_s

    def elapsed_s(self, time_s: float | None = None) -> float:
        """Seconds of motion at `time_s` (default: now): 0 until `start_s`."""
        return max(0.0, (self.clock.monotonic() if time_s is None else time_s) - self.start_s)

    def box_offsets(self, time_s: float | None = None) -> np.ndarray | None:
        if not self.objects:
            return None
        t = self.elapsed_s(time_s)
        offsets = np.zeros((self.n_boxes, 3), np.float32)
        for index, obj in self.objects:
            offsets[index] = obj.offset(t)
        return offsets

    def offset_of(self, name: str, time_s: float | None = None) -> np.ndarray:
        """The named object's translation (m) at `time_s` (default: now)."""
        for _, obj in self.objects:
            if obj.name == name:
                return obj.offset(self.elapsed_s(time_s))
        raise KeyError(f"no moving object named {name!r}")


def with_moving_objects(boxes: Sequence[Box], objects: Sequence[Mover]) -> tuple[list[Box], list[tuple[int, Mover]]]:
    """The boxes of a room with the objects' cubes appended, and each object's box index."""
    out = list(boxes)
    indices = []
    for obj in objects:
        indices.append((len(out), obj))
        out.append(obj.box())
    return out, indices


def moving_scene(base: Scene, objects: Sequence[Mover], clock: Clock = SYSTEM_CLOCK) -> Scene:
    """`base`'s room (the same boxes, seed, textures and light) with `objects` moving in it from now."""
    boxes, indices = with_moving_objects(base.boxes, objects)
    photos = getattr(base, "photos", None)  # a photo room's photographs, to paper it alike
    extra: dict[str, Any] = {"photos": photos} if photos is not None else {}
    scene = Scene(boxes, seed=base.seed, colour=base.colour, **extra)
    scene.light = base.light
    for index, obj in indices:
        if obj.texture == "speckle":
            _paint_speckle(scene, index, np.random.default_rng((base.seed, index)))
    scene.motion = SceneMotion(indices, len(boxes), clock)
    return scene


def _speckle(rng: np.random.Generator, height: int, width: int, texels_per_m: float) -> np.ndarray:
    """Grey 0..255: value noise at 6, 12 and 30 mm cells plus dark and bright dots. Nothing finer:
    at half a metre a pixel spans 2 mm, and finer texture would alias differently in each eye."""
    out = np.zeros((height, width), np.float32)
    for cell_m, amplitude in ((0.03, 35.0), (0.012, 30.0), (0.006, 18.0)):
        cell = max(1.0, cell_m * texels_per_m)
        small = rng.standard_normal((int(height / cell) + 2, int(width / cell) + 2)).astype(np.float32)
        out += amplitude * cv2.resize(small, (width, height), interpolation=cv2.INTER_CUBIC)
    for _ in range(int(height * width / (0.012 * texels_per_m) ** 2)):
        centre = (int(rng.integers(0, width)), int(rng.integers(0, height)))
        radius = int(rng.integers(max(1, int(0.003 * texels_per_m)), max(2, int(0.008 * texels_per_m))))
        cv2.circle(out, centre, radius, float(rng.choice((-80.0, 80.0))), thickness=-1)
    return np.clip(128 + out, 0, 255)


def _paint_speckle(scene: Scene, index: int, rng: np.random.Generator) -> None:
    """Paint box `index`'s faces in the scene's atlas with `_speckle` (both atlases)."""
    box = scene.boxes[index]
    for face in scene.faces:
        if face.box != index:
            continue
        w, h = face.size_px
        grey = cv2.copyMakeBorder(_speckle(rng, h, w, box.texels_per_m), _BORDER_PX, _BORDER_PX, _BORDER_PX,
                                  _BORDER_PX, cv2.BORDER_REPLICATE).astype(np.uint8)
        x0, y0 = face.origin_px[0] - _BORDER_PX, face.origin_px[1] - _BORDER_PX
        rows, cols = slice(y0, y0 + grey.shape[0]), slice(x0, x0 + grey.shape[1])
        if scene.atlas.ndim == 3:
            scene.atlas[rows, cols] = grey[:, :, None]
            scene.sampling_atlas[rows, cols, :3] = grey[:, :, None]
        else:
            scene.atlas[rows, cols] = grey  # a grey scene samples the atlas itself
