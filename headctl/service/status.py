"""The service's state in one typed snapshot, and the faults present now.

`status_snapshot(parts)` reads the parts' latest-value slots and counters (never a lock the
servo loop or an adaptation holds) into a `StatusSnapshot`: what `headctl status`, the API's
`GET /api/v1/state` (`StatusSnapshot.as_dict()`), the dashboard and `/metrics` show.
`fault_items(parts)` is the list of what is wrong now, each under a key that stays the same
while the fault lasts; `FaultWatcher` publishes `fault` and `fault_cleared` events as they
come and go.
"""
from __future__ import annotations

import dataclasses
import os
import threading
from typing import Callable, Sequence, TypedDict

import numpy as np

from calib_free.gaze.fixation import FixationRecord
from drivers.cameras.camera import StreamHealth
from drivers.cameras.stereo import SkewStats
from headctl.config.world import simulated_world
from headctl.json_types import JSONObject
from headctl.service.events import EventHub, LogEntry, plain
from headctl.service.parts import ServiceParts, ServicePhase
from headctl.service.tracking import TrackFigures

STALLED_FRAME_S = 1.0  # a streaming camera without a frame for this long is reported stalled
STALLED_LOOP_S = 1.0  # a live servo loop without a cycle for this long is reported stalled
FAILING_READS_S = 0.5  # servo reads failing for this long are reported


class LastFixation(TypedDict):
    """The last fixation as the status shows it (`last_fixation`)."""

    index: int
    kind: str
    outcome: str
    detail: str
    duration_s: float
    converged: bool
    confidence: float | None  # these four: None without a match
    position: np.ndarray | None
    left: list[float] | None
    right: list[float] | None


class VergenceLatency(TypedDict):
    count: int
    p50: float | None  # ms
    p99: float | None


class RestoredMap(TypedDict):
    adaptations: int
    recent_retinal_errors: list[float]


@dataclasses.dataclass(frozen=True)
class JointStatus:
    position_deg: float
    velocity_dps: float
    moving: bool
    torque_on: bool
    goal_deg: float | None
    hardware_errors: tuple[str, ...]
    temperature_c: float
    input_voltage_v: float


@dataclasses.dataclass(frozen=True)
class CameraStatus:
    name: str
    health: str
    stats: dict[str, int]
    restarts: int
    frame_age_s: float | None
    last_error: str | None


@dataclasses.dataclass(frozen=True)
class FixationStatus:
    state: str  # the head's phase: "saccade", "fine vergence", "idle", "paused (...)", ...
    explore: bool
    done: int
    taught: int
    refused: dict[str, int]
    looks_queued: int
    last: LastFixation | None
    vergence_latency_ms: VergenceLatency
    landing_error_px_median: float | None  # over the last target looks measured
    tracking: TrackFigures | None = None  # the running track's figures (GET /api/v1/track has them too)


@dataclasses.dataclass(frozen=True)
class LearningStatus:
    adaptations: int
    mean_retinal_error: float | None
    recent_retinal_errors: list[float]
    output_error_deg: list[float] | None
    adaptations_this_run: int
    queue_dropped: int
    # Means over the last 100 adaptations (the metrics' gauges).
    recent_mean_retinal_error: float | None
    recent_mean_confidence: float | None
    recent_mean_output_error_deg: list[float] | None


@dataclasses.dataclass(frozen=True)
class MapStatus:
    path: str
    restored_from: str
    restored: RestoredMap
    problems: list[str]
    checkpoints: int
    last_checkpoint_adaptations: int | None
    last_checkpoint_ms: float | None


