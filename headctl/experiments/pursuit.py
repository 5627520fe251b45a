"""`headctl experiment pursuit`: tracking error against the target's angular speed.

On the simulated head (`headctl.experiments.online.SimulatedHeadRig`, a `ManualClock`), a textured cube
sweeps back and forth around the head (`drivers.sim.motion`) at each speed in turn, and the
service's own pursuit (`headctl.service.tracking.Tracking`) follows it with a learned map.
The error is the ground truth: where the cube's front-face centre (the point the track
started on) is projected in the left image at each frame's exposure, from the servos' true
positions, measured from the fovea. Reported per speed: RMS and p95 over the run (after the
first `settle_s`), the lost-lock count (a lost track is started again on the cube), and the
frame-to-command latency.

How the delay is modelled on the manual clock: frames fall on the cameras' grid (n / fps);
a pair is handed to the tracker `latency_s - half a servo period` after its exposure (the
render, the capture thread and the processing of the real-time daemon, measured there), and
its goal reaches the servos at the next servo cycle (100 Hz), as the servo loop writes it.
The pose at exposure is the servos' own at that instant.
"""
from __future__ import annotations

import csv
import dataclasses
import json
import logging
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Mapping, TypedDict

import numpy as np

from calib_free.map.file import read_map
from calib_free.map.gaze_map import GazeMap
from calib_free.sim.experiments import EXPERIMENTS, run_experiment
from calib_free.gaze.pursuit import PoseHistory, PursuitParams, TrackOutcome
from drivers.cameras.camera import Frame
from drivers.cameras.config import FrameTimingConfig
from drivers.cameras.stereo import DEFAULT_TOLERANCE_PERIODS, FrameMatcher, StereoFrames
from drivers.servo.bus import BusState
from drivers.sim.camera import SimulatedCamera
from drivers.sim.camera_effects.frame_timing import FrameSlot
from drivers.sim.motion import MovingObject, SceneMotion
from drivers.config.reader import read_config
from headctl.config.head import HeadConfig, load_config
from headctl.experiments.online import SimulatedHeadRig, sim_config
from headctl.service.build import build_head
from headctl.service.tracking import Publish, Tracking

log = logging.getLogger(__name__)

SPEEDS_DEG_S = (5.0, 10.0, 20.0, 30.0, 40.0)
GOALS_RMS_PX = {10.0: 2.0, 30.0: 5.0}


def learned_map(rig: SimulatedHeadRig, fixations: int = 3000, seed: int = 0) -> GazeMap:
    """A map learned from `fixations` random fixations of the rig's geometric head model."""
    width, height = rig.config.image_size
    gm = GazeMap(rig.config.map_params(), seed=seed)
    run_experiment(dataclasses.replace(EXPERIMENTS["learn"], fixations=fixations), gm, rig.model, seed=seed,
                   landing_every=0)
    return gm


