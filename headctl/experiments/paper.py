"""The paper's simulated experiments as functions: an `ExperimentRequest` in, an `ExperimentReport` out.

An experiment is one of `calib_free.sim.experiments.EXPERIMENTS` (learn, baseline, prism,
pan-defect, swap: (r, m) pairs straight from the geometric head model) or of
`headctl.experiments.online.ONLINE_EXPERIMENTS` (online, online-prism, online-pan-defect: the
whole fixation loop on rendered images). `learn` runs its fixations, `measure_floor` the
representation's floor (k-NN) at the end, and `run` both: what `headctl experiment NAME` and
each run of a sweep do. Writing and printing the report is `headctl.experiments.report`'s.
"""
from __future__ import annotations

import dataclasses
import logging
import time
from dataclasses import dataclass
from typing import Callable, Mapping

from calib_free.gaze.exploration import EXPLORATION_KINDS
from calib_free.gaze.fixation import FixationRecord
from calib_free.lens import LENS_KINDS
from calib_free.map.gaze_map import GazeMap
from calib_free.map.params import PROFILES, GazeMapParams
from calib_free.sim.experiments import (EXPERIMENTS, ExperimentResult, ExperimentSpec, final_head, landing_targets,
                                        representation_floor, run_experiment)
from calib_free.sim.head_model import HeadModel
from drivers.sim.scene import ROOMS as ROOM_KINDS
from headctl.config.head import load_config
from headctl.errors import HeadctlError
from headctl.experiments.online import ONLINE_EXPERIMENTS, OnlineResult, OnlineSpec, run_online

log = logging.getLogger(__name__)

# What each option given as text (a sweep's runs) is read as: a number or one of a few names.
INT_OPTIONS = ("fixations", "width", "height", "floor_samples", "landing_every")
PATH_OPTIONS = ("config",)
CHOICE_OPTIONS: Mapping[str, tuple[str, ...]] = {"lens": tuple(LENS_KINDS), "exploration": tuple(EXPLORATION_KINDS),
                                                 "room": tuple(ROOM_KINDS)}

# Called with the fixations done since the last call and, online, the taught ones so far.
Progress = Callable[[int, "int | None"], None]


class ExperimentError(HeadctlError, ValueError):
    """An experiment that cannot be run as asked: an unknown name, options that do not apply."""


def experiment_names() -> list[str]:
    """The experiments `learn` runs: the geometric ones, then the online ones."""
    return sorted(EXPERIMENTS) + sorted(ONLINE_EXPERIMENTS)


@dataclass(frozen=True)
class ExperimentRequest:
    """One run of an experiment; the fields are `headctl experiment`'s options.

    `fixations`: None for the experiment's own; fewer drop the changes beyond them. `pose`:
    samples and lookups carry the head's pose. `exploration`, `room` and `config` apply to the
    online experiments (None: the profile's exploration, the config's room, the packaged
    `configs/sim.yaml`, whose simulated world, cameras, servos and room, the run happens in),
    `lens` to the geometric ones."""

    name: str
    profile: str = "default"
    fixations: int | None = None
    seed: int = 0
    width: int = 320
    height: int = 240
    lens: str = "foveated"
    floor_samples: int = 50_000
    landing_every: int = 100
    pose: bool = True
    exploration: str | None = None
    room: str | None = None
    config: str | None = None

    @classmethod
    def from_options(cls, name: str, profile: str, seed: int, options: Mapping[str, str],
                     pose: bool = True) -> "ExperimentRequest":
        """The request of options given as text (option -> value); ExperimentError names the
        option that is unknown or does not read."""
        if name not in EXPERIMENTS and name not in ONLINE_EXPERIMENTS:
            raise ExperimentError(f"argument name: invalid choice: {name!r} (choose from {', '.join(experiment_names())})")
        if profile not in PROFILES:
            raise ExperimentError(f"argument --profile: invalid choice: {profile!r} (choose from {', '.join(PROFILES)})")
        values: dict[str, int | str] = {}
        for option, text in options.items():
            flag = "--" + option.replace("_", "-")
            if option in INT_OPTIONS:
                try:
                    values[option] = int(text)
                except ValueError:
                    raise ExperimentError(f"argument {flag}: invalid int value: {text!r}") from None
            elif option in CHOICE_OPTIONS:
                if text not in CHOICE_OPTIONS[option]:
                    raise ExperimentError(f"argument {flag}: invalid choice: {text!r} "
                                          f"(choose from {', '.join(CHOICE_OPTIONS[option])})")
                values[option] = text
            elif option in PATH_OPTIONS:
                values[option] = text
            else:
                raise ExperimentError(f"unrecognized argument: {flag}")
        return cls(name, profile, seed=seed, pose=pose, **values)  # type: ignore[arg-type]

    @property
    def online(self) -> bool:
        return self.name in ONLINE_EXPERIMENTS

    def problem(self) -> str | None:
        """Why this request cannot be run, if it cannot."""
        if self.name not in EXPERIMENTS and not self.online:
            return f"{self.name!r}: no such experiment; expected one of {', '.join(experiment_names())}"
        if self.fixations is not None and self.fixations < 1:
            return f"--fixations must be at least 1, got {self.fixations}"
        if self.online and self.lens != "foveated":
            return "--lens applies to the geometric experiments only"
        if not self.online and (self.exploration is not None or self.room is not None or self.config is not None):
            return "--exploration, --room and --config apply to the online experiments only"
        return None

    def spec(self) -> ExperimentSpec:
        """The experiment's spec (an `OnlineSpec` online), cut to `fixations` if given."""
        spec: ExperimentSpec = ONLINE_EXPERIMENTS[self.name] if self.online else EXPERIMENTS[self.name]
        if self.fixations is not None:
            spec = dataclasses.replace(spec, fixations=self.fixations,
                                       changes=tuple(c for c in spec.changes if c.at < self.fixations))
        return spec


