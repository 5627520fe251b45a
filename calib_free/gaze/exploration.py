"""Where an exploratory fixation goes: the paper's random motor commands, or a target that teaches.

The paper draws exploratory saccades at random in motor space, so that what the map learns
does not depend on how targets are chosen (`RandomMotor`). From images, about half of such
fixations teach nothing: what the saccade brings to the foveae was out of view before it,
has no structure a patch can be matched on, repeats elsewhere in the image, or lies beyond
the map's disparity range. `TeachingExplorer` picks instead a target in the pre-fixation
pair that will teach, and lets the map's command take the head there:

- candidates: per cell of a grid over the left image, the place with the most structure in
  both directions (the smaller eigenvalue of the gradient structure tensor over a patch), so
  that a patch around it can be matched at all, and so that the targets spread over the image;
- each one's d: the patch's place in the right image along the same rows (as
  `measure_disparity` of the service finds it, `disparity.horizontal_offset`), matched
  well and without a rival along the row, within the map's disparity range; and the pose the
  map's command for (x, y, d) reaches, its pan and tilt within the joint limits (its
  vergence clipped into them: the far wall needs about the least there is);
- ranked by how near that pose comes to an aim drawn for the choice where the paper's
  random command would go (uniform within the limits and the exploration step), so that the
  poses fixations start from spread over the joint range as random commands do (the map
  takes the pose as an input, and where the head looks the room has texture or not); by how
  little has been taught near them in the image; by how often targets as far from the fovea
  taught before (strongly: `teach_rate_power`); by how often the recent target fixations near
  them in the image taught (as strongly: a place that taught nothing is rarely tried again,
  where otherwise it stays as untaught and uncertain, and so as wanted, as before); and by
  how uncertain the map is there (when
  the map says: `UncertainMap`, the predictive variance of its polynomial part; weakly, as it
  points to where fixations teach least);
- checked in that order until one has no rival elsewhere in either pre-fixation image
  (`correspondence.correspondence_map`: a repeat is what makes the two eyes' matches
  disagree).

While the map is young its commands land anywhere, so a chosen target would be missed: until
`warmup_taught` fixations have taught, and with probability `doubt_random` while the recent
target fixations land far from their targets (after a change of the head), the explorer
draws the paper's random command instead. What a fixation taught and where it landed comes
back through `observe`.

Both policies keep every command within the joint limits: `RandomMotor` draws inside them,
a target whose pan or tilt would leave them is not chosen, and a chosen target's vergence is
clipped into them.
"""
from __future__ import annotations

import collections
import enum
import logging
from dataclasses import dataclass, field
from typing import Callable, Protocol, Sequence, runtime_checkable

import cv2
import numpy as np

from calib_free.correspondence.search import CorrespondenceParams, correspondence_map
from calib_free.correspondence.stereo import row_repeat_ncc
from calib_free.correspondence.disparity import horizontal_offset
from calib_free.errors import OutOfRangeError

log = logging.getLogger(__name__)

Vector = Sequence[float] | np.ndarray


class ExplorationKind(enum.StrEnum):
    """How exploratory fixations choose where to go (`fixation.exploration` in a config)."""

    RANDOM = "random"  # the paper's: a random pose in motor space
    TEACHING = "teaching"  # a target in the pre-fixation pair that will teach


EXPLORATION_KINDS = tuple(kind.value for kind in ExplorationKind)


class ChoiceKind(enum.StrEnum):
    """What one exploratory fixation was sent to."""

    RANDOM = "random"  # a random motor command
    TARGET = "target"  # an image target through the map


@dataclass(frozen=True)
class ExplorationChoice:
    """Where an exploratory saccade goes: a relative command (deg), the image target (x, y, d)
    it was planned for, when it was, and the pan and tilt the choice aimed at (`TeachingParams.aim_spread_deg`)."""

    command: np.ndarray
    kind: ChoiceKind
    target: np.ndarray | None = None
    detail: str = ""
    aim: np.ndarray | None = None