@dataclasses.dataclass(frozen=True)
class StatusSnapshot:
    state: ServicePhase
    pid: int
    config: str
    uptime_s: float
    faults: dict[str, str]  # key -> message, what is wrong now
    api: str | None
    events_seq: int
    image_size: tuple[int, int]
    joints: dict[str, JointStatus]
    pose: dict[str, float] | None
    torque: bool | None
    servo_loop: JSONObject | None  # counters and period/jitter quantiles (`ServoLoop.timing`)
    bus_down: bool
    fixation: FixationStatus
    learning: LearningStatus | None
    map: MapStatus
    cameras: dict[str, CameraStatus]
    hardware_errors: JSONObject  # the servos' error episodes: open now, the last ended, reboots
    warnings: list[LogEntry]  # the last warnings and errors logged
    warning_counts: dict[str, int]
    event_counts: dict[str, int]  # events published, by type
    restarts: dict[str, int] = dataclasses.field(default_factory=dict)  # by part, done by the supervisor
    stereo: SkewStats | None = None  # the recent stereo pairs' skew (right - left timestamp), unpaired frames
    world: JSONObject | None = None  # a simulated head's world (headctl.config.world); None: a real head

    def as_dict(self) -> JSONObject:
        """The JSON of `GET /api/v1/state` (valid JSON whatever the values: NaN becomes null)."""
        out: JSONObject = plain(digits=None, value={
            "state": str(self.state), "pid": self.pid, "config": self.config, "uptime_s": self.uptime_s,
            "faults": list(self.faults.values()), "api": self.api, "events_seq": self.events_seq,
            "image_size": list(self.image_size),
            "joints": {j: dataclasses.asdict(s) for j, s in self.joints.items()},
            "pose": self.pose, "torque": self.torque, "servo_loop": self.servo_loop,
            "fixation": dataclasses.asdict(self.fixation),
            "learning": dataclasses.asdict(self.learning) if self.learning is not None else {},
            "map": dataclasses.asdict(self.map),
            "cameras": {side: dataclasses.asdict(c) for side, c in self.cameras.items()},
            "hardware_errors": self.hardware_errors,
            "events": self.warnings, "event_counts": self.warning_counts, "restarts": self.restarts,
            "world": self.world,
            "stereo": dataclasses.asdict(self.stereo) if self.stereo is not None else None})
        return out


def _percentiles(values: list[float], qs: tuple[float, ...]) -> list[float | None]:
    arr = np.asarray(values, dtype=float)
    return [float(np.percentile(arr, q)) if len(arr) else None for q in qs]


def _mean(values: Sequence[float | None]) -> float | None:
    finite = [float(v) for v in values if v is not None and np.isfinite(v)]
    return float(np.mean(finite)) if finite else None


def last_fixation(record: FixationRecord) -> LastFixation:
    match = record.match
    return {"index": record.index, "kind": str(record.kind), "outcome": str(record.outcome),
            "detail": record.detail, "duration_s": record.duration_s, "converged": record.converged,
            "confidence": None if match is None else record.confidence,
            "position": None if match is None else record.position,
            "left": None if match is None else [match.left.x, match.left.y],
            "right": None if match is None else [match.right.x, match.right.y]}


