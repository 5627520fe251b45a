"""One gaze fixation: coarse saccade, fine vergence, correspondence, and whether it may teach.

The paper's fixation strategy (section II): a saccade (pan, tilt and vergence together)
brings the target near the foveae, then fine vergence (vergence only) until the foveal
disparity vanishes; a saccade counts as done only once the fixation has converged, and only
such fixations teach the map.

`FixationController.fixate()` runs one fixation on a `GazeHead` -- anything that reads the
head's pose, moves it, reports when it is at rest and delivers stereo pairs taken after a
given time. `headctl` implements it over the real or simulated servo bus and cameras; this
module knows no driver. Every fixation, taught or refused, returns a `FixationRecord`
saying what happened and why.

Poses are absolute (pan, tilt, vergence) in degrees; commands relative; image positions
(x, y, d) in pixels of the left image, d = x_r - x_l.
"""
from __future__ import annotations

import dataclasses
import enum
import logging
import time
from dataclasses import dataclass, field
from typing import Any, Callable, Protocol

import numpy as np

from calib_free.correspondence.search import CorrespondenceParams, FixationMatch, match_fixation
from calib_free.correspondence.stereo import stereo_inconsistency
from calib_free.correspondence.disparity import as_grey_float, foveal_offset
from calib_free.map.adapter import Sample
from calib_free.errors import CalibFreeError, OutOfRangeError
from calib_free.gaze.exploration import (EXPLORATION_KINDS, ExplorationPolicy, ExplorationView, UncertainMap,
                                    make_exploration, random_motor_command)
from calib_free.map.gaze_map import Vector

log = logging.getLogger(__name__)


class HeadTimeoutError(CalibFreeError, TimeoutError):
    """The head did not come to rest in time."""


class PairTimeoutError(HeadTimeoutError):
    """No stereo pair exposed after the given time arrived in time."""


class GazeHead(Protocol):
    """What a fixation needs of a head. Poses are (pan, tilt, vergence), degrees."""

    pose_low: np.ndarray  # joint limits of (pan, tilt, vergence)
    pose_high: np.ndarray

    def read_pose(self) -> np.ndarray:
        """The pose now, from the encoders."""

    def move_to(self, pose: np.ndarray) -> np.ndarray:
        """Command an absolute pose (clamped to the limits); returns the pose commanded."""

    def verge_to(self, vergence: float) -> float:
        """Command the eyes alone to an absolute vergence (clamped); returns the vergence commanded."""

    def wait_settled(self, timeout_s: float, same_rest: bool = False) -> float:
        """Block until the head is at rest; the monotonic time from which it was. A head found
        still at the rest of the last call may answer the time now instead (a pair waited for
        after it then shows the view as it is now), unless `same_rest`: the caller knows
        nothing changed since that rest and will take a pair exposed during it."""

    def wait_pair(self, after_s: float, timeout_s: float) -> tuple[np.ndarray, np.ndarray]:
        """The first (left, right) pair exposed entirely after `after_s`; PairTimeoutError if none."""


class MapReader(Protocol):
    def command(self, position: Vector, pose: Vector | None = None) -> np.ndarray:
        """The relative command for `position` seen at `pose` (pan, tilt, vergence)."""

    def check_position(self, position: Vector) -> str:
        """'' if the map covers `position`, else why not."""