@dataclass(frozen=True)
class ExplorationView:
    """What a policy may look at before an exploratory fixation."""

    pose: np.ndarray  # (pan, tilt, vergence) now, deg
    pose_low: np.ndarray  # the joint limits
    pose_high: np.ndarray
    pre_left: np.ndarray  # the pre-fixation pair, grey float32
    pre_right: np.ndarray
    # The map's relative command for an image target (x, y, d); OutOfRangeError outside the map.
    plan: Callable[[np.ndarray], np.ndarray]
    # '' if the map covers a position (x, y, d), else why not.
    check_position: Callable[[np.ndarray], str]
    # The map's predictive variance at (x, y, d), when it has one.
    uncertainty: Callable[[np.ndarray], float] | None = None
    # How far the right camera's rows lie below the left's (their vertical misalignment).
    row_offset_px: float = 0.0


class FixationOutcomeView(Protocol):
    """What a policy learns of a fixation once it has run (a `FixationRecord`)."""

    @property
    def taught(self) -> bool: ...

    @property
    def position(self) -> np.ndarray | None: ...

    @property
    def pose_after(self) -> np.ndarray | None: ...


class ExplorationPolicy(Protocol):
    """Chooses each exploratory saccade; told how every fixation ended."""

    def choose(self, view: ExplorationView) -> ExplorationChoice: ...

    def observe(self, record: FixationOutcomeView) -> None: ...


@runtime_checkable
class UncertainMap(Protocol):
    """A map that says how uncertain it is at a position (the gaze map's polynomial part)."""

    def uncertainty(self, position: Vector, pose: Vector | None = None) -> float: ...


def random_motor_command(rng: np.random.Generator, pose: np.ndarray, low: np.ndarray, high: np.ndarray,
                         step_deg: Sequence[float]) -> np.ndarray:
    """The paper's exploratory command: to a uniformly random pose within the joint limits
    and `step_deg` (pan, tilt, vergence) of `pose`."""
    step = np.asarray(step_deg, dtype=float)
    lo = np.maximum(low, pose - step)
    hi = np.minimum(high, pose + step)
    command: np.ndarray = rng.uniform(lo, np.maximum(lo, hi)) - pose
    return command


class RandomMotor:
    """The paper's exploration: random commands in motor space, independent of the images.

    A given generator draws exactly the commands `random_motor_command` draws from it."""

    def __init__(self, rng: np.random.Generator, step_deg: Sequence[float] = (35.0, 25.0, 20.0)) -> None:
        self.rng = rng
        self.step_deg = tuple(float(s) for s in step_deg)

    def choose(self, view: ExplorationView) -> ExplorationChoice:
        command = random_motor_command(self.rng, view.pose, view.pose_low, view.pose_high, self.step_deg)
        return ExplorationChoice(command, ChoiceKind.RANDOM)

    def observe(self, record: FixationOutcomeView) -> None:
        pass


@dataclass(frozen=True)
class TeachingParams:
    """How `TeachingExplorer` chooses targets."""

    cells: tuple[int, int] = (8, 6)  # candidate grid over the left image (columns, rows)
    structure_block_px: int = 9  # the window of the structure tensor
    min_patch_std: float = 4.0  # grey levels: flatter patches are not candidates
    min_stereo_ncc: float = 0.75  # the patch's match in the right image, along its rows
    stereo_rival_margin: float = 0.15  # a rival along the row must score this much less
    max_rival_ncc: float = 0.8  # C (eq. 1) of the patch's best rival elsewhere in its own image
    disparity_margin_px: float = 4.0  # d this far inside the map's range
    pose_margin_deg: float = 0.5  # pan and tilt reached this far inside the joint limits
    max_checks: int = 20  # candidates checked in full per fixation
    warmup_taught: int = 10  # random commands until this many fixations have taught
    doubt_window: int = 20  # recent target fixations judged for the map's landing
    doubt_miss_fraction: float = 0.1  # median miss above this fraction of the width: in doubt
    doubt_random: float = 0.5  # in doubt, the chance of a random command instead of a target
    # Each choice draws an aim, a pan and tilt uniform within the joint limits and the
    # exploration step of the pose (where the paper's random command would go), and prefers
    # candidates whose saccade reaches near it: a Gaussian of this width (deg).
    aim_spread_deg: float = 8.0
    position_bins: tuple[int, int, int] = (8, 6, 4)  # (x, y, d) cells, for spreading
    uncertainty_weight: float = 0.3  # exponent of the map's relative uncertainty in the rank
    ring_width_fraction: float = 1.0 / 16  # rings of eccentricity whose teach rates are kept, of the width
    teach_rate_power: float = 4.0  # exponent of a ring's teach rate in the rank
    # Recent target fixations near a candidate in the image (within `nearby_px` in x and y and
    # `nearby_disparity_px` in d; the last `nearby_window` of them): their teach rate, to the
    # power `teach_rate_power`, weighs the candidate. What failed to teach from a place
    # usually fails again from there.
    nearby_px: float = 6.0
    nearby_disparity_px: float = 3.0
    nearby_window: int = 200

    def __post_init__(self) -> None:
        if min(self.cells) < 1 or min(self.position_bins) < 1:
            raise ValueError(f"cells and bins must be at least 1, got {self.cells}, {self.position_bins}")
        if self.aim_spread_deg <= 0:
            raise ValueError(f"aim_spread_deg must be positive, got {self.aim_spread_deg}")
        if self.max_checks < 1:
            raise ValueError(f"max_checks must be at least 1, got {self.max_checks}")
        if self.nearby_px < 0 or self.nearby_disparity_px < 0 or self.nearby_window < 0:
            raise ValueError(f"nearby_px, nearby_disparity_px and nearby_window must be >= 0, got "
                             f"{self.nearby_px}, {self.nearby_disparity_px}, {self.nearby_window}")
        if not 0.0 <= self.doubt_random <= 1.0:
            raise ValueError(f"doubt_random must be in [0, 1], got {self.doubt_random}")