def fault_items(parts: ServiceParts) -> dict[str, str]:
    """What is wrong now, by a key that stays the same while the fault lasts."""
    out: dict[str, str] = {}
    running = parts.running
    now = parts.clock.monotonic()
    if running is not None:
        loop = running.loop
        if loop.down_reason is not None:
            out["servo_bus"] = f"servo bus down: {loop.down_reason}"
        for joint, meanings in loop.faults.items():
            out[f"servo:{joint}"] = f"{loop.describe(joint)}: hardware error: {', '.join(meanings)} (joint held)"
        for joint, description in loop.missing.items():
            out[f"servo_missing:{joint}"] = f"servo missing: {description} (the other joints go on)"
        if loop.down_reason is None and now - loop.last_read_s > FAILING_READS_S:
            out["servo_reads"] = f"servo reads failing for {now - loop.last_read_s:.1f} s: {loop.last_read_error}"
        if loop.error is not None:
            out["servo_loop"] = f"servo loop failed: {loop.error!r}"
        if loop.is_alive() and now - loop.last_cycle_s > STALLED_LOOP_S:
            out["servo_loop_stall"] = f"servo loop stalled for {now - loop.last_cycle_s:.1f} s"
        if running.fixation.error is not None:
            out["fixation"] = f"fixation controller failed: {running.fixation.error!r}"
        if running.adapter.error is not None:
            out["adapter"] = f"adapter: {running.adapter.error!r}"
        if running.checkpointer.error:
            out["checkpoint"] = running.checkpointer.error
    out.update(parts.reported_faults)
    devices = parts.devices
    for side, camera in (devices.cameras.items() if devices is not None else ()):
        latest = camera.latest()
        if camera.health is not StreamHealth.STREAMING:
            out[f"camera:{side}"] = f"camera {side}: {camera.health.value} ({camera.last_error})"
        elif parts.phase is ServicePhase.RUNNING and (latest is None or now - latest.time_s > STALLED_FRAME_S):
            age = "no frame yet" if latest is None else f"no frame for {now - latest.time_s:.1f} s"
            out[f"camera:{side}"] = f"camera {side}: stalled, {age} ({camera.last_error})"
    return out


def service_state(parts: ServiceParts, faults: dict[str, str]) -> ServicePhase:
    if parts.phase is ServicePhase.RUNNING and faults:
        return ServicePhase.DEGRADED
    return parts.phase


def status_snapshot(parts: ServiceParts, api_faults: dict[str, str] | None = None) -> StatusSnapshot:
    """The service's state now; `api_faults`: what the API server reports wrong with itself."""
    config = parts.config
    running = parts.running
    now = parts.clock.monotonic()
    world = simulated_world(config)
    faults = {**fault_items(parts), **(api_faults or {})}
    joints: dict[str, JointStatus] = {}
    pose = None
    torque = None
    servo_loop = None
    bus_down = False
    if running is not None:
        loop = running.loop
        state = loop.latest_state()
        goals = loop.goals()
        if state is not None:
            for joint, js in state.joints.items():
                joints[joint] = JointStatus(round(js.position, 4), round(js.velocity, 3), js.moving, js.torque_on,
                                            goals.get(joint), tuple(js.hardware_errors), js.temperature_c,
                                            js.input_voltage_v)
            if not state.missing:  # a pose needs every joint
                pose = dict(zip(("pan", "tilt", "vergence"),
                                running.head.pose_from(state.positions).round(4).tolist()))
        torque = loop.torque_enabled
        servo_loop = loop.timing()
        bus_down = loop.down_reason is not None
    fixation = _fixation_status(parts)
    learning = _learning_status(parts)
    checkpointer = running.checkpointer if running is not None else None
    origin = parts.map_origin
    map_status = MapStatus(
        str(config.map_path), origin.source,
        {"adaptations": origin.adaptations, "recent_retinal_errors": list(origin.recent_retinal_errors)},
        list(origin.problems), checkpointer.count if checkpointer else 0,
        checkpointer.last_adaptations if checkpointer else None,
        None if not checkpointer or checkpointer.last_duration_s is None
        else round(checkpointer.last_duration_s * 1e3, 1))
    cameras: dict[str, CameraStatus] = {}
    for side, camera in (parts.devices.cameras.items() if parts.devices is not None else ()):
        latest = camera.latest()
        cameras[side] = CameraStatus(camera.name, camera.health.value, camera.stats(), parts.camera_restarts[side],
                                     None if latest is None else round(now - latest.time_s, 3),
                                     None if camera.last_error is None else str(camera.last_error))
    return StatusSnapshot(
        state=service_state(parts, faults), pid=os.getpid(), config=str(config.path),
        uptime_s=round(now - parts.started_s, 3), faults=faults, api=parts.api_url, events_seq=parts.hub.seq,
        image_size=config.image_size, joints=joints, pose=pose, torque=torque, servo_loop=servo_loop,
        bus_down=bus_down, fixation=fixation, learning=learning, map=map_status, cameras=cameras,
        hardware_errors=parts.hardware.status() if parts.hardware is not None else {"open": [], "ended": [],
                                                                                    "reboots": []},
        warnings=list(parts.warnings.events), warning_counts=dict(parts.warnings.counts),
        event_counts=dict(parts.hub.counts), restarts=dict(parts.restarts),
        stereo=running.pair.skew_stats() if running is not None else None,
        world=None if world is None else world.as_dict())


