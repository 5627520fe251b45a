"""A recorded session learned again: `relearn(RelearnRequest) -> RelearnReport`.

A recording (`headctl record`) holds each fixation's stereo pairs, losslessly, its record and
the head calls it made (`headctl.ros2.fixation_log`). Relearn builds a fresh gaze map (from
`--config FILE`'s `gaze_map` section, else the config the bag recorded, else the packaged
`configs/sim.yaml`) and runs every recorded fixation again, in order, through the service's
own `calib_free.gaze.fixation.FixationController`, learning through a
`calib_free.map.adapter.MapAdapter`: the head is a `ReplayHead` that answers each call as the
real head did (the pairs, the poses read, the goals commanded), and the exploration a
`ReplayedChoice` that sends each saccade where the live one went. Fine vergence, the
correspondence, the confidence and the map's checks run on the recorded pixels; only the map
is new. No simulator, no hardware.

What it tells: the fixations taught and the refusals by reason, recorded beside replayed (the
fixations whose outcome differs listed), and the learning curve (mean retinal error, eq. 8,
and output error of the adaptations of each `every` fixations) of the live run (the bag's
`learning` events) beside the replay's. A bag cut short (a killed recording) is replayed as
far as it reads, and the report says where it stopped.
"""
from __future__ import annotations

import collections
import dataclasses
import json
import logging
import math
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from calib_free.gaze.exploration import ChoiceKind, ExplorationChoice, ExplorationView, FixationOutcomeView
from calib_free.gaze.fixation import FixationController, FixationOutcome, FixationParams
from calib_free.map.adapter import MapAdapter, Sample
from calib_free.map.gaze_map import AdaptResult, GazeMap
from calib_free.map.params import GazeMapParams
from drivers.config.reader import read_config
from headctl.config.head import DEFAULT_CONFIG, FixationConfig, GazeMapConfig, load_config
from headctl.errors import ConfigError, HeadctlError
from headctl.json_types import JSONObject
from headctl.ros2 import bagtypes
from headctl.ros2.bag_reader import BagReader
from headctl.ros2.fixation_log import CONFIG, FIXATIONS, BagMessage, FixationReader, RecordedFixation, pair_topic
from headctl.service.events import plain
from headctl.service.fixation_trace import Call, Raised, StereoShot

log = logging.getLogger(__name__)

DIVERGED = "replay diverged"  # the replay asked the head for more than the recording holds
NO_MOTION = "target outside the live map (nothing was recorded after it)"
PAIRS_MISSING = "stereo pairs missing from the bag"
DIFFERENCES_KEPT = 20
LOG_EVERY = 100  # fixations between progress lines in the log
TARGET_OUTSIDE = str(FixationOutcome.TARGET_OUTSIDE)

# Called every `RelearnRequest.progress_every` fixations: (fixations replayed, taught, fixations a second).
Progress = Callable[[int, int, float], None]


class RelearnError(HeadctlError, ValueError):
    """A bag that cannot be replayed: not a bag, or without what a replay needs (named)."""


class ReplayDiverged(HeadctlError):
    """The replayed fixation asked the head for a call the recording does not hold."""


@dataclass(frozen=True)
class RelearnRequest:
    """`bag`: a recording's directory (or one of its .mcap files); `config`: a head config whose
    `gaze_map` and `fixation` sections to learn with (None: the bag's, else configs/sim.yaml);
    `every`: fixations per point of the learning curve."""

    bag: Path
    config: Path | None = None
    every: int = 100
    progress_every: int = 50

    def __post_init__(self) -> None:
        if self.every < 1:
            raise RelearnError(f"every: got {self.every}, expected at least 1 fixation a point")
        if self.progress_every < 1:
            raise RelearnError(f"progress_every: got {self.progress_every}, expected at least 1")


@dataclass
class Figures:
    """Fixations, the taught ones, the refused ones by outcome."""

    fixations: int = 0
    taught: int = 0
    refused: dict[str, int] = field(default_factory=dict)

    def add(self, outcome: str) -> None:
        self.fixations += 1
        if outcome == "taught":
            self.taught += 1
        else:
            self.refused[outcome] = self.refused.get(outcome, 0) + 1