@dataclass
class _Pending:
    """The last choice, until `observe` says how its fixation ended."""

    kind: ChoiceKind
    target: np.ndarray | None = None


@dataclass
class TeachingStats:
    """What the explorer has done, for summaries."""

    chosen: collections.Counter[str] = field(default_factory=collections.Counter)  # by ChoiceKind
    taught: collections.Counter[str] = field(default_factory=collections.Counter)
    rejected: collections.Counter[str] = field(default_factory=collections.Counter)  # candidates, by reason
    random_reasons: collections.Counter[str] = field(default_factory=collections.Counter)  # why a random command


class TeachingExplorer:
    """Exploration that teaches: image targets both eyes see, with structure, unique, within
    the map's disparity range and the joint limits, where little has been taught and the map
    is least certain (see the module's doc)."""

    def __init__(self, rng: np.random.Generator, step_deg: Sequence[float] = (35.0, 25.0, 20.0),
                 correspondence: CorrespondenceParams | None = None, search_px: int | None = None,
                 params: TeachingParams | None = None) -> None:
        self.rng = rng
        self.random = RandomMotor(rng, step_deg)
        self.correspondence = correspondence or CorrespondenceParams()
        self.search_px = search_px
        self.params = params or TeachingParams()
        self.taught_count = 0
        self.misses_px: collections.deque[float] = collections.deque(maxlen=self.params.doubt_window)
        rings = int(np.ceil(0.5 / self.params.ring_width_fraction * np.hypot(1.0, 1.0))) + 1
        self._ring_attempts = np.zeros(rings)  # target fixations by eccentricity
        self._ring_taught = np.zeros(rings)
        self._position_counts = np.zeros(self.params.position_bins)
        # (x, y, d, taught) of the recent target fixations
        self._recent_targets: collections.deque[tuple[float, float, float, bool]] = collections.deque(
            maxlen=self.params.nearby_window)
        self._limits: tuple[np.ndarray, np.ndarray] | None = None
        self._image: tuple[int, int, float] | None = None  # width, height, disparity search
        self._pending: _Pending | None = None
        self.stats = TeachingStats()

    # -- the policy -----------------------------------------------------------------------
    def choose(self, view: ExplorationView) -> ExplorationChoice:
        p = self.params
        height, width = view.pre_left.shape
        search = float(self.search_px if self.search_px is not None else width // 3)
        self._image = (width, height, search)
        self._limits = (np.asarray(view.pose_low, dtype=float), np.asarray(view.pose_high, dtype=float))
        choice: ExplorationChoice | None = None
        if self.taught_count < p.warmup_taught:
            reason = f"young map ({self.taught_count} < {p.warmup_taught} taught)"
        elif self._in_doubt() and self.rng.random() < p.doubt_random:
            reason = f"recent targets missed by {np.median(self.misses_px):.0f} px (median)"
        else:
            choice = self._target(view, search)
            reason = "no candidate passed"
        if choice is None:
            self.stats.random_reasons[reason.split(" (")[0]] += 1
            choice = self.random.choose(view)
            choice = ExplorationChoice(choice.command, ChoiceKind.RANDOM, detail=reason)
        self.stats.chosen[choice.kind] += 1
        self._pending = _Pending(choice.kind, choice.target)
        return choice

    def observe(self, record: FixationOutcomeView) -> None:
        pending, self._pending = self._pending, None
        position = record.position
        if pending is not None and pending.kind is ChoiceKind.TARGET:
            assert pending.target is not None
            ring = self._ring(pending.target)
            self._ring_attempts[ring] += 1
            self._ring_taught[ring] += bool(record.taught)
            x, y, d = (float(v) for v in pending.target[:3])
            self._recent_targets.append((x, y, d, bool(record.taught)))
            # Where the fixated content was, taught or not: a refused match is mostly right,
            # and the median of the window ignores the rest.
            miss = float("inf") if position is None else float(np.hypot(*(position[:2] - pending.target[:2])))
            self.misses_px.append(miss)
        if not record.taught or position is None:
            return
        self.taught_count += 1
        if pending is not None:
            self.stats.taught[pending.kind] += 1
        if self._image is not None:
            self._position_counts[self._position_bin(position)] += 1

    # -- choosing a target ----------------------------------------------------------------
    def _in_doubt(self) -> bool:
        p = self.params
        if len(self.misses_px) < p.doubt_window // 2 or self._image is None:
            return False
        return bool(np.median(self.misses_px) > p.doubt_miss_fraction * self._image[0])

    def _target(self, view: ExplorationView, search: float) -> ExplorationChoice | None:
        p = self.params
        candidates = self.candidates(view.pre_left)
        if not len(candidates):
            self.stats.rejected["no structure"] += 1
            return None
        aim = self.random.choose(view).command[:2] + view.pose[:2]  # where the paper's command would go
        # Each candidate's d (one strip of rows), so that the pose its saccade reaches is known
        # when ranking; the checks for repeats (along the row, then anywhere in either image)
        # wait until the candidates are ranked and run best first: most are never checked.
        ranked: list[tuple[np.ndarray, np.ndarray, float, float]] = []
        for xy in candidates:
            target, ncc, problem = self.stereo_target(view, xy, search)
            plan = None if target is None else self._plan(view, target)
            if target is None or plan is None:
                self.stats.rejected[problem or "outside the map"] += 1
                continue
            reached = view.pose + plan
            if not self._within_limits(reached):
                self.stats.rejected["beyond the joint limits"] += 1
                continue
            # A far target asks for about the least vergence there is (the far wall: 1.1 deg
            # against a limit of 1): the map's command may fall a little beyond it. The head
            # goes to the limit and fine vergence takes it from there.
            assert self._limits is not None
            vergence = float(np.clip(reached[2], self._limits[0][2], self._limits[1][2]))
            plan = plan + np.array([0.0, 0.0, vergence - reached[2]])
            reached = view.pose + plan
            ranked.append((target, plan, self._rank(target, reached, aim), ncc))
        if not ranked:
            return None
        # Rank by the aim, novelty in the image, the teach rate at that eccentricity and the
        # map's uncertainty; check the best first.
        weights = np.array([w for _, _, w, _ in ranked])
        if view.uncertainty is not None and p.uncertainty_weight > 0:
            variances = np.array([view.uncertainty(target) for target, _, _, _ in ranked])
            if np.all(np.isfinite(variances)) and np.max(variances) > 0:
                weights = weights * (variances / np.max(variances)) ** p.uncertainty_weight
        checks = 0  # of repeats anywhere (the costly one)
        for index in np.argsort(-weights, kind="stable"):
            target, plan, _, ncc = ranked[index]
            problem = self.row_rival_problem(view, target, ncc, search)
            if not problem:
                if checks == p.max_checks:
                    break
                checks += 1
                problem = self.repeat_problem(view, target)
            if problem:
                self.stats.rejected[problem] += 1
                continue
            return ExplorationChoice(plan, ChoiceKind.TARGET, target=target, aim=aim)
        return None

    def candidates(self, left: np.ndarray) -> np.ndarray:
        """(x, y) of the best-structured place in each cell of the grid over the left image,
        far enough from the border for the patches matched there; (n, 2)."""
        p = self.params
        height, width = left.shape
        pw, ph = self.correspondence.patch_size
        margin_x, margin_y = pw // 2 + 6, ph // 2 + 6  # the patch and the refinement's search
        if width <= 2 * margin_x or height <= 2 * margin_y:
            return np.zeros((0, 2))
        structure = cv2.cornerMinEigenVal(left, p.structure_block_px, ksize=3)
        mean = cv2.boxFilter(left, cv2.CV_32F, (pw, ph))
        var = cv2.boxFilter(left * left, cv2.CV_32F, (pw, ph)) - mean * mean
        flat = var < p.min_patch_std ** 2
        structure[flat] = 0.0
        xs = np.linspace(margin_x, width - margin_x, p.cells[0] + 1).astype(int)
        ys = np.linspace(margin_y, height - margin_y, p.cells[1] + 1).astype(int)
        found = []
        for j in range(p.cells[1]):
            for i in range(p.cells[0]):
                cell = structure[ys[j]:ys[j + 1], xs[i]:xs[i + 1]]
                if cell.size == 0:
                    continue
                v, u = np.unravel_index(int(np.argmax(cell)), cell.shape)
                if cell[v, u] > 0:
                    found.append((xs[i] + u, ys[j] + v))
        return np.array(found, dtype=float).reshape(-1, 2)

    def stereo_target(self, view: ExplorationView, xy: np.ndarray,
                      search: float) -> tuple[np.ndarray | None, float, str]:
        """(x, y, d) with d where the patch at `xy` lies along the same rows of the right image,
        and its NCC there, if it matches well within the map's disparity range; else (None,
        NCC, why not). Whether it lies there unambiguously: `row_rival_problem`."""
        p, cp = self.params, self.correspondence
        x, y = float(xy[0]), float(xy[1])
        d, ncc = horizontal_offset(view.pre_left, view.pre_right, (x, y), cp.patch_size, (-search, search),
                                   row_offset_px=view.row_offset_px)
        if ncc < p.min_stereo_ncc:
            return None, ncc, "no match in the right image"
        target = np.array([x, y, d])
        for margin in (-p.disparity_margin_px, p.disparity_margin_px):
            if view.check_position(target + np.array([0.0, 0.0, margin])):
                return None, ncc, "disparity outside the map"
        return target, ncc, ""

    def row_rival_problem(self, view: ExplorationView, target: np.ndarray, ncc: float, search: float) -> str:
        """Why the target's d is ambiguous ('' if not): its patch matches nearly as well (NCC
        within `stereo_rival_margin` of `ncc`) elsewhere along the same rows of the right image."""
        x, y, d = (float(v) for v in target)
        rival = row_repeat_ncc(view.pre_left, view.pre_right, (x, y), self.correspondence.patch_size, d, ncc, search,
                               self.params.stereo_rival_margin, view.row_offset_px)
        return "a rival along the row" if rival is not None else ""

    def repeat_problem(self, view: ExplorationView, target: np.ndarray) -> str:
        """Why the patch at `target` repeats elsewhere in either pre-fixation image ('' if not)."""
        x, y, d = (float(v) for v in target)
        for image, cx in ((view.pre_left, x), (view.pre_right, x + d)):
            if self._rival_in_image(image, cx, y) > self.params.max_rival_ncc:
                return "a repeat elsewhere in the image"
        return ""

    def _rival_in_image(self, image: np.ndarray, x: float, y: float) -> float:
        """C (eq. 1) of the best placement of the patch at (x, y) away from its own place."""
        pw, ph = self.correspondence.patch_size
        u0, v0 = int(round(x - (pw - 1) / 2.0)), int(round(y - (ph - 1) / 2.0))
        height, width = image.shape
        if u0 < 0 or v0 < 0 or u0 + pw > width or v0 + ph > height:
            return 1.0
        cmap = correspondence_map(image, image[v0:v0 + ph, u0:u0 + pw], self.correspondence)
        r = max(pw, ph) // 2  # within this of its own place, a placement is the patch itself
        cmap[max(0, v0 - r):v0 + r + 1, max(0, u0 - r):u0 + r + 1] = -1.0
        return float(cmap.max())

    # -- bookkeeping ------------------------------------------------------------------------
    def _plan(self, view: ExplorationView, target: np.ndarray) -> np.ndarray | None:
        try:
            plan = np.asarray(view.plan(target), dtype=float)
        except OutOfRangeError:
            return None
        return plan if plan.shape == (3,) and np.all(np.isfinite(plan)) else None

    def _within_limits(self, pose: np.ndarray) -> bool:
        """Whether pan and tilt are within the limits, with the margin (vergence is clipped)."""
        assert self._limits is not None
        margin = self.params.pose_margin_deg
        low, high = (limit[:2] for limit in self._limits)
        return bool(np.all(pose[:2] >= low + margin) and np.all(pose[:2] <= high - margin))

    def _ring(self, xy: np.ndarray) -> int:
        """The ring of eccentricity (distance from the fovea) `xy` lies in."""
        assert self._image is not None
        width, height, _ = self._image
        eccentricity = float(np.hypot(xy[0] - (width - 1) / 2.0, xy[1] - (height - 1) / 2.0))
        return min(int(eccentricity / (self.params.ring_width_fraction * width)), len(self._ring_taught) - 1)

    def _teach_rate(self, xy: np.ndarray) -> float:
        """How often targets as far from the fovea taught (a prior of one taught attempt), to
        the power `teach_rate_power`. The farther out, the less the lens lets the foveal patch
        after the saccade look like its place before it (on the foveated lens, measured: 99 %
        of targets within an eighth of the width taught, 50 % at a third, 12 % beyond)."""
        ring = self._ring(xy)
        return self._weighed_rate(float(self._ring_taught[ring]), float(self._ring_attempts[ring]))

    def _nearby_teach_rate(self, target: np.ndarray) -> float:
        """How often the recent target fixations near `target` in the image taught (a prior
        of one taught attempt), to the power `teach_rate_power`."""
        p = self.params
        if not self._recent_targets:
            return 1.0
        recent = np.array(self._recent_targets)
        near = (np.abs(recent[:, 0] - target[0]) <= p.nearby_px) & (np.abs(recent[:, 1] - target[1]) <= p.nearby_px) \
            & (np.abs(recent[:, 2] - target[2]) <= p.nearby_disparity_px)
        return self._weighed_rate(float(recent[near, 3].sum()), float(near.sum()))

    def _weighed_rate(self, taught: float, attempts: float) -> float:
        """A teach rate with a prior of one taught attempt, to the power `teach_rate_power`."""
        return float(((taught + 1.0) / (attempts + 1.0)) ** self.params.teach_rate_power)

    def _position_bin(self, position: np.ndarray) -> tuple[int, ...]:
        assert self._image is not None
        width, height, search = self._image
        low = np.array([-0.5, -0.5, -search])
        high = np.array([width - 0.5, height - 0.5, search])
        return _bin(position, low, high, self.params.position_bins)

    def _rank(self, target: np.ndarray, reached: np.ndarray, aim: np.ndarray) -> float:
        """How much a fixation on `target`, reaching the pose `reached`, is wanted: near the
        aim, where little has been taught in the image (x, y; all d), at an eccentricity
        and a place that teach."""
        off = (reached[:2] - aim) / self.params.aim_spread_deg
        taught_here = float(self._position_counts[self._position_bin(target)[:2]].sum())
        return float(np.exp(max(-0.5 * off @ off, -30.0)) / np.sqrt(1.0 + taught_here) * self._teach_rate(target)
                     * self._nearby_teach_rate(target))


def _bin(value: np.ndarray, low: np.ndarray, high: np.ndarray, bins: Sequence[int]) -> tuple[int, ...]:
    n = np.asarray(bins)
    cell = np.floor((np.asarray(value, dtype=float) - low) / np.maximum(high - low, 1e-9) * n).astype(int)
    return tuple(int(c) for c in np.clip(cell, 0, n - 1))


def make_exploration(kind: str, rng: np.random.Generator, step_deg: Sequence[float] = (35.0, 25.0, 20.0),
                     correspondence: CorrespondenceParams | None = None,
                     search_px: int | None = None) -> RandomMotor | TeachingExplorer:
    """The policy `kind` (`ExplorationKind`) drawing from `rng`."""
    if kind == ExplorationKind.RANDOM:
        return RandomMotor(rng, step_deg)
    if kind == ExplorationKind.TEACHING:
        return TeachingExplorer(rng, step_deg, correspondence, search_px)
    raise ValueError(f"exploration must be one of {', '.join(EXPLORATION_KINDS)}, got {kind!r}")


__all__ = ["ChoiceKind", "EXPLORATION_KINDS", "ExplorationChoice", "ExplorationKind", "ExplorationPolicy",
           "ExplorationView", "RandomMotor", "TeachingExplorer", "TeachingParams", "UncertainMap",
           "make_exploration", "random_motor_command"]