def _fixation_status(parts: ServiceParts) -> FixationStatus:
    running = parts.running
    if running is None:
        return FixationStatus(str(parts.phase), parts.config.fixation.explore, 0, 0, {}, parts.looks.pending(), None,
                              {"count": 0, "p50": None, "p99": None}, None)
    fix = running.fixation
    counts = fix.counts()
    last = fix.last
    latency = list(running.head_events.vergence_latency_s)
    l50, l99 = _percentiles(latency, (50, 99))
    landing = list(fix.landing_errors_px)
    return FixationStatus(
        running.head.phase, fix.explore, counts["done"], counts["taught"], counts["refused"], parts.looks.pending(),
        None if last is None else last_fixation(last),
        {"count": len(latency), "p50": None if l50 is None else round(l50 * 1e3, 3),
         "p99": None if l99 is None else round(l99 * 1e3, 3)},
        float(np.median(landing)) if landing else None, fix.tracking_status())


def _learning_status(parts: ServiceParts) -> LearningStatus | None:
    running = parts.running
    if running is None:
        return None
    adapter = running.adapter
    # The published progress, not the map under its lock: a status reader (the API's event
    # loop) must never wait for an adaptation.
    progress = adapter.progress
    recent = list(progress.recent_retinal_errors)
    outs = list(parts.learning.recent_output_errors)
    points = parts.learning.recent(100)
    output_errors = [p["output_error_deg"] for p in points if p["output_error_deg"] is not None]
    mean_output = None
    if output_errors:
        with np.errstate(all="ignore"):
            mean_output = [float(v) for v in np.nanmean(np.asarray(output_errors, dtype=float), axis=0)]
    return LearningStatus(
        adaptations=progress.adaptations, mean_retinal_error=_mean(recent), recent_retinal_errors=recent,
        output_error_deg=np.mean(outs, axis=0).round(4).tolist() if outs else None,
        adaptations_this_run=parts.learning.adaptations_run, queue_dropped=adapter.dropped,
        recent_mean_retinal_error=_mean([p["retinal_error"] for p in points]),
        recent_mean_confidence=_mean([p["confidence"] for p in points]),
        recent_mean_output_error_deg=mean_output)


class FaultWatcher:
    """A `fault` event when a fault appears, `fault_cleared` when it is gone: polled by the
    supervisor, and called by the servo loop the moment its bus or a joint changes (a bus down
    for less than a poll is still reported)."""

    def __init__(self, parts: ServiceParts, hub: EventHub,
                 more_faults: Callable[[], dict[str, str]] | None = None) -> None:
        self.parts = parts
        self.hub = hub
        self.more_faults = more_faults  # what others report wrong (the API server)
        self._seen: set[str] = set()
        self._lock = threading.Lock()

    def check(self) -> dict[str, str]:
        running, hardware = self.parts.running, self.parts.hardware
        if running is not None and hardware is not None:  # every hardware error, rebooted or not
            hardware.add(running.loop.fault_records(hardware.cursor))
        with self._lock:
            items = {**fault_items(self.parts), **(self.more_faults() if self.more_faults is not None else {})}
            for key in items.keys() - self._seen:
                self.hub.publish("fault", key=key, message=items[key])
            for key in self._seen - items.keys():
                self.hub.publish("fault_cleared", key=key)
            self._seen = set(items)
            return items