@dataclass(frozen=True)
class CurvePoint:
    """The adaptations taught by the fixations `first` to `last` (counted from the bag's first, 1-based)."""

    first: int
    last: int
    adaptations: int
    retinal_error: float | None  # their mean, eq. 8 (a fraction of the half-ranges)
    output_error_deg: list[float] | None  # their mean |dW(r*)| per axis (pan, tilt, vergence)


@dataclass
class RelearnReport:
    bag: str
    config_source: str  # where the map and fixation settings came from
    recorded: Figures
    replayed: Figures
    agree: int = 0  # replayed fixations whose outcome is the recorded one
    differences: list[tuple[int, str, str]] = field(default_factory=list)  # (index, recorded, replayed), the first
    skipped: dict[str, int] = field(default_factory=dict)  # not replayed, by why
    curve_recorded: list[CurvePoint] = field(default_factory=list)
    curve_replayed: list[CurvePoint] = field(default_factory=list)
    problems: list[str] = field(default_factory=list)  # files cut short
    files: list[str] = field(default_factory=list)
    seconds: float = 0.0

    @property
    def truncated(self) -> bool:
        return bool(self.problems)

    @property
    def fixations_per_s(self) -> float:
        return self.replayed.fixations / self.seconds if self.seconds > 0 else float("nan")

    def as_dict(self) -> JSONObject:
        out: JSONObject = plain({**dataclasses.asdict(self), "truncated": self.truncated,
                                 "fixations_per_s": self.fixations_per_s})
        return out


class ReplayHead:
    """A `GazeHead` answering each call from a recorded fixation, in the order it was made."""

    def __init__(self, fixation: RecordedFixation) -> None:
        self.pose_low, self.pose_high = fixation.pose_low, fixation.pose_high
        self.answers: dict[Call, collections.deque[Any]] = collections.defaultdict(collections.deque)
        for call, value in fixation.calls:
            self.answers[value.call if isinstance(value, Raised) else call].append(value)

    def _next(self, call: Call) -> Any:
        answers = self.answers[call]
        if not answers:
            raise ReplayDiverged(f"one {call} call more than the recording made")
        value = answers.popleft()
        if isinstance(value, Raised):
            raise value.exception()
        return value

    def read_pose(self) -> np.ndarray:
        return np.array(self._next(Call.POSE), dtype=float)

    def move_to(self, pose: np.ndarray) -> np.ndarray:
        return np.array(self._next(Call.MOVE), dtype=float)

    def verge_to(self, vergence: float) -> float:
        return float(self._next(Call.VERGE))

    def wait_settled(self, timeout_s: float, same_rest: bool = False) -> float:
        return float(self._next(Call.SETTLED))

    def wait_pair(self, after_s: float, timeout_s: float) -> tuple[np.ndarray, np.ndarray]:
        shot: StereoShot = self._next(Call.PAIR)
        return shot.left, shot.right


class ReplayedChoice:
    """An `ExplorationPolicy` sending each saccade where the recorded one went (`planned`)."""

    def __init__(self) -> None:
        self.planned = np.zeros(3)
        self.target: np.ndarray | None = None

    def choose(self, view: ExplorationView) -> ExplorationChoice:
        return ExplorationChoice(self.planned, ChoiceKind.RANDOM if self.target is None else ChoiceKind.TARGET,
                                 target=self.target)

    def observe(self, record: FixationOutcomeView) -> None:
        pass


@dataclass(frozen=True)
class _Settings:
    map_config: GazeMapConfig
    fixation: FixationParams
    source: str

    def map_params(self, image_size: tuple[int, int]) -> GazeMapParams:
        return self.map_config.params(image_size)


def _settings(request: RelearnRequest, recorded: str | None) -> _Settings:
    """The map's and the fixations' settings: `--config`, else the bag's, else configs/sim.yaml."""
    if request.config is not None:
        config = load_config(request.config)
        return _Settings(config.gaze_map, config.fixation.params, str(request.config))
    if recorded is not None:
        where = f"{request.bag} ({CONFIG})"
        try:
            data = yaml.safe_load(recorded)
            gaze_map = read_config(GazeMapConfig, data.get("gaze_map"), "gaze_map", file=where)
            fixation = read_config(FixationConfig, data.get("fixation"), "fixation", file=where)
        except (yaml.YAMLError, AttributeError, ConfigError) as err:
            raise RelearnError(f"{where}: the recorded config does not read: {err}; give one with --config") from err
        return _Settings(gaze_map, fixation.params, "the bag's recorded config")
    config = load_config(DEFAULT_CONFIG)
    return _Settings(config.gaze_map, config.fixation.params, f"{DEFAULT_CONFIG} (the bag recorded no config)")


