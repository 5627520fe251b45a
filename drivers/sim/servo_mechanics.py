"""What real X-series servos on a head add to the simulated servos' ideal motion.

`servo_bus.mechanics` (`ServoMechanicsConfig`) names a preset (`model`) and overrides any of
its values; `resolved()` gives the values in force (`Mechanics`). The code default preset,
`ideal`, adds nothing: the servos follow `drivers.sim.servo_motion.ProfileAxis` exactly and
report where they are. `xm430_head` is an XM430-W350 head with typical values (docs/sim-world.md,
"Servos", gives each number's source):

- play between the servo's output shaft and what the cameras see (`backlash_deg`): the output
  lags a reversal by the play; a loaded joint (the tilt) rests on its downhill flank;
- the position controller's dead band (`dead_band_ticks`): a goal that close to where the
  servo holds does not move it;
- the tilt's droop under the head's weight (`sag_deg_at_horizontal`, times the cosine of the
  tilt: the gravity torque of a centre of mass ahead of the tilt axis);
- the encoder's resolution (`encoder_ticks_per_rev`) and a reading that wobbles by up to
  `read_wobble_ticks`;
- the bus's timing through the USB adapter (`bus_timing`): a state read waits for the
  adapter's latency timer (`servo_bus.latency_timer_ms`) and every packet for its bytes at
  `servo_bus.baud`, on the bus's clock.

The encoder reads the output shaft (`GearedAxis.shaft`: the droop shows in the reading), the
cameras see the output beyond the play (`GearedAxis.output`). `ServoMechanics` is one bus's
mechanics: its readings draw their wobble from a generator seeded by `seed`, so a run is the
same for the same seed and the same calls.
"""
from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from drivers.config.reader import check_settings, setting
from drivers.errors import ServoConfigError
from drivers.sim.servo_motion import AxisState, GearedAxis, ProfileAxis, tilt_droop

TICKS_PER_REV = 4096  # X-series resolution (e-manual): 0.088 deg a tick
TICK_DEG = 360.0 / TICKS_PER_REV
MODELS: tuple[str, ...] = ("ideal", "xm430_head")

# Protocol 2.0 packet sizes of one servo-loop cycle (drivers.dynamixel.bus_v2): a Sync Read of
# the 16-byte state block from n servos (14 + n bytes out, 11 + 16 bytes back from each) and a
# Sync Write of the 4-byte goal (14 + 5 n bytes). 10 bits a byte on the wire (8N1).
_SYNC_READ_OUT_BYTES = 14
_STATUS_BYTES = 11 + 16
_SYNC_WRITE_BYTES = 14
_GOAL_BYTES = 1 + 4
_BITS_PER_BYTE = 10


@dataclass(frozen=True)
class Mechanics:
    """The mechanics in force (a preset with its overrides); all zero: the ideal servos."""

    backlash_deg: float = 0.0
    dead_band_ticks: float = 0.0
    sag_deg_at_horizontal: float = 0.0
    read_wobble_ticks: int = 0
    encoder_ticks_per_rev: int = 0  # 0: positions read exactly
    bus_timing: bool = False

    @property
    def dead_band_deg(self) -> float:
        return self.dead_band_ticks * TICK_DEG


PRESETS: dict[str, Mechanics] = {
    "ideal": Mechanics(),
    "xm430_head": Mechanics(backlash_deg=0.25, dead_band_ticks=1.0, sag_deg_at_horizontal=0.35, read_wobble_ticks=1,
                            encoder_ticks_per_rev=TICKS_PER_REV, bus_timing=True),
}


