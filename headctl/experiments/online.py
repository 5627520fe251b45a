"""The paper's method end to end on images: the online experiments on the simulated head.

`run_online` builds the simulated head from its config the way the service does
(`headctl.service.build`: the simulated servo bus with its motion model and joint limits,
the simulated cameras rendering the fish-eye views of the room from the joints' true
positions), with a `MapAdapter` learning on its own thread, and runs exploratory fixations (`calib_free.gaze.fixation`): saccade, fine
vergence, correspondence and confidence, and only converged, confident fixations teach.
Time is a `ManualClock`: waiting for the servos advances it, so nothing sleeps.

The paper's figures come from the adaptations (one per taught fixation); the landing error
is measured on the geometric model with the map as it is (`calib_free.sim.experiments`), on targets
in the room the head explores, seen from poses fixating the room (`landing`), and on the
geometric experiments' targets, anywhere within the joint limits (`landing_joint_range`): there
the vergence goes up to 20 deg, points 17 cm away where the room has none, and the map answers
for poses and disparities it was never taught.
"""
from __future__ import annotations

import collections
import dataclasses
import logging
import threading
import time
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from calib_free.map.gaze_map import GazeMap
from calib_free.map.adapter import MapAdapter, Sample
from calib_free.sim.experiments import (Change, ExperimentResult, ExperimentSpec, MeasuredRecovery, landing_errors_px,
                                        landing_targets, map_predictor, measured_landing_recovery)
from calib_free.gaze.exploration import ExplorationKind, TeachingExplorer
from calib_free.gaze.fixation import FixationController, FixationOutcome, FixationParams, FixationRecord
from calib_free.map.gaze_map import AdaptResult, Vector
from calib_free.sim.head_model import FixationSample, HeadModel
from calib_free.correspondence.search import CorrespondenceParams
from drivers.cameras.config import SceneConfig
from drivers.clock import ManualClock
from drivers.config.reader import read_config
from drivers.sim.camera import SimulatedCamera
from drivers.sim.eye_pair import EyePair
from drivers.sim.scene import Scene, shared_scene
from headctl.config.head import HeadConfig, load_config
from headctl.errors import HeadctlError
from headctl.experiments.perturbations import perturb
from headctl.service.exposure import ExposureHold
from headctl.service.head import RenderedPairSource
from headctl.service.build import HeadDevices, build_head

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class OnlineSpec(ExperimentSpec):
    """An experiment on images; `executed_command` as in `FixationParams` (None: the config's)."""

    executed_command: str | None = None


ONLINE_EXPERIMENTS = {
    "online": OnlineSpec("online", 2000, (), "learning from images, random initialisation (fig. 7)"),
    "online-prism": OnlineSpec("online-prism", 2000, (Change(1000, vertical_prism=True),),
                               "vertical prism (images upside down) at fixation 1,000 (fig. 8)"),
    "online-pan-defect": OnlineSpec(
        "online-pan-defect", 2000, (Change(1000, motor_offset_deg=(10.0, 0.0, 0.0)),),
        "+10 deg added to the pan angle read from the encoder at fixation 1,000 (fig. 9)",
        executed_command="commanded"),
}

