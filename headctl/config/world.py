"""Which simulated world a head's config puts it in: the kind one, a realistic one, or a mix.

Every part of the simulated world that a real one is less kind in names a preset in the
config (docs/sim-world.md): the cameras' sensor and frame timing, the servos' mechanics, the
room's light and its passers-by. A part is ideal when it names its preset without the effect
and changes none of its values; the world is ideal when every part is, realistic when none
is. A real head (no simulated servos) is in no simulated world.
"""
from __future__ import annotations

import dataclasses
import enum
from collections.abc import Mapping
from dataclasses import dataclass

from headctl.config.head import HeadConfig

IDEAL_PRESETS = frozenset({"ideal", "constant", "none"})  # each part's preset without the effect


class WorldKind(enum.StrEnum):
    IDEAL = "ideal"
    REALISTIC = "realistic"
    MIXED = "mixed"


@dataclass(frozen=True)
class Part:
    """One part of the world: its preset and the values the config changes in it."""

    preset: str
    changed: tuple[str, ...] = ()

    @property
    def ideal(self) -> bool:
        return self.preset in IDEAL_PRESETS and not self.changed

    def describe(self) -> str:
        return self.preset + (f" ({', '.join(self.changed)} changed)" if self.changed else "")


@dataclass(frozen=True)
class SimulatedWorld:
    kind: WorldKind
    parts: dict[str, Part]

    def describe(self) -> str:
        return f"{self.kind}: " + ", ".join(f"{name} {part.describe()}" for name, part in self.parts.items())

    def as_dict(self) -> dict[str, object]:
        return {"kind": str(self.kind), "parts": {name: part.describe() for name, part in self.parts.items()},
                "text": self.describe()}


def _part(section: object) -> Part:
    """The preset a config section names and the keys it changes from it."""
    preset = str(getattr(section, "model"))
    overrides = getattr(section, "overrides", None)
    if isinstance(overrides, Mapping):
        changed = sorted(overrides)
    else:
        changed = sorted(f.name for f in dataclasses.fields(section)  # type: ignore[arg-type]
                         if f.name not in ("model", "seed") and getattr(section, f.name) is not None)
    return Part(preset, tuple(changed))


def simulated_world(config: HeadConfig) -> SimulatedWorld | None:
    """The simulated world `config` puts its head in; None for a real head."""
    if not config.simulated:
        return None
    cameras = config.cameras
    parts: dict[str, Part] = {}
    for name, attribute in (("camera sensor", "sensor"), ("frame timing", "timing")):
        left, right = _part(getattr(cameras.left, attribute)), _part(getattr(cameras.right, attribute))
        if left == right:
            parts[name] = left
        else:
            parts[f"left {name}"], parts[f"right {name}"] = left, right
    parts["servos"] = _part(config.servo_bus.mechanics)
    parts["light"] = _part(cameras.scene.light)
    parts["passers-by"] = _part(cameras.scene.passers_by)
    ideal = [part.ideal for part in parts.values()]
    kind = WorldKind.IDEAL if all(ideal) else WorldKind.REALISTIC if not any(ideal) else WorldKind.MIXED
    return SimulatedWorld(kind, parts)


__all__ = ["IDEAL_PRESETS", "Part", "SimulatedWorld", "WorldKind", "simulated_world"]
