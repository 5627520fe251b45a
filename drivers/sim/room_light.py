"""The simulated room's light: how bright the room is at a time of the clock, over an exposure.

The room's illumination relative to its nominal level (1.0) is

    L(t) = D(t) + E(t) * (1 + m cos(2 pi f t + phi))

- D, daylight through a window: `1 - electric_share` at the start, then drifting up and down
  at `daylight_drift_per_min` (a fraction of the nominal light a minute) in straight stretches
  of 2 to 10 minutes, within +-`daylight_range` of where it started.
- E, electric light: `electric_share`, plus `lamp_step` while a lamp is on. The lamp is
  switched (on, off, on...) at the times `lamp_switch_times_s` names and at random times (a
  Poisson process of `lamp_switches_per_hour`), seconds after the light's start.
- Flicker: the electric light is modulated at twice the mains frequency `mains_hz` (a lamp's
  power peaks twice a cycle) with depth m = `flicker_depth` = (max - min) / (max + min), IEEE
  1789's percent flicker over 100; its phase phi is drawn from the seed.

`mean_over(start_s, exposure_s)` integrates L over the exposure in closed form: an exposure
of a whole number of flicker periods sees no flicker, a short one sees all of it. Before the
light's start the lamp and the daylight hold their starting values. Random times are drawn in
order as far as asked, from generators seeded by the room's seed: deterministic per seed
whatever the order of the questions. The numbers of the presets and where they come from:
docs/sim-world.md, section "Room".
"""
from __future__ import annotations

import bisect
import math
import threading
from dataclasses import dataclass
from typing import ClassVar, Literal, Protocol

import numpy as np

from drivers.config.presets import resolve
from drivers.config.reader import check_settings, setting
from drivers.errors import CameraConfigError

DAYLIGHT_STRETCH_S = (120.0, 600.0)  # how long the daylight drifts one way, uniform in this range
MAX_SWITCH_TIMES = 10_000


class Illumination(Protocol):
    """The room's relative illumination (1.0 nominal) averaged over an exposure window."""

    def mean_over(self, start_s: float, exposure_s: float) -> float:
        """The mean over [start_s, start_s + exposure_s] (clock seconds); at start_s when the
        exposure is not positive."""


class ConstantLight:
    """A room whose light never changes: 1.0 over any exposure."""

    def mean_over(self, start_s: float, exposure_s: float) -> float:
        return 1.0

    def __repr__(self) -> str:
        return "CONSTANT_LIGHT"


CONSTANT_LIGHT: Illumination = ConstantLight()


@dataclass(frozen=True)
class LightParams:
    """The values of a light preset, every one set (`LightConfig` gives them)."""

    mains_hz: float
    flicker_depth: float
    electric_share: float
    daylight_drift_per_min: float
    daylight_range: float
    lamp_step: float
    lamp_switches_per_hour: float
    lamp_switch_times_s: tuple[float, ...] = ()

    @property
    def changes(self) -> bool:
        """Whether this light ever differs from the nominal."""
        lamp = self.lamp_step > 0 and (self.lamp_switches_per_hour > 0 or bool(self.lamp_switch_times_s))
        flicker = self.flicker_depth > 0 and (self.electric_share > 0 or lamp)
        return lamp or flicker or self.daylight_drift_per_min > 0


# constant: every effect off (the others' values are home's, so one key given adds one effect);
# home: a room with a window, LED lamps on European mains, a lamp switched now and then.
LIGHT_PRESETS: dict[str, LightParams] = {
    "constant": LightParams(mains_hz=50.0, flicker_depth=0.0, electric_share=0.5, daylight_drift_per_min=0.0,
                            daylight_range=0.2, lamp_step=0.0, lamp_switches_per_hour=0.0),
    "home": LightParams(mains_hz=50.0, flicker_depth=0.25, electric_share=0.5, daylight_drift_per_min=0.02,
                        daylight_range=0.2, lamp_step=0.3, lamp_switches_per_hour=6.0),
}


def _times_ok(times: tuple[float, ...]) -> bool:
    return len(times) <= MAX_SWITCH_TIMES and all(t >= 0.0 for t in times)


@dataclass(frozen=True)
class LightConfig:
    """`cameras.scene.light`: the preset `model` names, each key given (not None) in its place."""

    model: Literal["constant", "home"] = "constant"
    mains_hz: float | None = setting(None, choices=(50.0, 60.0), expected="50 or 60 (Hz)")
    flicker_depth: float | None = setting(None, lo=0.0, hi=1.0, expected="a modulation depth in [0, 1]")
    electric_share: float | None = setting(None, lo=0.0, hi=1.0,
                                           expected="the electric light's share of the nominal light, [0, 1]")
    daylight_drift_per_min: float | None = setting(None, lo=0.0, hi=1.0,
                                                   expected="a fraction of the nominal light a minute, [0, 1]")
    daylight_range: float | None = setting(None, lo=0.0, hi=1.0, expected="a fraction of the nominal light, [0, 1]")
    lamp_step: float | None = setting(None, lo=0.0, hi=10.0, expected="a fraction of the nominal light, [0, 10]")
    lamp_switches_per_hour: float | None = setting(None, lo=0.0, hi=3600.0, expected="a rate in [0, 3600] an hour")
    lamp_switch_times_s: tuple[float, ...] | None = setting(
        None, check=_times_ok, expected=f"at most {MAX_SWITCH_TIMES} times >= 0 s after the start")

    CONFIG_ERROR: ClassVar[type[CameraConfigError]] = CameraConfigError

    def __post_init__(self) -> None:
        check_settings(self)
        p = self.params
        if p.daylight_range > 1.0 - p.electric_share + 1e-12:
            raise CameraConfigError(key_path="daylight_range", value=p.daylight_range,
                                    expected=f"at most the daylight's share, 1 - electric_share = "
                                             f"{1.0 - p.electric_share:g} (daylight never goes negative)")
        if p.daylight_drift_per_min > 0 and p.daylight_range <= 0:
            raise CameraConfigError(key_path="daylight_range", value=p.daylight_range,
                                    expected=f"a positive range for daylight drifting at {p.daylight_drift_per_min:g} "
                                             "a minute")

    @property
    def params(self) -> LightParams:
        return resolve(self, LIGHT_PRESETS)