@dataclass
class OnlineResult:
    spec: OnlineSpec
    records: list[FixationRecord] = field(default_factory=list)
    adaptations: list[tuple[int, AdaptResult]] = field(default_factory=list)  # (fixation index, result)
    landing: list[tuple[int, float]] = field(default_factory=list)  # (adaptations done, median px), room targets
    landing_joint_range: list[tuple[int, float]] = field(default_factory=list)  # ... targets anywhere in the limits
    landing_fixations: list[int] = field(default_factory=list)  # fixations done at each landing check
    landing_start_px: float | None = None  # the random map's, before the first fixation
    use_pose: bool = True  # samples and lookups carried the head's pose
    exploration: str = ""  # FixationParams.exploration
    exploration_stats: dict[str, dict[str, int]] = field(default_factory=dict)  # the explorer's, if it keeps any
    seconds: float = 0.0
    model: HeadModel | None = None  # the simulated head's geometry before any change
    config_path: str = ""  # the config whose simulated world the run happened in
    room: str = ""  # the room its cameras saw: generated or photos

    @property
    def retinal_error(self) -> np.ndarray:
        return np.array([r.retinal_error for _, r in self.adaptations if r.accepted])

    @property
    def output_error(self) -> np.ndarray:
        return np.array([r.output_error for _, r in self.adaptations if r.accepted]).reshape(-1, 3)

    def outcomes(self) -> dict[str, int]:
        return dict(collections.Counter(str(r.outcome) for r in self.records))

    def final(self, over: int = 10) -> dict[str, float]:
        ret, out = self.retinal_error[-over:], self.output_error[-over:]
        if not len(ret):
            return {"pan_deg": float("nan"), "tilt_deg": float("nan"), "vergence_deg": float("nan"),
                    "retinal_error": float("nan")}
        m = out.mean(axis=0)
        return {"pan_deg": float(m[0]), "tilt_deg": float(m[1]), "vergence_deg": float(m[2]),
                "retinal_error": float(ret.mean())}

    def as_experiment_result(self) -> ExperimentResult:
        """The learning curves per adaptation (taught fixation), as the geometric experiments give them."""
        accepted_tags = [tag for tag, r in self.adaptations if r.accepted]
        changes = tuple(dataclasses.replace(c, at=int(np.searchsorted(accepted_tags, c.at))) for c in self.spec.changes)
        spec = ExperimentSpec(self.spec.name, len(accepted_tags), changes, self.spec.description)
        result = ExperimentResult(spec, self.retinal_error, self.output_error, list(self.landing))
        result.refused = sum(1 for _, r in self.adaptations if not r.accepted)
        return result

    def measured_landing(self, over: int = 200) -> dict[str, float | int | None]:
        """Where the last `over` taught fixations that aimed at an image target ended, as their
        own correspondence measured it (`FixationRecord.landing_error_px`): the landing error a
        real head can know, in whatever world, beside the geometric model's (`landing`)."""
        errors = [e for e in self.measured_landing_px() if e is not None][-over:]
        if not errors:
            return {"fixations": 0, "median_px": None, "p90_px": None}
        return {"fixations": len(errors), "median_px": float(np.median(errors)),
                "p90_px": float(np.percentile(errors, 90))}

    def measured_landing_px(self) -> list[float | None]:
        """Per fixation, the landing error it measured itself (None: refused, or no image target)."""
        return [r.landing_error_px for r in self.records]

    def measured_landing_recovery(self, change: Change) -> MeasuredRecovery:
        """How the fixations' measured landing came back after `change` (`change.at` in
        fixations), counted in fixations since it (`calib_free.sim.experiments.measured_landing_recovery`)."""
        return measured_landing_recovery(self.measured_landing_px(), change.at)

    def vergence_convergence(self) -> dict[str, float]:
        """Of the fixations whose foveae matched, how many converged, and in how many steps."""
        matched = [r for r in self.records if r.vergence_disparities_px and r.outcome is not FixationOutcome.NO_VERGENCE_MATCH]
        converged = [r for r in matched if r.converged]
        steps = [r.vergence_steps for r in converged]
        return {"matched": len(matched), "converged": len(converged),
                "converged_fraction": len(converged) / len(matched) if matched else float("nan"),
                "median_steps": float(np.median(steps)) if steps else float("nan")}


def sim_config(width: int = 320, height: int = 240, seed: int = 0, lens: str = "foveated",
               base: HeadConfig | None = None, room: str | None = None) -> HeadConfig:
    """The simulated head's config (default: the packaged one) with grey cameras of this size
    and lens, papered with the room of `seed`: `room` "generated" or "photos" (scikit-image's
    photographs); None: the config's (`cameras.scene`)."""
    config = base if base is not None else load_config()
    if not config.simulated:
        raise HeadctlError(f"{config.path}: the online experiments need the simulated head (servo_bus.backend: sim)")
    cameras = {side: dataclasses.replace(getattr(config.cameras, side), width=width, height=height, lens=lens,
                                         seed=seed, image="grey") for side in ("left", "right")}
    scene = config.cameras.scene if room is None else read_config(SceneConfig, {"room": room}, "cameras.scene")
    return dataclasses.replace(config, cameras=dataclasses.replace(config.cameras, scene=scene, **cameras))


