"""People walking through the simulated room: person-sized slabs crossing the view at walking speed.

A passer-by enters through the room's right wall (-y) or its left wall (+y), walks straight
across at `speed_m_s`, `distance_m` ahead of the head (x, drawn per crossing from a range), and
leaves through the other wall; on the floor, `width_m` across its path, `depth_m` along x and
`height_m` tall (at most the room's height). Crossings begin at random times, a Poisson
process of `rate_per_min` from the motion's start, each taken by the first of `max_at_once`
slabs free then (a crossing none is free for does not happen). Between crossings a slab is
out of the world: `offset` gives NaN, and the renderer skips it. Its box at rest lies just
outside the room, so surfaces looked up at rest (`drivers.sim.truth`) never meet it.

Every random number comes from generators seeded by the room's seed, drawn in order as far as
asked: deterministic per seed. The numbers of the presets and where they come from:
docs/sim-world.md, section "Room".
"""
from __future__ import annotations

import bisect
import math
import threading
from dataclasses import dataclass
from typing import ClassVar, Literal

import numpy as np

from drivers.config.presets import resolve
from drivers.config.reader import check_settings, setting
from drivers.errors import CameraConfigError
from drivers.sim.motion import TEXTURES, mover_box
from drivers.sim.scene import Box

_PARKED_GAP_M = 0.05  # how far outside the room a slab waits between crossings


@dataclass(frozen=True)
class PassersByParams:
    """The values of a passers-by preset, every one set (`PassersByConfig` gives them)."""

    rate_per_min: float
    speed_m_s: float
    width_m: float
    depth_m: float
    height_m: float
    distance_m: tuple[float, float]
    texture: str
    max_at_once: int


# none: nobody walks by (the other values are home's, so `rate_per_min` alone starts them);
# home: now and then an adult crosses the room at an indoor walking pace.
PASSERS_PRESETS: dict[str, PassersByParams] = {
    "none": PassersByParams(rate_per_min=0.0, speed_m_s=1.2, width_m=0.45, depth_m=0.25, height_m=1.7,
                            distance_m=(1.2, 2.8), texture="rich", max_at_once=2),
    "home": PassersByParams(rate_per_min=1.0, speed_m_s=1.2, width_m=0.45, depth_m=0.25, height_m=1.7,
                            distance_m=(1.2, 2.8), texture="rich", max_at_once=2),
}


def _range_ok(r: tuple[float, float]) -> bool:
    return 0.2 <= r[0] <= r[1] <= 50.0


@dataclass(frozen=True)
class PassersByConfig:
    """`cameras.scene.passers_by`: the preset `model` names, each key given (not None) in its place."""

    model: Literal["none", "home"] = "none"
    rate_per_min: float | None = setting(None, lo=0.0, hi=600.0, expected="crossings a minute, [0, 600]")
    speed_m_s: float | None = setting(None, above=0.0, hi=20.0, expected="a walking speed in (0, 20] m/s")
    width_m: float | None = setting(None, above=0.0, hi=5.0, expected="a width in (0, 5] m")
    depth_m: float | None = setting(None, above=0.0, hi=5.0, expected="a depth in (0, 5] m")
    height_m: float | None = setting(None, above=0.0, hi=5.0, expected="a height in (0, 5] m")
    distance_m: tuple[float, float] | None = setting(
        None, check=_range_ok, expected="[nearest, farthest] m ahead of the head, 0.2 <= nearest <= farthest <= 50")
    texture: str | None = setting(None, choices=TEXTURES, expected=" or ".join(TEXTURES))
    max_at_once: int | None = setting(None, lo=1, hi=8, expected="1 to 8 people in the room at once")

    CONFIG_ERROR: ClassVar[type[CameraConfigError]] = CameraConfigError

    def __post_init__(self) -> None:
        check_settings(self)

    @property
    def params(self) -> PassersByParams:
        return resolve(self, PASSERS_PRESETS)


@dataclass(frozen=True)
class Crossing:
    """One walk across the room, seconds after the motion's start."""

    start_s: float
    slot: int  # which slab walks
    x_m: float  # how far ahead of the head
    direction: int  # +1: toward +y (from the head's right to its left), -1: the other way
    duration_s: float