class GridPairs:
    """The cameras and the servo loop on the manual clock: each eye's frames rendered at the
    exposures of its own timing (`drivers.sim.camera_effects.frame_timing.FrameTiming`, from the camera's
    config: one grid n / fps for both eyes when ideal, each eye its own phase, drift, jitter,
    lost and late frames when free-running), paired as `drivers.cameras.stereo.StereoPair`
    pairs them, each pair handed over `delay_s` after its later exposure (frames go on being
    exposed meanwhile), and goals written at the next servo cycle. Records the pose at every
    exposure and servo cycle, and the target's true image position at every left exposure;
    `at` is the tracker's pose source (interpolated, as the service's servo states are)."""

    def __init__(self, rig: SimulatedHeadRig, fps: float, delay_s: float, truth: Callable[[], np.ndarray],
                 servo_period_s: float = 0.01, seed: int = 0) -> None:
        self.rig, self.fps, self.delay_s, self.truth = rig, fps, delay_s, truth
        self.servo_period_s = servo_period_s
        cameras = (rig.devices.cameras["left"], rig.devices.cameras["right"])
        assert all(isinstance(c, SimulatedCamera) for c in cameras)
        self.cameras: tuple[SimulatedCamera, SimulatedCamera] = cameras  # type: ignore[assignment]
        self.timings = tuple(c.timing for c in self.cameras)
        world = rig.devices.world
        assert world is not None
        self.world = world
        self.history = PoseHistory(size=4096)
        self.true_positions: list[tuple[float, np.ndarray]] = []
        tolerance_s = rig.config.cameras.tolerance_s
        periods_s = (self.timings[0].period_s, self.timings[1].period_s)
        self.matcher = FrameMatcher(tolerance_s if tolerance_s is not None else
                                    DEFAULT_TOLERANCE_PERIODS * max(periods_s), periods_s)
        now = rig.clock.monotonic()
        self._next_index = [t.index_at(now) + 1 for t in self.timings]
        self._pending: list[tuple[float, int, Frame]] = []  # exposed, not yet delivered (late frames)
        self._pairs: list[StereoFrames] = []  # paired, not yet handed over
        self._counter = 0
        self._noise_std = rig.config.cameras.left.noise_std
        self._rng = np.random.default_rng(seed)
        self._last_times_s: tuple[float, float] | None = None

    def _next_exposure(self) -> tuple[int, FrameSlot]:
        side = min((0, 1), key=lambda i: self.timings[i].exposure_start_s(self._next_index[i]))
        return side, self.timings[side].slot(self._next_index[side])

    def _deliver(self, now_s: float) -> None:
        due = sorted((item for item in self._pending if item[0] <= now_s), key=lambda item: item[0])
        self._pending = [item for item in self._pending if item[0] > now_s]
        for _, side, frame in due:
            pair = self.matcher.add(side, frame)
            if pair is not None:
                self._pairs = [*self._pairs[-3:], pair]

    def _expose(self, side: int, slot: FrameSlot) -> None:
        """Frame `slot` of eye `side`, at its exposure (the clock there): the world then."""
        now = self.rig.clock.monotonic()
        if side == 0:
            self.true_positions.append((now, self.truth()))
        if slot.dropped:
            return
        image = self.cameras[side].render(self.world.true_joints(), now)
        if self._noise_std > 0:
            noisy = image.astype(np.float32) + self._rng.normal(0.0, self._noise_std, image.shape).astype(np.float32)
            image = np.clip(noisy, 0, 255).astype(np.uint8)
        self._counter += 1
        timing = self.timings[side]
        frame = Frame(self.cameras[side].name, self._counter, image, slot.timestamp_s,
                      slot.timestamp_s - timing.max_stamp_lag_s)
        self._pending.append((slot.delivery_s, side, frame))

    def advance_to(self, time_s: float) -> None:
        """Move the clock to `time_s`, exposing every frame of both eyes on the way."""
        clock = self.rig.clock
        while True:
            side, slot = self._next_exposure()
            if slot.exposure_start_s > time_s:
                break
            self._next_index[side] += 1
            clock.sleep(slot.exposure_start_s - clock.monotonic())
            self._deliver(clock.monotonic())
            self._record_pose()
            self._expose(side, slot)
        clock.sleep(time_s - clock.monotonic())
        self._deliver(clock.monotonic())

    def _record_pose(self) -> None:
        state = self.rig.bus.read_state()
        self.history.add(self.rig.clock.monotonic(), self.rig.head.pose_from(state.positions))

    def next_pair_s(self) -> tuple[float, float]:
        """The left exposure of the next pair not yet exposed, and a time before both its
        frames' conservative starts (that pair is then the first exposed after it)."""
        left, right = self.timings
        index = left.index_at(self.rig.clock.monotonic()) + 1
        while True:
            left_s = left.exposure_start_s(index)
            near = right.index_at(left_s)
            right_s = min((right.exposure_start_s(n) for n in (near, near + 1)), key=lambda t: abs(t - left_s))
            before_s = min(left_s - left.max_stamp_lag_s, right_s - right.max_stamp_lag_s) - 1e-6
            if before_s >= self.rig.clock.monotonic():
                return left_s, before_s
            index += 1

    def _next_event_s(self) -> float:
        """When the next frame is exposed or delivered."""
        _, slot = self._next_exposure()
        return min([slot.exposure_start_s, *(item[0] for item in self._pending)])

    # -- PairSource -----------------------------------------------------------------------
    @property
    def last_exposure_s(self) -> float | None:
        return None if self._last_times_s is None else max(self._last_times_s)

    @property
    def last_pair_times_s(self) -> tuple[float, float] | None:
        return self._last_times_s

    def wait_pair(self, after_s: float, timeout_s: float) -> tuple[np.ndarray, np.ndarray]:
        while not any(p.exposure_start_s >= after_s - 1e-9 for p in self._pairs):
            self.advance_to(max(self.rig.clock.monotonic(), self._next_event_s()))
        pair = next(p for p in self._pairs if p.exposure_start_s >= after_s - 1e-9)
        self._pairs = [p for p in self._pairs if p.left.counter > pair.left.counter]
        self.advance_to(max(self.rig.clock.monotonic(), max(pair.left.time_s, pair.right.time_s) + self.delay_s))
        self._last_times_s = (pair.left.time_s, pair.right.time_s)
        return pair.left.image, pair.right.image

    # -- JointBus (the servo loop's timing) -------------------------------------------------
    def read_state(self) -> BusState:
        return self.rig.bus.read_state()

    def write_goals(self, goals: Mapping[str, float]) -> dict[str, float]:
        now = self.rig.clock.monotonic()
        self.advance_to(math.floor(now / self.servo_period_s + 1) * self.servo_period_s)
        self._record_pose()
        return self.rig.bus.write_goals(goals)

    # -- ExposurePoses ------------------------------------------------------------------
    def at(self, time_s: float) -> np.ndarray | None:
        return self.history.at(time_s)

    def __enter__(self) -> "GridPairs":
        return self

    def __exit__(self, *exc: object) -> None:
        pass