class RoomSurfaces:
    """The simulated room's surfaces as `calib_free.sim.head_model.Surroundings`: the first box face a ray
    meets (the scene's first box is the room, seen from inside). Boxes at rest (where moving
    objects start)."""

    def __init__(self, scene: Scene) -> None:
        self.lo = np.asarray(scene.lo, dtype=float)
        self.hi = np.asarray(scene.hi, dtype=float)

    def first_surface(self, origin: np.ndarray, direction: np.ndarray) -> np.ndarray | None:
        with np.errstate(divide="ignore", invalid="ignore"):
            inv = 1.0 / np.asarray(direction, dtype=float)
            a, b = (self.lo - origin) * inv, (self.hi - origin) * inv
        near = np.max(np.fmin(a, b), axis=1)
        far = np.min(np.fmax(a, b), axis=1)
        distance = float(far[0])  # where the ray leaves the room
        hits = (near[1:] > 1e-6) & (near[1:] < far[1:])
        if np.any(hits):
            distance = min(distance, float(np.min(near[1:][hits])))
        if not (np.isfinite(distance) and distance > 0.0):
            return None
        point: np.ndarray = origin + distance * np.asarray(direction, dtype=float)
        return point


class _WithoutPose:
    """The adapter as a map that never sees the head's pose: lookups and samples without it,
    the paper's (x, y, d) alone."""

    def __init__(self, adapter: MapAdapter) -> None:
        self.adapter = adapter

    def command(self, position: Vector, pose: Vector | None = None) -> np.ndarray:
        return self.adapter.command(position)

    def check_position(self, position: Vector) -> str:
        return self.adapter.check_position(position)

    def submit(self, sample: Sample) -> None:
        self.adapter.submit(dataclasses.replace(sample, pose=None))


class SimulatedHeadRig:
    """The simulated head built from its config as the service builds it (`headctl.service.build`),
    on a `ManualClock`, with pairs rendered on demand instead of streamed; a context manager.

    `parallel_eyes`: the right eye renders on a worker thread while the left renders on the
    caller's (`drivers.sim.eye_pair`); the images are the same either way."""

    def __init__(self, width: int = 320, height: int = 240, seed: int = 0, lens: str = "foveated",
                 fixation: FixationParams | None = None, noise_std: float | None = None,
                 config: HeadConfig | None = None, room: str | None = None, parallel_eyes: bool = False) -> None:
        self.clock = ManualClock()
        self.config = sim_config(width, height, seed, lens, config, room)
        self.devices = HeadDevices.build(self.config, self.clock)
        world = self.devices.world
        assert world is not None  # sim_config checked that the head is simulated
        self.model = world.model
        assert self.devices.bus is not None  # built here, not owned by a servo process
        self.bus = self.devices.bus
        left, right = self.devices.cameras["left"], self.devices.cameras["right"]
        if not (isinstance(left, SimulatedCamera) and isinstance(right, SimulatedCamera)):
            raise HeadctlError(f"{self.config.path}: the online experiments need simulated cameras (backend: sim)")
        noise = self.config.cameras.left.noise_std if noise_std is None else noise_std
        self.eye_pair: EyePair[np.ndarray] = EyePair(parallel_eyes)
        self.pairs = RenderedPairSource(
            lambda joints: self.eye_pair.render(lambda: left.render(joints), lambda: right.render(joints)),
            world.true_joints, self.clock, noise_std=noise, seed=seed)
        self.head = build_head(self.config, self.bus, self.pairs, self.clock)
        # The cameras' exposure held over each fixation, as the service holds it (`cameras.*.exposure_control`).
        self.exposure = ExposureHold(self.devices.cameras.values())
        self.fixation = fixation or FixationParams()
        # The room the cameras render (the shared generated one unless the config names another).
        self.scene = world.scene if world.scene is not None else shared_scene(left.config.seed,
                                                                              left.config.image == "colour")
        self.surroundings = RoomSurfaces(self.scene)

    def __enter__(self) -> "SimulatedHeadRig":
        self.devices.open()
        self.bus.enable()
        return self

    def __exit__(self, *exc: object) -> None:
        self.eye_pair.close()
        self.devices.close()


def apply_change(change: Change, rig: SimulatedHeadRig, model: HeadModel) -> HeadModel:
    """Switch a perturbation on in the rig's head (its pairs or its bus wrapped,
    `headctl.experiments.perturbations`) and in the geometric model."""
    perturb(rig.head, change)
    return change.apply(model)


