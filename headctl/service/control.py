"""What clients may ask of a running service, and the interface the API and metrics use.

`HeadService` is the small typed interface the HTTP layer (`headctl.api.app`) and the metrics
(`headctl.api.metrics`) depend on: one status snapshot, the event hub, the looks, the switches,
the map actions and fault injection on the simulated head. `ServiceControl` implements it
over the service's parts. Every refusal is a `headctl.errors.ControlError` naming the field
at fault; what HTTP answer each kind becomes is the API's business.
"""
from __future__ import annotations

import dataclasses
import enum
import errno
import logging
import os
import re
import threading
from pathlib import Path
from typing import Callable, NotRequired, Protocol, TypedDict

import numpy as np

from calib_free.map.gaze_map import GazeMap
from calib_free.correspondence.disparity import DISPARITY_BAND_PX
from calib_free.correspondence.disparity import disparity_at as measured_disparity_at
from calib_free.correspondence.search import CorrespondenceParams
from calib_free.errors import DisparityError, MapFileError, OutOfRangeError, TargetPatchError
from calib_free.map.file import read_map, write_map
from calib_free.gaze.fixation import FixationRecord, LookParams
from calib_free.gaze.look_geometry import REACH_MARGIN_DEG, beyond_limits
from calib_free.gaze.target_depth import TargetDisparity
from calib_free.gaze.target_depth import target_disparity as look_disparity
from drivers.servo.bus import BusState
from drivers.servo.joints import JOINTS
from drivers.cameras.camera import Frame
from drivers.errors import DriverError
from drivers.sim.camera import SimulatedCamera
from headctl.errors import ControlError, InvalidRequestError, NotFoundError, UnavailableError
from headctl.json_types import JSONObject
from headctl.service.events import EventHub
from headctl.service.fixation_trace import TraceSubscriber
from headctl.service.looks import LookAnswer, LookJob, LookKind, LookRequest, LookState
from headctl.service.parts import RunningParts, ServiceParts, ServicePhase
from headctl.service.status import StatusSnapshot, status_snapshot
from headctl.service.tracking import TrackFigures

log = logging.getLogger(__name__)

PAIR_MAX_AGE_S = 0.5  # a target's disparity is measured only in a pair this recent
MAP_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9._-]{0,100}\.npz")


def disparity_at(left: np.ndarray, right: np.ndarray, x: float, y: float, patch_size: tuple[int, int],
                 disparity_range: tuple[float, float], band_px: int = DISPARITY_BAND_PX,
                 row_offset_px: float = 0.0) -> tuple[float, float]:
    """`calib_free.correspondence.disparity.disparity_at`; InvalidRequestError (naming `d`) where
    it cannot be measured."""
    try:
        return measured_disparity_at(left, right, x, y, patch_size, disparity_range, band_px, row_offset_px)
    except DisparityError as err:
        raise InvalidRequestError(f"d: {err}; send d", "d") from None


def target_disparity(left: np.ndarray, right: np.ndarray, x: float, y: float, patch_size: tuple[int, int],
                     disparity_range: tuple[float, float], look: LookParams,
                     band_px: int = DISPARITY_BAND_PX, row_offset_px: float = 0.0,
                     rival_margin: float = CorrespondenceParams.stereo_rival_margin) -> TargetDisparity:
    """`calib_free.gaze.target_depth.target_disparity`; InvalidRequestError (naming `d`) when the target
    cannot be looked at."""
    try:
        return look_disparity(left, right, x, y, patch_size, disparity_range, look, band_px, row_offset_px,
                              rival_margin)
    except TargetPatchError as err:
        raise InvalidRequestError(f"d: {err}", "d") from None


class SimFault(enum.StrEnum):
    """Faults the simulated head can be given (tests, demonstrations)."""

    BUS_DOWN = "bus_down"
    RESTORE_BUS = "restore_bus"
    HARDWARE_ERROR = "hardware_error"
    CAMERA_STALL = "camera_stall"
    CAMERA_RESUME = "camera_resume"
    CAMERA_UNPLUG = "camera_unplug"  # the device node vanishes: reads and reopens fail
    CAMERA_REPLUG = "camera_replug"  # it is back: the camera reopens with its config
    # A brown-out: every servo loses power (silent, torque off) until power_back, when they
    # boot with RAM defaults and Hardware Error Status `bits` (1: input voltage).
    POWER_LOSS = "power_loss"
    POWER_BACK = "power_back"
    SERVO_REMOVE = "servo_remove"  # `joint`'s servo leaves the bus (silent) until servo_add
    SERVO_ADD = "servo_add"  # it is back, just powered up (torque off)
    # The state directory's disk full (every checkpoint fails with ENOSPC) until writable again.
    STATE_DIR_FULL = "state_dir_full"
    STATE_DIR_WRITABLE = "state_dir_writable"