def with_timing(config: HeadConfig, timing: str | None, skew_s: float | None = None) -> HeadConfig:
    """`config` with both cameras on the frame timing preset `timing` (None: as it is), the
    right camera's phase `skew_s` after the left's when given (before it when negative); an
    unsynchronised pair takes the default tolerance, which finds its nearest frames."""
    if timing is None:
        return config
    phases = (None, None) if skew_s is None else (max(0.0, -skew_s), max(0.0, skew_s))
    cameras = {side: dataclasses.replace(getattr(config.cameras, side), timing=read_config(
        FrameTimingConfig, {"model": timing, **({} if phase is None else {"phase_s": phase})},
        f"cameras.{side}.timing")) for side, phase in zip(("left", "right"), phases)}
    tolerance = config.cameras.tolerance_s if timing == "ideal" else None
    return dataclasses.replace(config, cameras=dataclasses.replace(config.cameras, tolerance_s=tolerance, **cameras))


class SpeedSummary(TypedDict):
    """One speed's figures (a row of the CSV)."""
    speed_deg_s: float
    frames: int
    lost: int
    rms_px: float | None
    p95_px: float | None
    max_px: float | None
    latency_p50_ms: float | None


class PursuitSummary(TypedDict):
    """The pursuit JSON: the figures of every speed, one list per figure."""
    experiment: str
    map: str
    duration_s: float
    modelled_latency_ms: float
    timing: str  # the cameras' frame timing preset
    correct_skew: bool
    skew_ms: float | None  # the right camera's phase after the left's, when set
    speeds_deg_s: list[float]
    rms_px: list[float | None]
    p95_px: list[float | None]
    max_px: list[float | None]
    lost: list[int]
    frame_to_command_p50_ms: list[float | None]
    goals_rms_px: dict[str, float]


@dataclass
class SpeedRun:
    speed_deg_s: float
    errors_px: list[float] = field(default_factory=list)  # true, per frame after settling
    latency_s: list[float] = field(default_factory=list)
    lost: int = 0
    frames: int = 0
    outcomes: list[str] = field(default_factory=list)

    def summary(self) -> SpeedSummary:
        e = np.asarray(self.errors_px)
        lat = np.asarray(self.latency_s) * 1e3
        return {"speed_deg_s": self.speed_deg_s, "frames": self.frames, "lost": self.lost,
                "rms_px": float(np.sqrt(np.mean(e ** 2))) if len(e) else None,
                "p95_px": float(np.percentile(e, 95)) if len(e) else None,
                "max_px": float(e.max()) if len(e) else None,
                "latency_p50_ms": float(np.percentile(lat, 50)) if len(lat) else None}