@dataclass(frozen=True)
class LookParams:
    """How a closed-loop look (`calib_free.gaze.look`) finds its target again and corrects."""

    tolerance_px: float = 1.0  # the target this near the left fovea: the look is on target
    max_corrective_steps: int = 3  # corrective fixations after the first before giving up
    # Past those, up to this many more while the target lies within `finishing_reach_px` of the
    # fovea: a target that near is found where a step can have left it, not taken from among
    # repeats, and the servos' play can leave it a pixel or two off after a step.
    finishing_steps: int = 2
    finishing_reach_px: float = 3.0
    target_patch_size: tuple[int, int] = (21, 21)  # (w, h) of the target's patch, px
    min_target_ncc: float = 0.7  # the target's patch matched less well than this: not found
    # Grey levels: a patch less textured than this has nothing to be found by. Two exposures of
    # one patch differ by the sensor's noise n, and match at NCC 1 - n^2 / std^2; to reach
    # min_target_ncc 0.7 the patch needs std >= 1.8 n. A webcam's noise at mid grey is about
    # 2-3 grey levels (docs/sim-world.md), more under auto gain: 6 leaves a third to spare.
    min_patch_std: float = 6.0
    ambiguity_ncc_margin: float = 0.1  # a second place matching within this of the best: ambiguous
    # The larger patch, where the smaller repeats in its own view, must match its own view's
    # second place worse than the best by this much to be used (`calib_free.gaze.refind`)
    context_ncc_margin: float = 0.25
    search_radius_px: int | None = None  # how far from the fovea to search the target (None: width/3)
    max_target_scale: float = 4.0  # the most the view may magnify the target's patch between views
    # Converged this far (deg) from the vergence the map gives the target's d: another depth, not
    # the target. After 5 minutes of exploring, the map's vergence for a d is that far off where
    # the left eye is on the target: of 472 recorded realistic looks that converged truly within
    # 3 px, 17 ended 3 deg or more from it, 2 beyond 5 deg (7.7 at most). At 3 deg, the check
    # refused 35 looks in the real-time benchmark's runs: 34 truly on target (33 within 6 deg)
    # and one look-alike at 13.5 deg; offline, the look-alikes it refused lay 3.1-12.4 deg off,
    # 3 of 6 within 6 (docs/method.md).
    max_vergence_mismatch_deg: float = 6.0

    def __post_init__(self) -> None:
        if self.tolerance_px <= 0:
            raise ValueError(f"tolerance_px must be positive, got {self.tolerance_px}")
        if self.max_corrective_steps < 0:
            raise ValueError(f"max_corrective_steps must be >= 0, got {self.max_corrective_steps}")
        if self.finishing_steps < 0:
            raise ValueError(f"finishing_steps must be >= 0, got {self.finishing_steps}")
        if not self.finishing_reach_px >= self.tolerance_px:
            raise ValueError(f"finishing_reach_px must be at least tolerance_px ({self.tolerance_px}), "
                             f"got {self.finishing_reach_px}")
        if min(self.target_patch_size) < 5:
            raise ValueError(f"target_patch_size must be at least 5 x 5 pixels, got {self.target_patch_size}")
        if not -1.0 < self.min_target_ncc < 1.0:
            raise ValueError(f"min_target_ncc must be in (-1, 1), got {self.min_target_ncc}")
        if not self.min_patch_std > 0:
            raise ValueError(f"min_patch_std must be positive, got {self.min_patch_std}")
        if not 0.0 <= self.ambiguity_ncc_margin < 1.0:
            raise ValueError(f"ambiguity_ncc_margin must be in [0, 1), got {self.ambiguity_ncc_margin}")
        if not self.ambiguity_ncc_margin <= self.context_ncc_margin < 1.0:
            raise ValueError(f"context_ncc_margin must be in [ambiguity_ncc_margin, 1), got {self.context_ncc_margin}")
        if self.search_radius_px is not None and self.search_radius_px < 1:
            raise ValueError(f"search_radius_px must be at least 1 px, got {self.search_radius_px}")
        if not 1.0 <= self.max_target_scale <= 16.0:
            raise ValueError(f"max_target_scale must be in [1, 16], got {self.max_target_scale}")
        if self.max_vergence_mismatch_deg <= 0:
            raise ValueError(f"max_vergence_mismatch_deg must be positive, got {self.max_vergence_mismatch_deg}")