def exploration_for(profile: str) -> str:
    """The exploration a profile's experiments use: the paper's random commands for `paper`."""
    return ExplorationKind.RANDOM if profile == "paper" else ExplorationKind.TEACHING


def run_online(spec: OnlineSpec, profile: str = "default", seed: int = 0, width: int = 320, height: int = 240,
               landing_every: int = 100, landing_count: int = 300,
               progress: Callable[[FixationRecord], None] | None = None,
               exploration: str | None = None, room: str | None = None, use_pose: bool = True,
               config: HeadConfig | None = None) -> OnlineResult:
    """Run `spec` on the simulated head from a random map; returns records and curves.

    `exploration`: `FixationParams.exploration`; None: the paper's random commands with the
    `paper` profile, targets that teach with the `default` one. Correspondence follows the
    profile (`CorrespondenceParams.profile_values`). `config`: the simulated head whose world
    the run happens in (None: the packaged configs/sim.yaml). `room`: "generated" or "photos"
    (None: the config's). `use_pose`: samples and lookups carry the head's pose (False: the
    map learns and answers from (x, y, d) alone)."""
    result = OnlineResult(spec, use_pose=use_pose)
    lock = threading.Lock()
    if exploration is None:
        exploration = exploration_for(profile)
    config = config if config is not None else load_config()
    # The config's fixation settings (its head's), with the experiment's exploration and profile.
    executed = spec.executed_command or config.fixation.params.executed_command
    fixation = dataclasses.replace(config.fixation.params, executed_command=executed,
                                   exploration=exploration, correspondence=CorrespondenceParams.profile_values(profile))
    result.exploration = exploration
    gm = GazeMap.for_image(width, height, seed=seed, profile=profile)

    def on_adapted(sample: Sample, res: AdaptResult) -> None:
        with lock:
            result.adaptations.append((sample.tag, res))

    started = time.monotonic()
    changes = {c.at: c for c in spec.changes}
    with SimulatedHeadRig(width, height, seed, fixation=fixation, config=config, room=room) as rig, \
            MapAdapter(gm, on_adapted=on_adapted) as adapter:
        model = result.model = rig.model
        result.config_path, result.room = str(rig.config.path), rig.config.cameras.scene.kind
        drange = gm.params.disparity_range

        def target_sets(at: int) -> tuple[list[FixationSample], list[FixationSample]]:
            return (landing_targets(model, landing_count, drange, seed + 7919 + at, rig.surroundings),
                    landing_targets(model, landing_count, drange, seed + 7919 + at))

        def landing_px() -> tuple[float, float]:
            """Median landing error (px) on the room's targets and on the joint range's."""
            def medians(m: GazeMap) -> tuple[float, float]:
                in_room, anywhere = (float(np.median(landing_errors_px(model, ts, map_predictor(m, use_pose))))
                                     for ts in targets)
                return in_room, anywhere
            return adapter.with_map(medians)

        targets = target_sets(0)
        reader = adapter if use_pose else _WithoutPose(adapter)
        controller = FixationController(rig.head, reader, fixation, seed=seed, clock=rig.clock.monotonic,
                                        learner=reader)
        if landing_every:  # the random map's, where the learning curve starts
            result.landing_start_px = landing_px()[0]
        for n in range(spec.fixations):
            if n in changes:
                model = apply_change(changes[n], rig, model)
                targets = target_sets(n)
                log.info("fixation %d: %s", n, spec.description)
            with rig.exposure.held():
                record = controller.fixate()
            result.records.append(record)
            if progress is not None:
                progress(record)
            if landing_every and ((n + 1) % landing_every == 0 or n + 1 == spec.fixations):
                adapter.wait_idle()
                room_px, anywhere_px = landing_px()
                with lock:
                    result.landing.append((len(result.adaptations), room_px))
                    result.landing_joint_range.append((len(result.adaptations), anywhere_px))
                result.landing_fixations.append(n + 1)
        adapter.wait_idle()
        if adapter.error is not None:
            raise adapter.error
        if isinstance(controller.exploration, TeachingExplorer):
            stats = controller.exploration.stats
            result.exploration_stats = {"chosen": dict(stats.chosen), "taught": dict(stats.taught),
                                        "rejected": dict(stats.rejected)}
    result.seconds = time.monotonic() - started
    return result