class Crowd:
    """The crossings of `params` through the room `room` (a scene's first box), from `seed`."""

    def __init__(self, params: PassersByParams, room: Box, seed: int) -> None:
        self.params = params
        self.room = room
        self._rng = np.random.default_rng((seed, 0x22))
        self._lock = threading.Lock()
        self._drawn_until = 0.0  # the time of the last arrival drawn
        self._free_at = [0.0] * params.max_at_once  # when each slab is back outside
        self._by_slot: list[list[Crossing]] = [[] for _ in range(params.max_at_once)]
        self._starts: list[list[float]] = [[] for _ in range(params.max_at_once)]
        height = min(params.height_m, room.hi[2] - room.lo[2] - 0.01)
        self.z_m = (room.lo[2], room.lo[2] + height)  # floor to the top of the head
        self.path_m = (room.lo[1] - params.width_m / 2.0, room.hi[1] + params.width_m / 2.0)  # wholly outside
        self.duration_s = (self.path_m[1] - self.path_m[0]) / params.speed_m_s

    def _extend(self, until_s: float) -> None:
        rate_s = self.params.rate_per_min / 60.0
        if rate_s <= 0:
            return
        with self._lock:
            while self._drawn_until <= until_s:
                start = self._drawn_until + float(self._rng.exponential(1.0 / rate_s))
                x = float(self._rng.uniform(*self.params.distance_m))
                direction = 1 if self._rng.random() < 0.5 else -1
                self._drawn_until = start
                free = [s for s in range(len(self._free_at)) if self._free_at[s] <= start]
                if not free:
                    continue
                crossing = Crossing(start, free[0], x, direction, self.duration_s)
                self._free_at[free[0]] = start + self.duration_s
                self._by_slot[free[0]].append(crossing)
                self._starts[free[0]].append(start)

    def crossings(self, until_s: float) -> list[Crossing]:
        """Every crossing begun by `until_s` (s after the motion's start), in time order."""
        self._extend(until_s)
        found = [c for slot in self._by_slot for c in slot if c.start_s <= until_s]
        return sorted(found, key=lambda c: c.start_s)

    def centre(self, slot: int, t_s: float) -> np.ndarray | None:
        """Where slab `slot`'s centre is at `t_s` (s after the motion's start); None: outside."""
        self._extend(t_s)
        i = bisect.bisect_right(self._starts[slot], t_s) - 1
        if i < 0:
            return None
        c = self._by_slot[slot][i]
        walked = (t_s - c.start_s) * self.params.speed_m_s
        if walked >= self.path_m[1] - self.path_m[0]:
            return None
        y = self.path_m[0] + walked if c.direction > 0 else self.path_m[1] - walked
        return np.array([c.x_m, y, 0.5 * (self.z_m[0] + self.z_m[1])])

    def parked_centre(self) -> np.ndarray:
        """Where the slabs rest (their boxes in the scene): just outside the room's -y wall."""
        near, far = self.params.distance_m
        return np.array([0.5 * (near + far), self.room.lo[1] - self.params.width_m / 2.0 - _PARKED_GAP_M,
                         0.5 * (self.z_m[0] + self.z_m[1])])

    def walkers(self) -> list["PasserBy"]:
        """One mover (`drivers.sim.motion.Mover`) per slab."""
        return [PasserBy(self, slot) for slot in range(self.params.max_at_once)]


class PasserBy:
    """One slab of a crowd as a moving box of the scene (`drivers.sim.motion.Mover`)."""

    def __init__(self, crowd: Crowd, slot: int) -> None:
        self.crowd, self.slot = crowd, slot
        self.name = f"passer_by_{slot}"
        self.texture = crowd.params.texture
        self.texels_per_m = 300.0  # a person seen from a metre or more: a few mm a texel

    def box(self) -> Box:
        p = self.crowd.params
        half = np.array([p.depth_m / 2.0, p.width_m / 2.0, (self.crowd.z_m[1] - self.crowd.z_m[0]) / 2.0])
        return mover_box(self.name, self.crowd.parked_centre(), half, self.texture, self.texels_per_m)

    def offset(self, t_s: float) -> np.ndarray:
        centre = self.crowd.centre(self.slot, t_s)
        if centre is None:
            return np.full(3, math.nan)
        moved: np.ndarray = centre - self.crowd.parked_centre()
        return moved