@dataclass(frozen=True)
class FixationParams:
    """How a fixation runs and what it takes for one to teach."""

    vergence_tolerance_px: float = 1.0  # |foveal disparity| at which vergence has converged
    max_vergence_steps: int = 5  # fine-vergence moves before giving up
    # deg of vergence per px of foveal disparity; None: the map's own d-to-vergence slope at
    # the fovea, `fallback_vergence_gain` while that slope is implausible (a young map)
    vergence_gain_deg_per_px: float | None = None
    fallback_vergence_gain: float = 0.2
    vergence_patch_size: tuple[int, int] = (32, 20)
    vergence_search_px: int | None = None  # how far either side of the right fovea to look (None: width/3)
    min_vergence_ncc: float = 0.6  # foveal patches less alike than this: nothing to verge on
    # Rows either side of the right fovea's the foveal match may lie on when it is not found
    # near the rows it was last found on: the two cameras' vertical misalignment (optical
    # centres off the image centre by up to 10 px each on board-lens webcams), which no eye
    # movement removes.
    vergence_band_px: int = 24
    confidence_floor: float = 0.3  # the least confidence (eq. 7) that teaches
    settle_timeout_s: float = 3.0
    frame_timeout_s: float = 2.0
    executed_command: str = "encoders"  # or "commanded": the planned move, as the paper's fig. 9 learns
    # An exploratory saccade goes to a random pose within the limits and at most this far
    # (pan, tilt, vergence) from the current one: farther, what it fixates was rarely in
    # view before it, and such a fixation cannot teach.
    exploration_step_deg: tuple[float, float, float] = (35.0, 25.0, 20.0)
    # Where exploratory fixations go (`calib_free.gaze.exploration`): "random", the paper's random
    # commands in motor space, or "teaching", image targets chosen so that the fixation teaches.
    exploration: str = "teaching"
    correspondence: CorrespondenceParams = field(default_factory=CorrespondenceParams)
    look: LookParams = field(default_factory=LookParams)  # closed-loop looks (`calib_free.gaze.look`)

    def __post_init__(self) -> None:
        if self.vergence_tolerance_px <= 0:
            raise ValueError(f"vergence_tolerance_px must be positive, got {self.vergence_tolerance_px}")
        if self.max_vergence_steps < 0:
            raise ValueError(f"max_vergence_steps must be >= 0, got {self.max_vergence_steps}")
        if not 0.0 <= self.confidence_floor <= 1.0:
            raise ValueError(f"confidence_floor must be in [0, 1], got {self.confidence_floor}")
        if self.executed_command not in ("encoders", "commanded"):
            raise ValueError(f"executed_command must be 'encoders' or 'commanded', got {self.executed_command!r}")
        if self.exploration not in EXPLORATION_KINDS:
            raise ValueError(f"exploration must be one of {', '.join(EXPLORATION_KINDS)}, got {self.exploration!r}")


STUCK_PX = 0.25  # a corrective step that moved what it corrects by less than this was not made
MAX_BOOST = 2.0  # the most a step not made is lengthened, times its own


def next_boost(boost: float, change: float | None) -> float:
    """How much longer than planned the next corrective step goes, after one that moved what it
    corrects by `change` (None: the first): fine vergence's foveal disparity, signed; a look's
    target, its displacement in the image. A step smaller than the servos' dead band, or taken
    up by the play of a reversal, leaves it where it was: the next is twice as long."""
    return min(boost * 2.0, MAX_BOOST) if change is not None and abs(change) < STUCK_PX else 1.0


class FixationOutcome(enum.StrEnum):
    """How a fixation ended: it taught the map, or why it did not. The values are what the
    status, the events and the logs show."""

    TAUGHT = "taught"
    TARGET_OUTSIDE = "target outside the map"
    TARGET_REFUSED = "target refused before the saccade"
    NOT_SETTLED = "head did not settle"
    NO_FRAMES = "no stereo pair in time"
    NO_VERGENCE_MATCH = "foveal patches do not match"
    NOT_CONVERGED = "vergence did not converge"
    LOW_CONFIDENCE = "confidence below the floor"
    POSITION_OUTSIDE = "correspondence outside the map"
    INCONSISTENT = "left and right matches disagree"
    # Interrupted by the head (`FixationInterrupted`): the motion already sent completes,
    # nothing further is sent, nothing is taught.
    BUS_DOWN = "servo bus down"
    SERVO_FAULT = "servo fault"
    SHUTDOWN = "aborted at shutdown"
    CANCELLED = "look cancelled"


class FixationKind(enum.StrEnum):
    TARGET = "target"  # a client's image target
    EXPLORE = "explore"  # an exploratory command


class FixationInterrupted(CalibFreeError):
    """Raised by a head when the fixation in progress must stop: the head is shutting down, a
    client cancelled the look, the servo bus went down or a servo faulted. `outcome` says
    which; the fixation ends refused with it."""

    def __init__(self, outcome: FixationOutcome, detail: str) -> None:
        super().__init__(detail)
        self.outcome = outcome


class SampleSink(Protocol):
    """Where taught fixations go (a `calib_free.map.adapter.MapAdapter`)."""

    def submit(self, sample: Sample) -> None: ...