class FullDisk:
    """A checkpoint writer on a full disk (`SimFault.STATE_DIR_FULL`): every save fails with
    ENOSPC before a byte is written; `writer` is the one it stands in for."""

    def __init__(self, writer: Callable[[GazeMap, Path], None]) -> None:
        self.writer = writer

    def __call__(self, gm: GazeMap, path: Path) -> None:
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(path))


class MapAnswer(TypedDict):
    """What a map action did: the file saved, loaded or started again in, and its adaptations."""

    path: str
    adaptations: int
    backup: NotRequired[str]  # a reset's: where the map before it was saved


class HeadService(Protocol):
    """What the API and the metrics may ask of the service."""

    @property
    def events(self) -> EventHub: ...

    def snapshot(self) -> StatusSnapshot: ...

    def learning_since(self, since: int = 0, limit: int = 5000) -> JSONObject: ...

    def look(self, request: LookRequest, replace: bool = False) -> LookJob: ...

    def get_look(self, look_id: int) -> LookJob: ...

    def cancel_look(self, look_id: int) -> LookJob: ...

    def set_exploration(self, enabled: bool) -> bool: ...

    def set_torque(self, enabled: bool) -> bool: ...

    def save_map(self, name: str | None = None) -> MapAnswer: ...

    def load_map(self, name: str | None = None) -> MapAnswer: ...

    def reset_map(self, seed: int | None = None) -> MapAnswer: ...

    def inject_fault(self, fault: SimFault, joint: str | None = None, camera: str | None = None,
                     bits: int = 0) -> str: ...

    def latest_frame(self, side: str) -> Frame | None: ...

    def joint_state(self) -> BusState | None: ...

    def last_fixation(self) -> FixationRecord | None: ...

    def track(self, x: float | None, y: float | None) -> LookJob: ...

    def stop_track(self) -> LookJob: ...

    def get_track(self) -> LookAnswer: ...

    def tracking_now(self) -> TrackFigures | None: ...

    def subscribe_fixations(self, deliver: TraceSubscriber) -> Callable[[], None]: ...

    def report_fault(self, key: str, message: str | None) -> None: ...