@dataclass(frozen=True)
class ExperimentReport:
    """What a run found: the learning curves per fixation (online: per taught fixation), the
    head it learned on (before any change), the floor if measured."""

    request: ExperimentRequest
    spec: ExperimentSpec
    result: ExperimentResult
    model: HeadModel
    seconds: float  # learning, without the floor
    online: OnlineResult | None = None
    floor_px: float | None = None


def learn(request: ExperimentRequest, progress: Progress | None = None) -> ExperimentReport:
    """Run the request's fixations from a random map; ExperimentError if it cannot be run."""
    problem = request.problem()
    if problem:
        raise ExperimentError(problem)
    spec = request.spec()
    started = time.monotonic()
    if isinstance(spec, OnlineSpec):
        taught = 0

        def on_record(record: FixationRecord) -> None:
            nonlocal taught
            taught += record.taught
            if progress is not None:
                progress(1, taught)

        online = run_online(spec, request.profile, seed=request.seed, width=request.width, height=request.height,
                            landing_every=request.landing_every, progress=on_record,
                            exploration=request.exploration, room=request.room,
                            use_pose=request.pose, config=load_config(request.config))
        assert online.model is not None
        return ExperimentReport(request, spec, online.as_experiment_result(), online.model,
                                time.monotonic() - started, online=online)
    model = HeadModel.default(request.width, request.height, lens=request.lens)
    gm = GazeMap.for_image(request.width, request.height, seed=request.seed, profile=request.profile)
    result = run_experiment(spec, gm, model, seed=request.seed, landing_every=request.landing_every,
                            progress=None if progress is None else lambda n: progress(n, None),
                            use_pose=request.pose)
    return ExperimentReport(request, spec, result, model, time.monotonic() - started)


def measure_floor(report: ExperimentReport, say: Callable[[str], None] | None = None) -> ExperimentReport:
    """The report with the representation's floor (k-NN on the request's `floor_samples`;
    none for 0) on the head as it is at the end of the run."""
    request = report.request
    if request.floor_samples <= 0:
        return report
    if say is not None:
        say(f"measuring the representation floor (k-NN on {request.floor_samples} samples)...")
    drange = GazeMapParams().disparity_range  # both kinds of run use the default range
    end_head = final_head(report.spec, report.model)
    targets = landing_targets(end_head, 500, drange, seed=request.seed + 7919 + report.spec.fixations)
    floor_px, _best_k = representation_floor(end_head, drange, request.floor_samples, targets, seed=request.seed + 1)
    return dataclasses.replace(report, floor_px=floor_px)


def run(request: ExperimentRequest, progress: Progress | None = None,
        say: Callable[[str], None] | None = None) -> ExperimentReport:
    """`learn`, then `measure_floor`."""
    return measure_floor(learn(request, progress), say)


__all__ = ["CHOICE_OPTIONS", "INT_OPTIONS", "PATH_OPTIONS", "ExperimentError", "ExperimentReport", "ExperimentRequest", "Progress",
           "experiment_names", "learn", "measure_floor", "run"]