def _curve(taught_by: dict[int, list[tuple[float | None, list[float | None] | None]]], order: list[int],
           every: int) -> list[CurvePoint]:
    """Points of `every` fixations (in `order`, the recorded indices) from the adaptations each taught."""
    points = []
    for start in range(0, len(order), every):
        chunk = order[start:start + every]
        errors = [e for i in chunk for e, _ in taught_by.get(i, []) if e is not None and math.isfinite(e)]
        outputs = [o for i in chunk for _, o in taught_by.get(i, []) if o is not None and None not in o]
        points.append(CurvePoint(start + 1, start + len(chunk), sum(len(taught_by.get(i, [])) for i in chunk),
                                 float(np.mean(errors)) if errors else None,
                                 [float(v) for v in np.mean(np.asarray(outputs, dtype=float), axis=0)]
                                 if outputs else None))
    return points


def _json(text: str) -> Any:
    try:
        return json.loads(text)
    except ValueError:
        return text


def _events(messages: Iterator[BagMessage], learning: list[JSONObject]) -> Iterator[BagMessage]:
    """The messages, the live learning curve's points (`learning` on /head/events) kept aside."""
    store = bagtypes.typestore()
    for message in messages:
        if message.topic.endswith("/head/events"):
            msg: Any = store.deserialize_cdr(message.data, message.msgtype)
            if msg.name == "learning":
                learning.append({kv.key: _json(kv.value) for kv in msg.values})
        yield message


def relearn(request: RelearnRequest, progress: Progress | None = None) -> RelearnReport:
    """Replay the bag's fixations on a fresh map; see the module docstring."""
    started = time.monotonic()
    bag = BagReader(request.bag)
    reader = FixationReader()
    learning: list[JSONObject] = []
    report = RelearnReport(str(request.bag), "", Figures(), Figures())
    adaptations: dict[int, list[tuple[float | None, list[float | None] | None]]] = collections.defaultdict(list)
    order: list[int] = []
    controller: FixationController | None = None
    adapter: MapAdapter | None = None
    choice = ReplayedChoice()

    def on_adapted(sample: Sample, result: AdaptResult) -> None:
        if result.accepted:
            adaptations[sample.tag].append((result.retinal_error, [float(v) for v in result.output_error]))

    try:
        for fixation in reader.fixations(_events(bag.messages(), learning)):
            order.append(fixation.index)
            report.recorded.add(fixation.outcome)
            planned = fixation.array("planned")
            why = PAIRS_MISSING if fixation.missing_pairs else NO_MOTION if fixation.outcome == TARGET_OUTSIDE else ""
            if why:
                report.skipped[why] = report.skipped.get(why, 0) + 1
                continue
            shots = [v for c, v in fixation.calls if c is Call.PAIR]
            if not shots:  # the head failed before the first pair (a timeout, a fault): nothing else decides
                outcome = fixation.outcome
            else:
                head = ReplayHead(fixation)
                if controller is None or adapter is None:
                    settings = _settings(request, reader.config)
                    report.config_source = settings.source
                    height, width = shots[0].left.shape[:2]
                    gm = GazeMap(settings.map_params((width, height)), seed=settings.map_config.seed)
                    adapter = MapAdapter(gm, on_adapted=on_adapted, name="relearn-adapter").start()
                    controller = FixationController(head, adapter, settings.fixation, clock=time.monotonic,
                                                    learner=adapter, exploration=choice)
                controller.head = head
                controller.count = fixation.index  # the samples' tags: the recorded indices
                choice.planned = np.zeros(3) if planned is None else planned
                choice.target = fixation.array("explore_target")
                try:
                    outcome = str(controller.fixate().outcome)
                except ReplayDiverged as err:
                    outcome = DIVERGED
                    log.debug("fixation %d: %s", fixation.index, err)
                adapter.wait_idle()
            report.replayed.add(outcome)
            if outcome == fixation.outcome:
                report.agree += 1
            elif len(report.differences) < DIFFERENCES_KEPT:
                report.differences.append((fixation.index, fixation.outcome, outcome))
            done = report.replayed.fixations
            rate_per_s = done / max(time.monotonic() - started, 1e-9)
            if progress is not None and done % request.progress_every == 0:
                progress(done, report.replayed.taught, rate_per_s)
            if done % LOG_EVERY == 0:
                log.info("relearn: %d fixations replayed, %d taught, %.1f fixations/s", done, report.replayed.taught,
                         rate_per_s)
    finally:
        if adapter is not None:
            adapter.stop()
    report.files, report.problems = [str(f) for f in bag.files], bag.problems
    if not order:
        seen = ", ".join(sorted(reader.topics)) or "none"
        raise RelearnError(
            f"{request.bag}: no fixation records to replay: the bag has no /{FIXATIONS} messages (the recorder's "
            f"fixation records) with their pairs on /{pair_topic('left')} and /{pair_topic('right')}; "
            f"its topics: {seen}" + (f"; {'; '.join(bag.problems)}" if bag.problems else ""))
    if adapter is not None and adapter.error is not None:
        raise adapter.error
    live: dict[int, list[tuple[float | None, list[float | None] | None]]] = collections.defaultdict(list)
    for point in learning:
        index = point.get("fixation")
        if isinstance(index, int):
            error, output = point.get("retinal_error"), point.get("output_error_deg")
            live[index].append((float(error) if isinstance(error, (int, float)) else None,
                                [None if v is None else float(v) for v in output] if isinstance(output, list)
                                else None))
    report.curve_recorded = _curve(live, order, request.every)
    report.curve_replayed = _curve(adaptations, order, request.every)
    report.seconds = time.monotonic() - started
    return report


