"""The paper's method end to end on images: the online experiments on the simulated head.

`run_online` builds the simulated head the way the service would -- a `SimulatedServoBus`
(motion model, joint limits) driven through the `ServoBus` interface, fish-eye images
rendered by `drivers.sim_scene` from the joints' true positions, a `MapAdapter` learning
on its own thread -- and runs exploratory fixations (`calib_free.fixation`): saccade, fine
vergence, correspondence and confidence, and only converged, confident fixations teach.
Time is a `ManualClock`: waiting for the servos advances it, so nothing sleeps.

The paper's figures come from the adaptations (one per taught fixation); the landing error
is measured on the geometric model with the map as it is (`calib_free.experiments`).
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

from calib_free import GazeMap
from calib_free.adapter import MapAdapter, Sample
from calib_free.experiments import (Change, ExperimentResult, ExperimentSpec, landing_errors_px, landing_targets,
                                    map_predictor)
from calib_free.fixation import REFUSED_NO_VERGENCE_MATCH, FixationController, FixationParams, FixationRecord
from calib_free.gaze_map import AdaptResult
from calib_free.sim import HeadModel, JointLimits
from drivers.clock import ManualClock
from drivers.servo_bus import ServoBusConfig
from drivers.sim_scene import StereoRenderer, shared_scene
from drivers.sim_servo import SimulatedServoBus
from headctl.head import DriverHead, RenderedPairSource

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class OnlineSpec(ExperimentSpec):
    """An experiment on images; `executed_command` as in `FixationParams`."""

    executed_command: str = "encoders"


ONLINE_EXPERIMENTS = {
    "online": OnlineSpec("online", 2000, (), "learning from images, random initialisation (fig. 7)"),
    "online-prism": OnlineSpec("online-prism", 2000, (Change(1000, vertical_prism=True),),
                               "vertical prism (images upside down) at fixation 1,000 (fig. 8)"),
    "online-pan-defect": OnlineSpec(
        "online-pan-defect", 2000, (Change(1000, motor_offset_deg=(10.0, 0.0, 0.0)),),
        "+10 deg added to the pan angle read from the encoder at fixation 1,000 (fig. 9)",
        executed_command="commanded"),
}

SIM_SERVO_CONFIG = {
    "backend": "sim",
    "port": "sim:head",
    "joints": {
        "pan": {"id": 1, "min_angle": -40, "max_angle": 40, "profile_velocity": 240, "profile_acceleration": 2400},
        "tilt": {"id": 2, "min_angle": -25, "max_angle": 25, "profile_velocity": 240, "profile_acceleration": 2400},
        "left_eye": {"id": 3, "min_angle": -15, "max_angle": 15, "profile_velocity": 240,
                     "profile_acceleration": 2400},
        "right_eye": {"id": 4, "min_angle": -15, "max_angle": 15, "profile_velocity": 240,
                      "profile_acceleration": 2400},
    },
}


@dataclass
class OnlineResult:
    spec: OnlineSpec
    records: list[FixationRecord] = field(default_factory=list)
    adaptations: list[tuple[int, AdaptResult]] = field(default_factory=list)  # (fixation index, result)
    landing: list[tuple[int, float]] = field(default_factory=list)  # (adaptations done, median px)
    landing_fixations: list[int] = field(default_factory=list)  # fixations done at each landing check
    seconds: float = 0.0

    @property
    def retinal_error(self) -> np.ndarray:
        return np.array([r.retinal_error for _, r in self.adaptations if r.accepted])

    @property
    def output_error(self) -> np.ndarray:
        return np.array([r.output_error for _, r in self.adaptations if r.accepted]).reshape(-1, 3)

    def outcomes(self) -> dict[str, int]:
        return dict(collections.Counter(r.outcome for r in self.records))

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

    def vergence_convergence(self) -> dict[str, float]:
        """Of the fixations whose foveae matched, how many converged, and in how many steps."""
        matched = [r for r in self.records if r.vergence_disparities_px and r.outcome != REFUSED_NO_VERGENCE_MATCH]
        converged = [r for r in matched if r.converged]
        steps = [r.vergence_steps for r in converged]
        return {"matched": len(matched), "converged": len(converged),
                "converged_fraction": len(converged) / len(matched) if matched else float("nan"),
                "median_steps": float(np.median(steps)) if steps else float("nan")}


class SimulatedHeadRig:
    """The simulated head, wired as the service wires a real one; a context manager."""

    def __init__(self, width: int = 320, height: int = 240, seed: int = 0, lens: str = "foveated",
                 fixation: FixationParams | None = None, noise_std: float = 2.0) -> None:
        self.clock = ManualClock()
        self.model = self.geometry(width, height, lens)
        self.bus = SimulatedServoBus(ServoBusConfig.from_mapping(SIM_SERVO_CONFIG), clock=self.clock,
                                     initial_positions={"pan": 0.0, "tilt": 0.0, "left_eye": 5.0, "right_eye": -5.0})
        self.renderer = StereoRenderer(self.model, shared_scene(seed, False))
        self.pairs = RenderedPairSource(self.renderer.render, self._true_joints, self.clock,
                                        noise_std=noise_std, seed=seed)
        self.head = DriverHead(self.bus, self.pairs, clock=self.clock, vergence_range=self.model.limits.vergence)
        self.fixation = fixation or FixationParams()

    @staticmethod
    def geometry(width: int = 320, height: int = 240, lens: str = "foveated") -> HeadModel:
        """The rig's head model: vergence from 1 deg, as the room's far walls (3 m) need with 60 mm."""
        return HeadModel.default(width, height, lens=lens, limits=JointLimits(vergence=(1.0, 20.0)))

    def _true_joints(self) -> dict[str, float]:
        return {j: self.bus.true_position(j) for j in ("pan", "tilt", "left_eye", "right_eye")}

    def __enter__(self) -> "SimulatedHeadRig":
        self.bus.open()
        self.bus.enable()
        return self

    def __exit__(self, *exc: object) -> None:
        self.bus.close()
        self.renderer.close()


def apply_change(change: Change, rig: SimulatedHeadRig, model: HeadModel) -> HeadModel:
    """Switch a perturbation on in the rig (images or controller) and in the geometric model."""
    if change.vertical_prism:
        rig.head.image_transform = np.flipud
    if change.motor_offset_deg is not None:
        rig.head.pan_reading_offset_deg = change.motor_offset_deg[0]
    if change.swap_eyes or change.baseline_delta_m or change.motor_gain:
        raise ValueError(f"the online experiments do not model {change}")
    return change.apply(model)


def run_online(spec: OnlineSpec, profile: str = "default", seed: int = 0, width: int = 320, height: int = 240,
               landing_every: int = 100, landing_count: int = 300,
               progress: Callable[[FixationRecord], None] | None = None) -> OnlineResult:
    """Run `spec` on the simulated head from a random map; returns records and curves."""
    result = OnlineResult(spec)
    lock = threading.Lock()
    fixation = FixationParams(executed_command=spec.executed_command)
    gm = GazeMap.for_image(width, height, seed=seed, profile=profile)

    def on_adapted(sample: Sample, res: AdaptResult) -> None:
        with lock:
            result.adaptations.append((sample.tag, res))

    started = time.monotonic()
    changes = {c.at: c for c in spec.changes}
    with SimulatedHeadRig(width, height, seed, fixation=fixation) as rig, \
            MapAdapter(gm, on_adapted=on_adapted) as adapter:
        model = rig.model
        targets = landing_targets(model, landing_count, gm.params.disparity_range, seed=seed + 7919)
        controller = FixationController(rig.head, adapter, fixation, seed=seed, clock=rig.clock.monotonic)
        for n in range(spec.fixations):
            if n in changes:
                model = apply_change(changes[n], rig, model)
                targets = landing_targets(model, landing_count, gm.params.disparity_range, seed=seed + 7919 + n)
                log.info("fixation %d: %s", n, spec.description)
            record = controller.fixate()
            if record.taught:
                adapter.submit(Sample(record.position, record.executed, record.confidence, tag=n))
            result.records.append(record)
            if progress is not None:
                progress(record)
            if landing_every and ((n + 1) % landing_every == 0 or n + 1 == spec.fixations):
                adapter.wait_idle()
                errors = adapter.with_map(lambda m: landing_errors_px(model, targets, map_predictor(m)))
                with lock:
                    result.landing.append((len(result.adaptations), float(np.median(errors))))
                result.landing_fixations.append(n + 1)
        adapter.wait_idle()
        if adapter.error is not None:
            raise adapter.error
    result.seconds = time.monotonic() - started
    return result
