"""The parts of a running service, as the daemon assembled them, and its lifecycle phase.

`ServiceParts` is what the status reporter, the control facade and the supervisor read; the
daemon fills it while it starts (`running` is None until every thread runs) and empties it
as it stops. Each collaborator reads the parts; none reaches into another's attributes.
"""
from __future__ import annotations

import collections
import dataclasses
import enum
import threading
from typing import TypedDict

import numpy as np

from calib_free.map.adapter import MapAdapter, Sample
from calib_free.map.gaze_map import AdaptResult
from drivers.clock import Clock
from drivers.cameras.stereo import StereoPair
from headctl.config.head import HeadConfig
from headctl.json_types import JSONObject
from headctl.service.build import HeadDevices
from headctl.service.events import EventHub, EventLog, plain
from headctl.service.fixation_thread import FixationThread, HeadEvents
from headctl.service.fixation_trace import FixationTaps
from headctl.service.servo_io.hardware_faults import HardwareFaults
from headctl.service.looks import LookQueue
from headctl.service.persistence import Checkpointer, MagnificationFile
from headctl.service.servo_io.loop import ServoIO
from headctl.service.head import Head


class ServicePhase(enum.StrEnum):
    STARTING = "starting"
    RUNNING = "running"
    DEGRADED = "degraded"  # running, with a fault present (never stored: derived from the faults)
    STOPPING = "stopping"
    STOPPED = "stopped"


@dataclasses.dataclass
class MapOrigin:
    """Where the map being learned came from when the service started."""

    source: str = ""  # a file, or "new"
    problems: list[str] = dataclasses.field(default_factory=list)
    adaptations: int = 0
    recent_retinal_errors: list[float] = dataclasses.field(default_factory=list)


class LearningPoint(TypedDict):
    """One accepted adaptation on the learning curve, JSON-ready (`plain`: NaN as None)."""
    n: int  # the point's index in the log
    fixation: int  # the index of the fixation that taught it (`FixationRecord.index`)
    adaptations: int
    t: float  # wall time, s
    retinal_error: float | None
    output_error_deg: list[float | None] | None
    confidence: float | None


class LearningLog:
    """The learning curves, one point an adaptation (`on_adapted` runs on the adapter thread)."""

    def __init__(self, clock: Clock, size: int = 5000) -> None:
        self.clock = clock
        self.points: collections.deque[LearningPoint] = collections.deque(maxlen=size)
        self.adaptations_run = 0
        self.recent_output_errors: collections.deque[np.ndarray] = collections.deque(maxlen=10)
        self._lock = threading.Lock()
        self._seq = 0  # the points' index: grows through a map reset or load

    def add(self, adaptations: int, sample: Sample, result: AdaptResult, wall_time_s: float) -> None:
        if not result.accepted:
            return
        with self._lock:
            self.adaptations_run += 1
            self.recent_output_errors.append(np.asarray(result.output_error, dtype=float))
            self._seq += 1
            self.points.append(plain({
                "n": self._seq, "fixation": sample.tag, "adaptations": adaptations, "t": wall_time_s,
                "retinal_error": result.retinal_error,
                "output_error_deg": result.output_error, "confidence": sample.confidence}))

    def since(self, since: int = 0, limit: int = 5000) -> JSONObject:
        """The points after point `since` (at most `limit`, the newest) and the `since` to ask
        with next time."""
        with self._lock:
            points = [p for p in self.points if p["n"] > since]
            newest = self._seq
        return {"next": newest, "points": points[-limit:] if limit > 0 else []}

    def recent(self, count: int) -> list[LearningPoint]:
        with self._lock:
            return list(self.points)[-count:]


@dataclasses.dataclass
class RunningParts:
    """The threads and devices of a running service."""

    devices: HeadDevices
    pair: StereoPair
    loop: ServoIO
    adapter: MapAdapter
    checkpointer: Checkpointer
    head: Head
    head_events: HeadEvents
    fixation: FixationThread
    magnification_file: MagnificationFile  # the looks' lens magnification, saved when it changed


@dataclasses.dataclass
class ServiceParts:
    """Everything the service's collaborators read; `running` once every thread runs."""

    config: HeadConfig
    clock: Clock
    hub: EventHub
    warnings: EventLog
    looks: LookQueue
    learning: LearningLog
    started_s: float
    phase: ServicePhase = ServicePhase.STARTING
    running: RunningParts | None = None
    devices: HeadDevices | None = None  # as soon as they are open (the status shows them while starting)
    map_origin: MapOrigin = dataclasses.field(default_factory=MapOrigin)
    api_url: str | None = None
    camera_restarts: collections.Counter[str] = dataclasses.field(default_factory=collections.Counter)
    restarts: collections.Counter[str] = dataclasses.field(default_factory=collections.Counter)  # by part (supervisor)
    hardware: HardwareFaults | None = None  # the servos' hardware-error episodes, told as events
    fixation_taps: FixationTaps = dataclasses.field(default_factory=FixationTaps)  # who records the fixations
    # Faults the front ends report of their own work (a recording that failed): key -> message.
    reported_faults: dict[str, str] = dataclasses.field(default_factory=dict)