@dataclass(frozen=True)
class ServoMechanicsConfig:
    """`servo_bus.mechanics` of the simulated head: a preset (`model`) and per-effect values
    that override it (None: the preset's). `seed` seeds the reading's wobble."""

    model: str = setting("ideal", choices=MODELS)
    backlash_deg: float | None = setting(None, lo=0.0, hi=5.0)
    dead_band_ticks: float | None = setting(None, lo=0.0, hi=50.0)
    sag_deg_at_horizontal: float | None = setting(None, lo=0.0, hi=10.0)
    read_wobble_ticks: int | None = setting(None, lo=0, hi=20)
    encoder_ticks_per_rev: int | None = setting(
        None, lo=0, hi=1 << 20, check=lambda n: n is None or n == 0 or n >= 256,
        expected="0 (positions read exactly) or a resolution of at least 256 ticks a turn (X-series: 4096)")
    bus_timing: bool | None = None
    seed: int = setting(0, lo=0, hi=2**32 - 1)

    CONFIG_ERROR: ClassVar[type[ServoConfigError]] = ServoConfigError

    def __post_init__(self) -> None:
        check_settings(self)

    def resolved(self) -> Mechanics:
        overrides = {f.name: getattr(self, f.name) for f in dataclasses.fields(Mechanics)
                     if getattr(self, f.name) is not None}
        return dataclasses.replace(PRESETS[self.model], **overrides)


class ServoMechanics:
    """One bus's mechanics: its servos' axes, the dead band, the encoder's readings, the time a
    cycle's packets take. Not thread-safe: its owner serialises access."""

    def __init__(self, config: ServoMechanicsConfig, *, baud: int = 1_000_000, latency_timer_ms: float = 1.0,
                 return_delay_us: float = 0.0) -> None:
        self.values = config.resolved()
        self.baud = baud
        self.latency_timer_ms = latency_timer_ms
        self.return_delay_us = return_delay_us
        self._rng = np.random.default_rng(config.seed)

    def axis(self, at: AxisState | float, time_s: float, *, loaded: bool = False,
             joint_angle: Callable[[float], float] = float, direction: int = 1) -> GearedAxis:
        """A servo's axis (servo frame) in the state `at`, or at a position alone as a fresh servo
        is: its controller holding there, the output at the shaft (a loaded one on its flank);
        `loaded`: it carries the head's weight (the tilt), `joint_angle` and `direction` map its
        frame to the joint's."""
        droop = tilt_droop(self.values.sag_deg_at_horizontal) if loaded else None
        load = None if droop is None else (lambda servo_deg: direction * droop(joint_angle(servo_deg)))
        position, output = (at.position, at.output) if isinstance(at, AxisState) else (at, None)
        return GearedAxis(position, time_s, backlash=self.values.backlash_deg, load=load, output=output)

    def command(self, axis: ProfileAxis, goal_deg: float) -> None:
        """A goal reaches the position controller: within the dead band of where a resting
        servo holds, it does not move it."""
        dead_band = self.values.dead_band_deg
        if dead_band and not axis.moving and abs(goal_deg - axis.position) <= dead_band:
            return
        axis.set_goal(goal_deg)

    def reading(self, shaft_deg: float) -> float:
        """What the encoder reports of a shaft at `shaft_deg`: within its resolution, wobbling
        by up to `read_wobble_ticks` either way."""
        ticks = self.values.encoder_ticks_per_rev
        if not ticks:
            return shaft_deg
        tick_deg = 360.0 / ticks
        wobble = self.values.read_wobble_ticks
        offset = int(self._rng.integers(-wobble, wobble + 1)) if wobble else 0
        return (round(shaft_deg / tick_deg) + offset) * tick_deg

    def read_cost_s(self, servos: int) -> float:
        """How long a state read of `servos` servos keeps the caller: the request and the replies
        on the wire, each reply's return delay, and the adapter's latency timer, which holds a
        reply shorter than the adapter's USB packet until it expires. 0 without bus timing."""
        if not self.values.bus_timing:
            return 0.0
        wire_bytes = _SYNC_READ_OUT_BYTES + servos + servos * _STATUS_BYTES
        return (self.latency_timer_ms / 1000.0 + wire_bytes * _BITS_PER_BYTE / self.baud
                + servos * self.return_delay_us / 1e6)

    def write_cost_s(self, servos: int) -> float:
        """How long a goal write to `servos` servos takes on the wire (no reply to wait for)."""
        if not self.values.bus_timing:
            return 0.0
        return (_SYNC_WRITE_BYTES + servos * _GOAL_BYTES) * _BITS_PER_BYTE / self.baud