@dataclass
class FixationRecord:
    """Everything about one fixation, taught or refused."""

    index: int
    kind: FixationKind
    target: np.ndarray | None = None  # the client's (x, y, d)
    explore_target: np.ndarray | None = None  # the image target an exploratory saccade was planned for
    planned: np.ndarray | None = None  # the saccade's relative command
    pose_before: np.ndarray | None = None
    pose_after: np.ndarray | None = None
    executed: np.ndarray | None = None  # the relative command the head executed
    vergence_disparities_px: list[float] = field(default_factory=list)
    vergence_steps: int = 0
    converged: bool = False
    match: FixationMatch | None = None
    outcome: FixationOutcome | None = None  # None while the fixation runs
    detail: str = ""
    duration_s: float = 0.0
    # A target fixation's left image before the saccade and its pair at the end (at rest, after
    # fine vergence), grey: what a closed-loop look finds its target in. Not in `as_dict()`.
    pre_left_image: np.ndarray | None = field(default=None, repr=False)
    final_left_image: np.ndarray | None = field(default=None, repr=False)
    final_right_image: np.ndarray | None = field(default=None, repr=False)

    @property
    def taught(self) -> bool:
        return self.outcome is FixationOutcome.TAUGHT

    @property
    def position(self) -> np.ndarray | None:
        return None if self.match is None else self.match.position

    @property
    def confidence(self) -> float:
        return float("nan") if self.match is None else self.match.confidence

    @property
    def landing_error_px(self) -> float | None:
        """How far from the image target it aimed at (a client's or an exploratory one) the
        saccade landed, in the image before it: from the correspondence, only if it taught."""
        aim = self.target if self.target is not None else self.explore_target
        if aim is None or not self.taught or self.position is None:
            return None
        return float(np.hypot(*(self.position[:2] - np.asarray(aim, dtype=float)[:2])))

    _NOT_IN_DICT = frozenset({"match", "pre_left_image", "final_left_image", "final_right_image"})

    def as_dict(self) -> dict[str, Any]:
        def plain(v: Any) -> Any:
            return v.tolist() if isinstance(v, np.ndarray) else v

        out = {f.name: plain(getattr(self, f.name)) for f in dataclasses.fields(self) if f.name not in self._NOT_IN_DICT}
        out["position"] = plain(self.position)
        out["confidence"] = None if self.match is None else self.confidence
        out["factors"] = None if self.match is None else self.match.factors()
        return out


