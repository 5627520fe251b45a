"""The simulated room a config names (`cameras.scene`), as the cameras of a head render it.

The room of the cameras' seed and image (`drivers.sim.scene.shared_scene`: generated or papered
with photographs), with the moving objects given and the config's passers-by moving in a scene
of its own (`drivers.sim.motion.moving_scene`), lit by the config's light from now
(`drivers.sim.room_light`). A room where nothing moves and the light is constant is the shared
scene itself.
"""
from __future__ import annotations

import copy
from collections.abc import Sequence

from drivers.cameras.config import SceneConfig
from drivers.clock import SYSTEM_CLOCK, Clock
from drivers.sim.motion import Mover, moving_scene
from drivers.sim.passers_by import Crowd
from drivers.sim.room_light import CONSTANT_LIGHT, room_light
from drivers.sim.scene import Scene, shared_scene


def room_scene(config: SceneConfig, seed: int, colour: bool, objects: Sequence[Mover] = (),
               clock: Clock = SYSTEM_CLOCK) -> Scene:
    """The room `config` names for cameras of `seed` and `colour`, `objects` (e.g. the head
    config's `sim_objects`) and the passers-by moving in it, and its light, from the clock's now."""
    folder = None if config.folder is None else str(config.folder)
    scene = shared_scene(seed, colour, config.kind, folder)
    movers = list(objects)
    passers = config.passers_by.params
    if passers.rate_per_min > 0:
        movers += Crowd(passers, scene.boxes[0], seed).walkers()
    if movers:
        scene = moving_scene(scene, movers, clock)
    light = room_light(config.light, seed, clock.monotonic())
    if light is not CONSTANT_LIGHT:
        if not movers:  # the shared scene is every camera's of this seed: light a copy
            scene = copy.copy(scene)
        scene.light = light
    return scene