class ServiceControl:
    """`HeadService` over the parts of a service (thread-safe; ControlError names the field at fault)."""

    def __init__(self, parts: ServiceParts, more_faults: Callable[[], dict[str, str]] | None = None) -> None:
        self.parts = parts
        self.more_faults = more_faults
        self._track: LookJob | None = None  # the last track queued
        self._track_lock = threading.Lock()

    @property
    def events(self) -> EventHub:
        return self.parts.hub

    def snapshot(self) -> StatusSnapshot:
        return status_snapshot(self.parts, self.more_faults() if self.more_faults is not None else None)

    def learning_since(self, since: int = 0, limit: int = 5000) -> JSONObject:
        return self.parts.learning.since(since, limit)

    def subscribe_fixations(self, deliver: TraceSubscriber) -> Callable[[], None]:
        """Call `deliver` with every fixation's trace (`headctl.service.fixation_trace`) from now
        on, on the fixation thread (it must not block); returns the unsubscribe function."""
        return self.parts.fixation_taps.subscribe(deliver)

    def report_fault(self, key: str, message: str | None) -> None:
        """A front end's fault in its own work (`key` "recording": a bag whose write failed),
        in the status's faults until reported again with `message` None."""
        faults = dict(self.parts.reported_faults)  # replaced, never changed in place: readers take no lock
        if message is None:
            faults.pop(key, None)
        else:
            faults[key] = message
        self.parts.reported_faults = faults

    def latest_frame(self, side: str) -> Frame | None:
        devices = self.parts.devices
        camera = devices.cameras.get(side) if devices is not None else None
        return camera.latest() if camera is not None else None

    def joint_state(self) -> BusState | None:
        """The servo loop's latest state (all joints, stamped at the read), without waiting; None
        before the first read or while the service does not run."""
        running = self.parts.running
        return running.loop.latest_state() if running is not None else None

    def last_fixation(self) -> FixationRecord | None:
        running = self.parts.running
        return running.fixation.last if running is not None else None

    def _running(self) -> RunningParts:
        running = self.parts.running
        if self.parts.phase is not ServicePhase.RUNNING or running is None:
            raise UnavailableError(f"the service is {self.parts.phase}, not running")
        return running

    def _pose_now(self, running: RunningParts) -> np.ndarray:
        """The pose of the servo loop's latest state, without waiting for a fresh one."""
        state = running.loop.latest_state()
        if state is None:
            raise UnavailableError("no servo state read yet")
        if state.missing:
            raise UnavailableError(f"no pose: servo missing: {'; '.join(state.missing.values())}")
        return running.head.pose_from(state.positions)

    # -- looks ------------------------------------------------------------------------------
    def look(self, request: LookRequest, replace: bool = False) -> LookJob:
        """Queue a look after checking it against the image, the map and the joint limits."""
        running = self._running()
        head = running.head
        if request.kind is LookKind.TARGET:
            width, height = self.parts.config.image_size
            d_low, d_high = running.adapter.map.params.disparity_range
            x, y, d = request.values
            checks = [("x", x, 0, width - 1, "the image's columns"), ("y", y, 0, height - 1, "the image's rows")]
            for name, value, low, high, what in checks:
                if not low <= value <= high:
                    raise InvalidRequestError(f"{name} = {value:g} is outside {what}, [{low:g}, {high:g}]", name)
            if d is None:  # sent without a disparity: measured where the client pointed, else the fixation's
                found = self.measure_disparity(x, y)
                d = found.d
                request = dataclasses.replace(request, values=(x, y, d), d_ncc=found.ncc, d_reason=found.reason)
            if not d_low <= d <= d_high:
                raise InvalidRequestError(f"d = {d:g} is outside the map's disparity range "
                                          f"(gaze_map.disparity_range), [{d_low:g}, {d_high:g}]", "d")
            # The target is in the view of the pose now; the head may move before the look runs.
            pose = self._pose_now(running)
            request = dataclasses.replace(request, reference_pose=tuple(pose.tolist()))
            self._check_reach(running, (x, y, d), pose)
        else:
            goal = request.angles_goal(self._pose_now(running) if request.relative else np.zeros(3),
                                       head.pose_low, head.pose_high)
            for i, name in enumerate(("pan", "tilt", "vergence")):
                low, high = head.pose_low[i], head.pose_high[i]
                if not low - 1e-9 <= goal[i] <= high + 1e-9:
                    where = (f"{goal[i] - request.values[i]:.2f} + {request.values[i]:g} = {goal[i]:.2f}"
                             if request.relative else f"{goal[i]:g}")
                    raise InvalidRequestError(f"{name}: {where} deg is outside the limits [{low:g}, {high:g}] deg "
                                              "(servo_bus.joints, fixation.vergence_range)", name)
        job = self.parts.looks.submit(request, replace=replace)
        log.info("look %d queued: %s", job.id, request.as_dict())
        return job

    @staticmethod
    def _check_reach(running: RunningParts, target: tuple[float, float, float], pose: np.ndarray) -> None:
        """Refuse, before the head moves, a target whose saccade the map sends clearly beyond the
        pan or tilt limits (`REACH_MARGIN_DEG`): no look can end on it. The pose that fixates a
        point is the same whatever pose the head starts from (its eyes verge symmetrically), so
        turning the head first does not bring it within reach; turning the robot does."""
        head = running.head
        try:
            goal = pose + running.adapter.command(target, pose=pose)
        except OutOfRangeError:
            return  # outside the map: the look says so
        beyond = beyond_limits(goal, head.pose_low, head.pose_high, REACH_MARGIN_DEG)
        if beyond:
            x, y, _ = target
            raise InvalidRequestError(
                f"x, y: the target at ({x:g}, {y:g}) is beyond the joint limits: the map's saccade to it ends at "
                f"{beyond} (servo_bus.joints); the pose that fixates it is the same from any other, so no look "
                "can end on it: turn the robot the head is on towards it", "x")

    def get_look(self, look_id: int) -> LookJob:
        return self.parts.looks.get(look_id)

    def cancel_look(self, look_id: int) -> LookJob:
        return self.parts.looks.cancel(look_id)

    def measure_disparity(self, x: float, y: float) -> TargetDisparity:
        """The disparity (px, x_right - x_left) to look at (x, y) of the left image with, from the
        latest stereo pair (`target_disparity`): where the patch around it lies in the right
        image within the map's disparity range, about the rows fine vergence last found the
        pair's misalignment at (what fine vergence measures at the fovea, measured off-centre),
        else 0 when the look can find the target by its patch.
        UnavailableError (naming `d`) without a recent pair; InvalidRequestError (naming `d`)
        when the target cannot be looked at."""
        running = self._running()
        pair = running.pair.latest()
        now = self.parts.clock.monotonic()
        age_s = None if pair is None else now - min(pair.left.time_s, pair.right.time_s)
        if pair is None or age_s is None or age_s > PAIR_MAX_AGE_S:
            raise UnavailableError(f"d: no stereo pair from the last {PAIR_MAX_AGE_S:g} s to measure the "
                                   f"disparity at ({x:g}, {y:g}) in; send d", "d")
        controller = running.fixation.controller
        params = controller.params
        return target_disparity(pair.left.image, pair.right.image, x, y, params.vergence_patch_size,
                                running.adapter.map.params.disparity_range, params.look,
                                row_offset_px=controller.row_offset_px,
                                rival_margin=params.correspondence.stereo_rival_margin)

    # -- tracks -------------------------------------------------------------------------------
    def track(self, x: float | None, y: float | None) -> LookJob:
        """Queue a track of the patch at (x, y) of the left image (None, None: the fovea); it
        preempts the look or track running (the fixation thread ends it)."""
        self._running()  # UnavailableError unless the service runs
        width, height = self.parts.config.image_size
        if (x is None) != (y is None):
            raise InvalidRequestError("send both x and y, or neither (the fovea)", "x" if x is None else "y")
        if x is None or y is None:
            x, y = (width - 1) / 2.0, (height - 1) / 2.0
        for name, value, high, what in (("x", x, width - 1, "the image's columns"), ("y", y, height - 1, "the image's rows")):
            if not 0 <= value <= high:
                raise InvalidRequestError(f"{name} = {value:g} is outside {what}, [0, {high:g}]", name)
        job = self.parts.looks.submit(LookRequest(LookKind.TRACK, (float(x), float(y), 0.0)))
        with self._track_lock:
            self._track = job
        log.info("track %d queued at (%.1f, %.1f)", job.id, x, y)
        return job

    def stop_track(self) -> LookJob:
        """Stop the track queued or running (ControlError when there is none)."""
        with self._track_lock:
            job = self._track
        if job is None or job.state.finished:
            raise ControlError("no track is queued or running", "id")
        if job.state is LookState.RUNNING:
            job.request_cancel("stopped", "stopped by a client")
            return job
        return self.parts.looks.cancel(job.id)

    def get_track(self) -> LookAnswer:
        """The last track queued (its job), with the running one's figures so far."""
        with self._track_lock:
            job = self._track
        if job is None:
            raise NotFoundError("no track has been queued since the service started", "id")
        out = job.as_dict()
        live = self.tracking_now()
        if live is not None and job.state is LookState.RUNNING:
            out["result"] = {"stats": live}
        return out

    def tracking_now(self) -> TrackFigures | None:
        """The running track's figures (position of the patch, errors, latency), or None."""
        running = self.parts.running
        return running.fixation.tracking_status() if running is not None else None

    # -- switches -----------------------------------------------------------------------------
    def set_exploration(self, enabled: bool) -> bool:
        fix = self._running().fixation
        if fix.explore != enabled:
            fix.explore = enabled
            log.info("exploration %s (requested)", "on" if enabled else "off")
            self.parts.hub.publish("exploration", enabled=enabled)
        return fix.explore

    def set_torque(self, enabled: bool) -> bool:
        loop = self._running().loop
        if loop.down_reason is not None:
            raise UnavailableError(f"servo bus down ({loop.down_reason}): torque cannot be switched now")
        try:
            loop.set_torque(enabled)
        except DriverError as err:
            raise ControlError(f"torque {'on' if enabled else 'off'} failed: {err}", "enabled") from err
        self.parts.hub.publish("torque", enabled=enabled)
        return enabled

    # -- the map ------------------------------------------------------------------------------
    def _map_path(self, name: str | None) -> Path:
        if name is None:
            return self.parts.config.map_path
        if not MAP_NAME.fullmatch(name):
            raise InvalidRequestError(f"name {name!r}: expected a file name in the state directory, such as "
                                      "'before-lens-swap.npz' (letters, digits, . _ -; ending .npz)", "name")
        return self.parts.config.state_dir / name

    def save_map(self, name: str | None = None) -> MapAnswer:
        """Save the map (default: the checkpoint file, atomically, keeping .prev)."""
        running = self._running()
        path = self._map_path(name)
        if name is None:
            checkpointer = running.checkpointer
            checkpointer.save()
            if checkpointer.error:
                raise ControlError(checkpointer.error, "name")
            adaptations = checkpointer.last_adaptations
        else:
            def save(gm: GazeMap) -> int:
                write_map(gm, path)
                return gm.adaptations

            try:
                adaptations = running.adapter.with_map(save)
            except OSError as err:
                raise ControlError(f"{path}: cannot save: {err}", "name") from err
        self.parts.hub.publish("map", action="saved", path=str(path), adaptations=adaptations)
        return {"path": str(path), "adaptations": adaptations}

    def load_map(self, name: str | None = None) -> MapAnswer:
        """Replace the map being learned by a saved one (made for the same map parameters)."""
        running = self._running()
        path = self._map_path(name)
        if not path.exists():
            raise NotFoundError(f"{path}: no such map file", "name")
        try:
            gm = read_map(path)
        except MapFileError as err:
            raise ControlError(str(err), "name") from err
        if gm.params != self.parts.config.map_params():
            raise ControlError(f"{path}: saved for other map parameters (image size {gm.params.image_size}, "
                               f"grid {gm.params.grid_shape}, profile {gm.params.profile}) than this head's",
                               "name")
        running.adapter.replace_map(gm)
        log.warning("gaze map replaced by %s (%d adaptations)", path, gm.adaptations)
        self.parts.hub.publish("map", action="loaded", path=str(path), adaptations=gm.adaptations)
        return {"path": str(path), "adaptations": gm.adaptations}

    def reset_map(self, seed: int | None = None) -> MapAnswer:
        """Start learning again from a random map; the map before is saved as `before-reset.npz`."""
        running = self._running()
        config = self.parts.config
        backup = config.state_dir / "before-reset.npz"
        running.adapter.with_map(lambda gm: write_map(gm, backup, keep_previous=False))
        seed = config.gaze_map.seed if seed is None else seed
        running.adapter.replace_map(GazeMap(config.map_params(), seed=seed))
        log.warning("gaze map reset to a random map (seed %d); the previous one is in %s", seed, backup)
        self.parts.hub.publish("map", action="reset", seed=seed, backup=str(backup), adaptations=0)
        return {"path": str(config.map_path), "adaptations": 0, "backup": str(backup)}

    # -- fault injection (simulated head only) ---------------------------------------------------
    def inject_fault(self, fault: SimFault, joint: str | None = None, camera: str | None = None,
                     bits: int = 0) -> str:
        devices = self.parts.devices
        world = devices.world if devices is not None else None
        if world is None:
            raise UnavailableError("fault injection needs the simulated head (servo_bus.backend: sim)", "fault")
        servos = world.servos
        of_a_joint: dict[SimFault, Callable[[str], None]] = {
            SimFault.HARDWARE_ERROR: lambda j: servos.inject_hardware_error(j, bits or 0b0010_0000),
            SimFault.SERVO_REMOVE: servos.remove_servo, SimFault.SERVO_ADD: servos.add_servo}
        if fault is SimFault.BUS_DOWN:
            world.servos.inject_bus_down()
        elif fault is SimFault.RESTORE_BUS:
            world.servos.restore_bus()
        elif fault in of_a_joint:
            if joint not in JOINTS:
                raise InvalidRequestError(f"{fault} needs joint: one of {', '.join(JOINTS)}, got {joint!r}", "joint")
            of_a_joint[fault](joint)
        elif fault is SimFault.POWER_LOSS:
            world.servos.inject_power_loss()
        elif fault is SimFault.POWER_BACK:
            world.servos.restore_power(bits)
        elif fault in (SimFault.STATE_DIR_FULL, SimFault.STATE_DIR_WRITABLE):
            running = self.parts.running
            if running is None:
                raise UnavailableError(f"{fault} needs a running service", "fault")
            writer = running.checkpointer.writer
            if fault is SimFault.STATE_DIR_FULL and not isinstance(writer, FullDisk):
                running.checkpointer.writer = FullDisk(writer)
            elif fault is SimFault.STATE_DIR_WRITABLE and isinstance(writer, FullDisk):
                running.checkpointer.writer = writer.writer
        elif camera not in ("left", "right"):
            raise InvalidRequestError(f"{fault} needs camera: left or right, got {camera!r}", "camera")
        elif fault is SimFault.CAMERA_STALL:
            world.stalled.add(camera)
        elif fault is SimFault.CAMERA_RESUME:
            world.stalled.discard(camera)
        else:
            eye = devices.cameras[camera] if devices is not None else None
            if not isinstance(eye, SimulatedCamera):
                raise UnavailableError(f"{fault} needs a simulated camera {camera}, got {type(eye).__name__}",
                                       "camera")
            if fault is SimFault.CAMERA_UNPLUG:
                eye.unplug()
            else:
                eye.replug()
        log.warning("injected fault: %s %s", fault, joint or camera or "")
        return str(fault)