def run_speed(speed_deg_s: float, gm: GazeMap, *, duration_s: float = 6.0, settle_s: float = 1.0,
              latency_s: float = 0.04, fps: float = 30.0, params: PursuitParams | None = None,
              obj: MovingObject | None = None, seed: int = 0, publish: Publish | None = None,
              base: HeadConfig | None = None, timing: str | None = None,
              skew_s: float | None = None) -> SpeedRun:
    """Pursue the cube sweeping at `speed_deg_s` for `duration_s` (see the module docstring)
    in the simulated world of `base` (None: the packaged configs/sim.yaml); `timing`: both
    cameras' frame timing preset (`ideal`, `free_running`; None: the config's), `skew_s`: the
    right camera's phase after the left's (None: the preset's)."""
    obj = dataclasses.replace(obj or MovingObject(), speed_deg_s=speed_deg_s)
    config = with_timing(dataclasses.replace(sim_config(seed=seed, base=base), sim_objects=(obj,)), timing, skew_s)
    run = SpeedRun(speed_deg_s)
    with SimulatedHeadRig(seed=seed, config=config) as rig:
        world = rig.devices.world
        assert world is not None and world.scene is not None and world.scene.motion is not None
        motion = world.scene.motion
        assert isinstance(motion, SceneMotion)
        fovea = np.array([(rig.model.width - 1) / 2.0, (rig.model.height - 1) / 2.0])

        def truth(at_s: float | None = None) -> np.ndarray:
            """The cube's front-face centre in the left image, from the servos' true positions
            (at `at_s`: the cube then, the servos as they are now)."""
            point = obj.centre(motion.elapsed_s(at_s)) - np.array([obj.size_m / 2.0, 0.0, 0.0])
            joints = world.true_joints()
            (rotation, centre), _ = rig.model.eye_frames_from_joints(
                joints["pan"], joints["tilt"], joints["left_eye"], joints["right_eye"])
            uv, _ = rig.model.lens_left.project((rotation @ (point - centre))[None])
            return np.asarray(uv[0], dtype=float)

        pairs = GridPairs(rig, fps, max(0.0, latency_s - 0.005), truth, seed=seed)
        head = build_head(rig.config, pairs, pairs, rig.clock)
        # Start looking at the cube: its direction and distance give pan, tilt and vergence.
        distance = obj.distance_m
        vergence = math.degrees(2 * math.atan(rig.model.baseline_m / 2 / distance))
        head.move_to(np.array([obj.azimuth_deg, obj.elevation_deg, vergence]))
        head.wait_settled(3.0)
        motion.start_s = rig.clock.monotonic()  # the sweep starts now, from its centre
        tracking = Tracking(head, gm, gm.params.disparity_range, params, frame_period_s=1.0 / fps,
                            publish=publish, poses=lambda: pairs, clock=rig.clock)
        end_s = motion.start_s + duration_s
        while rig.clock.monotonic() < end_s:
            # The track starts on the next pair: the clock just before its exposures.
            exposure_s, before_s = pairs.next_pair_s()
            pairs.advance_to(before_s)
            start = truth(exposure_s)
            if not (0 <= start[0] < rig.model.width and 0 <= start[1] < rig.model.height):
                break
            first = len(pairs.true_positions) + 1  # after the frame the track starts on
            end = tracking.run(0, (float(start[0]), float(start[1])), lambda: rig.clock.monotonic() >= end_s)
            run.outcomes.append(str(end.outcome))
            run.latency_s.extend(end.stats.frame_to_command_s)
            for t, uv in pairs.true_positions[first:]:
                if t - motion.start_s >= settle_s:
                    run.errors_px.append(float(np.hypot(*(uv - fovea))))
            run.frames += len(pairs.true_positions) - first
            if end.outcome is TrackOutcome.LOST or end.outcome is TrackOutcome.NOT_FOUND:
                run.lost += 1
                continue
            break
    return run


@dataclass(frozen=True)
class PursuitSpec:
    """A pursuit experiment: the speeds in turn, each for `duration_s`, with the modelled
    frame-to-command latency; the map from `map_path`, or learned from `fixations` fixations
    of the geometric head model. `profile` names the files."""

    speeds_deg_s: tuple[float, ...] = SPEEDS_DEG_S
    duration_s: float = 6.0
    latency_s: float = 0.04
    map_path: Path | None = None
    fixations: int = 3000
    seed: int = 0
    profile: str = "default"
    config: Path | None = None  # the simulated head whose world it runs in (None: configs/sim.yaml)
    timing: str | None = None  # both cameras' frame timing preset; None: the config's
    skew_s: float | None = None  # the right camera's phase after the left's; None: the preset's
    correct_skew: bool = True  # PursuitParams.correct_skew

    @property
    def stem(self) -> str:
        """The files' name: `pursuit-<profile>[-<timing>][-skew<ms>][-uncorrected]`."""
        return "-".join(["pursuit", self.profile, *([self.timing] if self.timing else []),
                         *([f"skew{self.skew_s * 1e3:g}"] if self.skew_s is not None else []),
                         *([] if self.correct_skew else ["uncorrected"])])