class FixationController:
    """Runs fixations on a head with a (shared, concurrently adapted) map."""

    # deg of vergence per px of disparity a real head can have (negative: d < 0 converges)
    PLAUSIBLE_GAIN = (-2.0, -0.02)

    def __init__(self, head: GazeHead, gaze_map: MapReader, params: FixationParams | None = None,
                 image_size: tuple[int, int] | None = None, seed: int | None = None,
                 clock: Callable[[], float] = time.monotonic, learner: SampleSink | None = None,
                 exploration: ExplorationPolicy | None = None) -> None:
        self.head = head
        self.map = gaze_map
        self.learner = learner  # taught fixations are submitted here
        self.params = params or FixationParams()
        self.image_size = image_size
        self.rng = np.random.default_rng(seed)
        self.clock = clock
        self.count = 0
        # How far the right camera's rows lie below the left's at the foveae (their vertical
        # misalignment): where the last converged fixation found the foveal match.
        self.row_offset_px = 0.0
        p = self.params
        # Where exploratory fixations go: `params.exploration`'s policy, drawing from `rng`.
        self.exploration: ExplorationPolicy = exploration if exploration is not None else make_exploration(
            p.exploration, self.rng, p.exploration_step_deg, p.correspondence, p.vergence_search_px)

    # -- the map's view of vergence ----------------------------------------------------------
    def vergence_gain(self, width: int, height: int) -> float:
        """Degrees of vergence per pixel of foveal disparity (negative: d < 0 needs converging).

        From the map: the vergence of W at the fovea over d = +-10 px. A young, random map
        gives nonsense, so outside `PLAUSIBLE_GAIN` the fallback gain is used.
        """
        p = self.params
        if p.vergence_gain_deg_per_px is not None:
            return -abs(p.vergence_gain_deg_per_px)
        cx, cy = (width - 1) / 2.0, (height - 1) / 2.0
        try:
            slope = (self.map.command((cx, cy, 10.0))[2] - self.map.command((cx, cy, -10.0))[2]) / 20.0
        except OutOfRangeError:
            slope = 0.0
        if self.PLAUSIBLE_GAIN[0] <= slope <= self.PLAUSIBLE_GAIN[1]:
            return float(slope)
        return -abs(p.fallback_vergence_gain)

    def foveal_offset(self, left: np.ndarray, right: np.ndarray) -> tuple[float, float, float]:
        """The foveal match (dx, dy, NCC): on the rows it was last found on, else within
        `vergence_band_px` rows of the fovea's (the cameras' misalignment found afresh)."""
        p = self.params
        near = foveal_offset(left, right, p.vergence_patch_size, p.vergence_search_px, 0, self.row_offset_px)
        if near[2] >= p.min_vergence_ncc or p.vergence_band_px <= 0:
            return near
        wide = foveal_offset(left, right, p.vergence_patch_size, p.vergence_search_px, p.vergence_band_px)
        return wide if wide[2] > near[2] else near

    # -- one fixation ---------------------------------------------------------------------
    def random_command(self, pose: np.ndarray) -> np.ndarray:
        """An exploratory command: to a uniformly random pose within the joint limits and
        `exploration_step_deg` of the current pose."""
        return random_motor_command(self.rng, pose, self.head.pose_low, self.head.pose_high,
                                    self.params.exploration_step_deg)

    def fixate(self, target: Vector | None = None, reference_pose: Vector | None = None,
               continues: bool = False, target_check: Callable[[np.ndarray], str] | None = None) -> FixationRecord:
        """One fixation: to a client's image target (x, y, d), or exploratory when None.

        `reference_pose`: the pose whose view the target was chosen in, when the head may have
        moved since (a queued look); the saccade then goes to that pose plus the map's command
        for the target, which is where the client meant, from wherever the head is now.
        `continues`: the fixation follows one that ended at rest, with nothing changed since
        but the target found in its last pair (a look's corrective step): a head still at that
        rest starts from a pair of it instead of waiting for a new one.
        `target_check`: judges the target in the left image before the saccade (grey), where
        the fixation will look for it; a reason it gives ends the fixation before the head
        moves (`FixationOutcome.TARGET_REFUSED`)."""
        started = self.clock()
        record = FixationRecord(index=self.count, kind=FixationKind.EXPLORE if target is None else FixationKind.TARGET)
        self.count += 1
        if target is not None:
            record.target = np.asarray(target, dtype=float)
        try:
            self._run(record, target, reference_pose, continues, target_check)
        except HeadTimeoutError as err:
            record.outcome = FixationOutcome.NO_FRAMES if isinstance(err, PairTimeoutError) \
                else FixationOutcome.NOT_SETTLED
            record.detail = str(err)
        except FixationInterrupted as err:
            record.outcome, record.detail = err.outcome, str(err)
        record.duration_s = self.clock() - started
        log.debug("fixation %d (%s): %s %s", record.index, record.kind, record.outcome, record.detail)
        if record.taught and self.learner is not None:
            assert record.position is not None and record.executed is not None
            self.learner.submit(Sample(record.position, record.executed, record.confidence, tag=record.index,
                                       pose=record.pose_before))
        self.exploration.observe(record)
        return record

    def _run(self, record: FixationRecord, target: Vector | None, reference_pose: Vector | None = None,
             continues: bool = False, target_check: Callable[[np.ndarray], str] | None = None) -> None:
        p = self.params
        head = self.head
        # The pre-fixation pair, at rest. Every pair of a fixation is taken with the head at
        # rest, so unsynchronised cameras need no correction here: a still head sees a still
        # scene, and its two images show the same whatever time apart they were exposed
        # (pursuit, where the head moves during a pair, corrects its disparity for that).
        rest_s = head.wait_settled(p.settle_timeout_s, same_rest=continues)
        pre_left, pre_right = (as_grey_float(im) for im in head.wait_pair(rest_s, p.frame_timeout_s))
        if target is not None:
            record.pre_left_image = pre_left
        pose_before = head.read_pose()
        record.pose_before = pose_before
        if target is not None and target_check is not None:
            refused = target_check(pre_left)
            if refused:
                record.outcome, record.detail = FixationOutcome.TARGET_REFUSED, refused
                return
        height, width = pre_left.shape
        if target is None:
            gaze_map = self.map
            choice = self.exploration.choose(ExplorationView(
                pose_before, head.pose_low, head.pose_high, pre_left, pre_right,
                lambda r: gaze_map.command(r, pose=pose_before), gaze_map.check_position,
                (lambda r: gaze_map.uncertainty(r, pose=pose_before)) if isinstance(gaze_map, UncertainMap) else None,
                self.row_offset_px))
            planned, record.explore_target = choice.command, choice.target
        else:
            try:
                seen_at = pose_before if reference_pose is None else np.asarray(reference_pose, dtype=float)
                planned = np.asarray(self.map.command(target, pose=seen_at), dtype=float)
                if reference_pose is not None:
                    planned = np.asarray(reference_pose, dtype=float) + planned - pose_before
            except OutOfRangeError as err:
                record.outcome, record.detail = FixationOutcome.TARGET_OUTSIDE, str(err)
                return
        record.planned = planned
        # Coarse saccade: pan, tilt and vergence together.
        goal = head.move_to(pose_before + planned)
        commanded = goal - pose_before  # the relative moves commanded, summed
        rest_s = head.wait_settled(p.settle_timeout_s)
        left, right = head.wait_pair(rest_s, p.frame_timeout_s)
        # Fine vergence: vergence only, until the foveal disparity vanishes. The first step
        # uses the map's gain; later ones the secant of what the last step really did.
        gain = self.vergence_gain(width, height)
        last_step: tuple[float, float] | None = None  # (vergence moved, disparity before it)
        boost = 1.0
        for step in range(p.max_vergence_steps + 1):
            disparity, rows, score = self.foveal_offset(left, right)
            record.vergence_disparities_px.append(disparity)
            if last_step is not None and disparity != last_step[1]:
                # Newton on disparity(vergence): the step that would cancel what is left.
                secant = -last_step[0] / (disparity - last_step[1])
                if self.PLAUSIBLE_GAIN[0] <= secant <= self.PLAUSIBLE_GAIN[1]:
                    gain = secant
            if score < p.min_vergence_ncc:
                record.outcome = FixationOutcome.NO_VERGENCE_MATCH
                record.detail = f"NCC {score:.2f} < {p.min_vergence_ncc} between the foveae"
                break
            if abs(disparity) <= p.vergence_tolerance_px:
                record.converged = True
                self.row_offset_px = rows
                break
            if step == p.max_vergence_steps:
                break
            record.vergence_steps += 1
            boost = next_boost(boost, None if last_step is None else disparity - last_step[1])
            before = head.read_pose()[2]
            vergence = head.verge_to(before + boost * gain * disparity)  # the eyes only: pan and tilt stay put
            commanded = commanded + np.array([0.0, 0.0, vergence - before])
            rest_s = head.wait_settled(p.settle_timeout_s)
            left, right = head.wait_pair(rest_s, p.frame_timeout_s)
            last_step = (float(head.read_pose()[2] - before), disparity)
        if target is not None:
            record.final_left_image, record.final_right_image = as_grey_float(left), as_grey_float(right)
        pose_after = head.read_pose()
        record.pose_after = pose_after
        if p.executed_command == "encoders":
            record.executed = pose_after - pose_before
        else:  # what was commanded: the saccade and the vergence steps, relative to each reading
            record.executed = commanded
        if not record.converged:
            if record.outcome is None:
                record.outcome = FixationOutcome.NOT_CONVERGED
                record.detail = (f"|disparity| {abs(record.vergence_disparities_px[-1]):.1f} px > "
                                 f"{p.vergence_tolerance_px} px after {record.vergence_steps} steps")
            return
        # Where was what is now on the foveae? (II-B, II-C)
        record.match = match = match_fixation(pre_left, pre_right, as_grey_float(left), as_grey_float(right),
                                              p.correspondence)
        problem = self.map.check_position(match.position)
        if problem:
            record.outcome, record.detail = FixationOutcome.POSITION_OUTSIDE, problem
            return
        # The stereo consistency check goes beyond eqs. 1-7: not in the paper's profile.
        problem = "" if p.correspondence.paper else stereo_inconsistency(record.match, pre_left, pre_right,
                                                                          p.correspondence, self.row_offset_px)
        if problem:
            record.outcome, record.detail = FixationOutcome.INCONSISTENT, problem
            return
        if record.confidence < p.confidence_floor:
            record.outcome = FixationOutcome.LOW_CONFIDENCE
            record.detail = (f"c = {record.confidence:.2f} < {p.confidence_floor} (left {match.left.confidence:.2f}, "
                             f"right {match.right.confidence:.2f})")
            return
        record.outcome = FixationOutcome.TAUGHT