def _num(value: float | None, digits: int = 3) -> str:
    return "-" if value is None else f"{value:.{digits}f}"


def format_report(report: RelearnReport) -> str:
    """The report as `headctl experiment relearn` prints it."""
    rec, rep = report.recorded, report.replayed
    lines = [f"relearn {report.bag}: {rec.fixations} fixations recorded, {rep.fixations} replayed in "
             f"{report.seconds:.1f} s ({report.fixations_per_s:.1f} fixations/s); map and fixation settings from "
             f"{report.config_source or '-'}"]
    if report.truncated:
        lines.append("the bag is cut short: replayed what reads (" + "; ".join(report.problems) + ")")
    for why, n in report.skipped.items():
        lines.append(f"not replayed: {n} ({why})")
    lines.append(f"{'':44s} {'recorded':>9s} {'replayed':>9s}")
    lines.append(f"{'taught':44s} {rec.taught:9d} {rep.taught:9d}")
    for outcome in sorted(set(rec.refused) | set(rep.refused)):
        lines.append(f"{'refused: ' + outcome:44s} {rec.refused.get(outcome, 0):9d} {rep.refused.get(outcome, 0):9d}")
    lines.append(f"same outcome: {report.agree} of {rep.fixations}")
    for index, was, now in report.differences:
        lines.append(f"  fixation {index}: recorded {was}, replayed {now}")
    lines.append("learning curve (the adaptations of each block of fixations; retinal error eq. 8, output error deg):")
    lines.append(f"{'fixations':>13s} {'live n':>7s} {'live ret':>9s} {'live out (p, t, v)':>21s} "
                 f"{'replay n':>9s} {'replay ret':>11s} {'replay out (p, t, v)':>21s}")
    for live, again in zip(report.curve_recorded, report.curve_replayed):
        def out(p: CurvePoint) -> str:
            return "-" if p.output_error_deg is None else ", ".join(f"{v:.2f}" for v in p.output_error_deg)
        lines.append(f"{f'{live.first}-{live.last}':>13s} {live.adaptations:7d} {_num(live.retinal_error):>9s} "
                     f"{out(live):>21s} {again.adaptations:9d} {_num(again.retinal_error):>11s} {out(again):>21s}")
    return "\n".join(lines)