@dataclass(frozen=True)
class PursuitResult:
    spec: PursuitSpec
    map_source: str  # where the map came from, as the summary tells it
    runs: tuple[SpeedRun, ...]

    def summary(self) -> PursuitSummary:
        """The figures per speed, as the JSON gives them."""
        summaries = [r.summary() for r in self.runs]
        return {"experiment": "pursuit", "map": self.map_source, "duration_s": self.spec.duration_s,
                "modelled_latency_ms": self.spec.latency_s * 1e3,
                "timing": self.spec.timing or "the config's", "correct_skew": self.spec.correct_skew,
                "skew_ms": None if self.spec.skew_s is None else self.spec.skew_s * 1e3,
                "speeds_deg_s": [s["speed_deg_s"] for s in summaries],
                "rms_px": [s["rms_px"] for s in summaries], "p95_px": [s["p95_px"] for s in summaries],
                "max_px": [s["max_px"] for s in summaries], "lost": [s["lost"] for s in summaries],
                "frame_to_command_p50_ms": [s["latency_p50_ms"] for s in summaries],
                "goals_rms_px": {str(k): v for k, v in GOALS_RMS_PX.items()}}


def run_pursuit(spec: PursuitSpec) -> PursuitResult:
    """Every speed of `spec` in turn (see the module docstring)."""
    base = load_config(spec.config)
    if spec.map_path is not None:
        gm = read_map(spec.map_path)
        map_source = str(spec.map_path)
    else:
        with SimulatedHeadRig(seed=spec.seed, config=base) as rig:
            gm = learned_map(rig, spec.fixations, spec.seed)
        map_source = f"learned from {spec.fixations} fixations of the geometric head model"
    runs = []
    for speed in spec.speeds_deg_s:
        run = run_speed(speed, gm, duration_s=spec.duration_s, latency_s=spec.latency_s, seed=spec.seed,
                        base=base, params=PursuitParams(correct_skew=spec.correct_skew), timing=spec.timing,
                        skew_s=spec.skew_s)
        log.info("pursuit at %g deg/s: %s", speed, run.summary())
        runs.append(run)
    return PursuitResult(spec, map_source, tuple(runs))


def write_pursuit(result: PursuitResult, out_dir: Path) -> PursuitSummary:
    """Write `pursuit-<profile>.csv`, `.png` and `.json` to `out_dir`; returns the summary."""
    summaries = [r.summary() for r in result.runs]
    out_dir.mkdir(parents=True, exist_ok=True)
    stem = out_dir / result.spec.stem
    with open(stem.with_suffix(".csv"), "w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(["speed_deg_s", "frames", "rms_px", "p95_px", "max_px", "lost", "latency_p50_ms"])
        for s in summaries:
            writer.writerow([s["speed_deg_s"], s["frames"], s["rms_px"], s["p95_px"], s["max_px"], s["lost"],
                             s["latency_p50_ms"]])
    summary = result.summary()
    stem.with_suffix(".json").write_text(json.dumps(summary, indent=2) + "\n")
    plot_pursuit(list(result.runs), stem.with_suffix(".png"))
    return summary


def plot_pursuit(runs: list[SpeedRun], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 4))
    speeds = [r.speed_deg_s for r in runs]
    summaries = [r.summary() for r in runs]
    # A speed without frames after settling has no figures: NaN, a gap in the line.
    ax.plot(speeds, np.array([s["rms_px"] for s in summaries], dtype=float), "o-", label="RMS")
    ax.plot(speeds, np.array([s["p95_px"] for s in summaries], dtype=float), "s--", label="p95")
    for speed, goal in GOALS_RMS_PX.items():
        ax.plot([speed], [goal], "rv", label="goal (RMS)" if speed == min(GOALS_RMS_PX) else None)
    ax.set_xlabel("target angular speed, deg/s")
    ax.set_ylabel("retinal error of the target, px")
    ax.set_title("smooth pursuit on the simulated head")
    ax.grid(True, alpha=0.3)
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def format_result(result: PursuitSummary) -> str:
    lines = [f"pursuit ({result['map']}; {result['duration_s']:g} s a speed, "
             f"{result['modelled_latency_ms']:.0f} ms frame-to-command modelled; frame timing {result['timing']}"
             + ("" if result["skew_ms"] is None else f", right camera {result['skew_ms']:g} ms after the left")
             + f", skew {'corrected' if result['correct_skew'] else 'not corrected'})",
             "  speed deg/s   RMS px   p95 px   max px   lost   latency p50 ms   goal"]
    for i, speed in enumerate(result["speeds_deg_s"]):
        goal = GOALS_RMS_PX.get(speed)
        lines.append(f"  {speed:10.0f} {result['rms_px'][i]:8.2f} {result['p95_px'][i]:8.2f} {result['max_px'][i]:8.2f} "
                     f"{result['lost'][i]:6d} {result['frame_to_command_p50_ms'][i]:16.0f}   "
                     + (f"RMS <= {goal:g}" if goal else ""))
    return "\n".join(lines)
