"""The paper's method end to end on images: the online experiments on the simulated head.

`run_online` builds the simulated head from its config the way the service does
(`headctl.service.build`: the simulated servo bus with its motion model and joint limits,
the simulated cameras rendering the fish-eye views of the room from the joints' true
positions), with a `MapAdapter` learning on its own thread, and runs exploratory fixations (`calib_free.fixation`): saccade, fine
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
from calib_free.fixation import FixationController, FixationOutcome, FixationParams, FixationRecord
from calib_free.gaze_map import AdaptResult
from calib_free.sim import HeadModel
from drivers.clock import ManualClock
from drivers.sim_camera import SimulatedCamera
from headctl.config import HeadConfig, load_config
from headctl.errors import HeadctlError
from headctl.head import RenderedPairSource
from headctl.service.build import HeadDevices, build_head

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

@dataclass
class OnlineResult:
    spec: OnlineSpec
    records: list[FixationRecord] = field(default_factory=list)
    adaptations: list[tuple[int, AdaptResult]] = field(default_factory=list)  # (fixation index, result)
    landing: list[tuple[int, float]] = field(default_factory=list)  # (adaptations done, median px)
    landing_fixations: list[int] = field(default_factory=list)  # fixations done at each landing check
    seconds: float = 0.0
    model: HeadModel | None = None  # the simulated head's geometry before any change

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

    def vergence_convergence(self) -> dict[str, float]:
        """Of the fixations whose foveae matched, how many converged, and in how many steps."""
        matched = [r for r in self.records if r.vergence_disparities_px and r.outcome is not FixationOutcome.NO_VERGENCE_MATCH]
        converged = [r for r in matched if r.converged]
        steps = [r.vergence_steps for r in converged]
        return {"matched": len(matched), "converged": len(converged),
                "converged_fraction": len(converged) / len(matched) if matched else float("nan"),
                "median_steps": float(np.median(steps)) if steps else float("nan")}


def sim_config(width: int = 320, height: int = 240, seed: int = 0, lens: str = "foveated",
               base: HeadConfig | None = None) -> HeadConfig:
    """The simulated head's config (default: the packaged one) with grey cameras of this size
    and lens, papered with the room of `seed`."""
    config = base if base is not None else load_config()
    if not config.simulated:
        raise HeadctlError(f"{config.path}: the online experiments need the simulated head (servo_bus.backend: sim)")
    cameras = {side: dataclasses.replace(getattr(config.cameras, side), width=width, height=height, lens=lens,
                                         seed=seed, image="grey") for side in ("left", "right")}
    return dataclasses.replace(config, cameras=dataclasses.replace(config.cameras, **cameras))


class SimulatedHeadRig:
    """The simulated head built from its config as the service builds it (`headctl.service.build`),
    on a `ManualClock`, with pairs rendered on demand instead of streamed; a context manager."""

    def __init__(self, width: int = 320, height: int = 240, seed: int = 0, lens: str = "foveated",
                 fixation: FixationParams | None = None, noise_std: float | None = None,
                 config: HeadConfig | None = None) -> None:
        self.clock = ManualClock()
        self.config = sim_config(width, height, seed, lens, config)
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
        self.pairs = RenderedPairSource(lambda joints: (left.render(joints), right.render(joints)),
                                        world.true_joints, self.clock, noise_std=noise, seed=seed)
        self.head = build_head(self.config, self.bus, self.pairs, self.clock)
        self.fixation = fixation or FixationParams()

    def __enter__(self) -> "SimulatedHeadRig":
        self.devices.open()
        self.bus.enable()
        return self

    def __exit__(self, *exc: object) -> None:
        self.devices.close()


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
        model = result.model = rig.model
        targets = landing_targets(model, landing_count, gm.params.disparity_range, seed=seed + 7919)
        controller = FixationController(rig.head, adapter, fixation, seed=seed, clock=rig.clock.monotonic,
                                        learner=adapter)
        for n in range(spec.fixations):
            if n in changes:
                model = apply_change(changes[n], rig, model)
                targets = landing_targets(model, landing_count, gm.params.disparity_range, seed=seed + 7919 + n)
                log.info("fixation %d: %s", n, spec.description)
            record = controller.fixate()
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