class RoomLight:
    """The light of `LightParams` from clock time `start_s`, its random times drawn from `seed`."""

    def __init__(self, params: LightParams, seed: int, start_s: float = 0.0) -> None:
        self.params = params
        self.start_s = start_s
        self.omega = 2.0 * math.pi * 2.0 * params.mains_hz  # rad/s of the flicker
        self.phase = float(np.random.default_rng((seed, 0x11, 0)).uniform(0.0, 2.0 * math.pi))
        self._lamp_rng = np.random.default_rng((seed, 0x11, 1))
        self._day_rng = np.random.default_rng((seed, 0x11, 2))
        self._scheduled = sorted(params.lamp_switch_times_s)
        self._random: list[float] = []  # random switch times drawn so far (after the start)
        self._next_random = self._draw_gap(0.0)
        self._day_t, self._day_w = [0.0], [0.0]  # the daylight's knots: (s after start, change)
        self._lock = threading.Lock()

    def __repr__(self) -> str:
        return f"RoomLight({self.params}, start_s={self.start_s})"

    # -- the random times, drawn in order -------------------------------------------------------
    def _draw_gap(self, after: float) -> float:
        rate_s = self.params.lamp_switches_per_hour / 3600.0
        return after + float(self._lamp_rng.exponential(1.0 / rate_s)) if rate_s > 0 else math.inf

    def _extend(self, until: float) -> None:
        """Draw the random switch times and daylight knots up to `until` (s after start)."""
        with self._lock:
            while self._next_random <= until:
                self._random.append(self._next_random)
                self._next_random = self._draw_gap(self._next_random)
            rate_s = self.params.daylight_drift_per_min / 60.0
            bound = self.params.daylight_range
            while rate_s > 0 and self._day_t[-1] <= until:
                w = self._day_w[-1]
                direction = 1.0 if self._day_rng.random() < 0.5 else -1.0
                if w >= bound - 1e-12:
                    direction = -1.0
                elif w <= -bound + 1e-12:
                    direction = 1.0
                room = bound - w if direction > 0 else bound + w
                duration = min(float(self._day_rng.uniform(*DAYLIGHT_STRETCH_S)), max(room, 0.0) / rate_s)
                self._day_t.append(self._day_t[-1] + duration)
                self._day_w.append(w + direction * rate_s * duration)

    def lamp_switch_times_s(self, until_s: float) -> list[float]:
        """Clock times the lamp is switched (the first switches it on), up to `until_s`."""
        until = until_s - self.start_s
        self._extend(until)
        times = sorted(t for t in (*self._scheduled, *self._random) if t <= until)
        return [self.start_s + t for t in times]

    # -- the parts of the light, at tau seconds after the start -------------------------------
    def _lamp_on(self, tau: float) -> bool:
        """Whether the lamp is on at tau (a switch at tau counts)."""
        return (bisect.bisect_right(self._scheduled, tau) + bisect.bisect_right(self._random, tau)) % 2 == 1

    def _electric(self, tau: float) -> float:
        return self.params.electric_share + (self.params.lamp_step if self._lamp_on(tau) else 0.0)

    def _daylight(self, tau: float) -> float:
        return 1.0 - self.params.electric_share + float(np.interp(tau, self._day_t, self._day_w))

    def level_at(self, time_s: float) -> float:
        """The illumination at an instant of the clock."""
        tau = time_s - self.start_s
        self._extend(tau)
        flicker = 1.0 + self.params.flicker_depth * math.cos(self.omega * tau + self.phase)
        return self._daylight(tau) + self._electric(tau) * flicker

    def mean_over(self, start_s: float, exposure_s: float) -> float:
        if not exposure_s > 0:
            return self.level_at(start_s)
        a = start_s - self.start_s
        b = a + exposure_s
        self._extend(b)
        with self._lock:
            inside = [t for times in (self._scheduled, self._random, self._day_t)
                      for t in times[bisect.bisect_right(times, a):bisect.bisect_left(times, b)]]
        cuts = sorted({a, b, *inside, *((0.0,) if a < 0.0 < b else ())})
        depth, omega, phase = self.params.flicker_depth, self.omega, self.phase
        total = 0.0
        for u, v in zip(cuts, cuts[1:]):
            width = v - u
            # The daylight is straight between its knots; the lamp steady between its switches.
            day = 0.5 * (self._daylight(u) + self._daylight(v)) * width
            # The integral of cos(omega t + phase) over [u, v], in a form exact for tiny widths.
            wave = 2.0 / omega * math.cos(0.5 * omega * (u + v) + phase) * math.sin(0.5 * omega * width)
            total += day + self._electric(0.5 * (u + v)) * (width + depth * wave)
        return total / exposure_s


def room_light(config: LightConfig, seed: int, start_s: float = 0.0) -> Illumination:
    """The light a config names, from clock time `start_s`: CONSTANT_LIGHT when nothing changes."""
    params = config.params
    return RoomLight(params, seed, start_s) if params.changes else CONSTANT_LIGHT
