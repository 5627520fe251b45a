"""The cameras' exposure held over a fixation (`headctl.service.exposure`): locked before the
fixation's first image, unlocked after it ends however it ends, once for a whole look, on
the simulated head and through the fixation thread and the online experiments. The cameras
held are small fakes with the lock hooks, so what each fixation does to them is recorded
beside the pairs the head takes."""
from __future__ import annotations

import logging
import threading

import numpy as np
import pytest

from calib_free.gaze.fixation import FixationController, FixationParams
from calib_free.map.gaze_map import GazeMap
from drivers.cameras.camera import Camera, Capabilities, ExposureMode
from drivers.cameras.config import CameraConfig
from drivers.clock import SYSTEM_CLOCK
from drivers.errors import CameraError
from headctl.experiments import online
from headctl.experiments.online import OnlineSpec, SimulatedHeadRig, run_online
from headctl.service.events import EventHub
from headctl.service.exposure import ExposureHold
from headctl.service.fixation_thread import FixationThread, Interrupt
from headctl.service.looks import LookKind, LookQueue, LookRequest, LookState
from tests.support.planar_head import LinearMap, PlanarHead


class LockableCamera(Camera):
    """A camera whose lock hooks write into a shared log."""

    backend_name = "lockable"
    capabilities = Capabilities(exposure_lock=True)

    def __init__(self, name: str, log: list[str], control: str = "lock_per_fixation") -> None:
        super().__init__(CameraConfig(backend="lockable", exposure_control=control), name=name)
        self.log = log
        self.fail_unlock = 0

    def _lock_exposure(self) -> None:
        self.log.append(f"lock {self.name}")

    def _unlock_exposure(self) -> None:
        if self.fail_unlock:
            self.fail_unlock -= 1
            raise CameraError(f"{self.name}: no answer")
        self.log.append(f"unlock {self.name}")


class LoggedPairs:
    """A pair source that logs each pair and the cameras' exposure modes when it was taken."""

    def __init__(self, pairs, log: list[str], cameras: list[Camera]) -> None:
        self.pairs, self.log, self.cameras = pairs, log, cameras
        self.modes: list[tuple[ExposureMode, ...]] = []

    @property
    def last_exposure_s(self):
        return self.pairs.last_exposure_s

    def wait_pair(self, after_s, timeout_s):
        self.log.append("pair")
        self.modes.append(tuple(c.exposure_mode for c in self.cameras))
        return self.pairs.wait_pair(after_s, timeout_s)


@pytest.fixture
def cameras():
    log: list[str] = []
    pair = [LockableCamera("left", log), LockableCamera("right", log)]
    for camera in pair:
        camera.open()
    log.clear()  # opening with lock_per_fixation let the auto exposure run: not a fixation's
    yield pair, log
    for camera in pair:
        camera.close()


class ServiceHead(PlanarHead):
    """The plane head with the phase the fixation thread sets."""

    def set_phase(self, phase: str) -> None:
        pass


def fixation_thread(controller, head, hold) -> FixationThread:
    return FixationThread(controller, head, Interrupt(threading.Event()), LookQueue(), EventHub(), lambda: None,
                          exposure=hold)


def test_an_exploratory_fixation_on_the_simulated_head_locks_before_its_first_image_and_unlocks_after(cameras):
    pair, log = cameras
    with SimulatedHeadRig(seed=0) as rig:
        logged = rig.head.pairs = LoggedPairs(rig.head.pairs, log, pair)
        controller = FixationController(rig.head, GazeMap.for_image(320, 240, seed=0), rig.fixation, seed=3,
                                        clock=rig.clock.monotonic)
        thread = fixation_thread(controller, rig.head, ExposureHold(pair))
        for _ in range(2):
            record = thread._fixate(None)  # what the thread's loop does for an exploratory fixation
            assert record.outcome
    first = log.index("pair")
    assert log[:first] == ["lock left", "lock right"]  # both held before the pre-saccade pair
    assert log.count("lock left") == log.count("unlock left") == 2
    second = log.index("lock left", 1)
    assert log[second - 2:second] == ["unlock left", "unlock right"]  # the first fixation ended unlocked
    assert log[-2:] == ["unlock left", "unlock right"]
    assert all(modes == (ExposureMode.LOCKED,) * 2 for modes in logged.modes)  # every pair under one exposure
    assert all(c.exposure_mode is ExposureMode.AUTO for c in pair)


def test_a_fixation_that_fails_unlocks_all_the_same(cameras):
    pair, log = cameras

    class BrokenController:
        params = FixationParams()
        clock = staticmethod(SYSTEM_CLOCK.monotonic)

        def fixate(self, target=None, reference_pose=None, continues=False):
            assert all(c.exposure_mode is ExposureMode.LOCKED for c in pair)
            raise RuntimeError("the controller failed")

    thread = fixation_thread(BrokenController(), ServiceHead(), ExposureHold(pair))
    with pytest.raises(RuntimeError, match="the controller failed"):
        thread._fixate(None)
    assert log == ["lock left", "lock right", "unlock left", "unlock right"]
    assert all(c.exposure_mode is ExposureMode.AUTO for c in pair)


def test_a_look_holds_one_exposure_over_all_its_fixations(cameras):
    pair, log = cameras
    head = ServiceHead()
    real_wait_pair = head.wait_pair

    def wait_pair(after_s, timeout_s):
        log.append("pair")
        return real_wait_pair(after_s, timeout_s)

    head.wait_pair = wait_pair
    controller = FixationController(head, LinearMap(0.8), seed=0)
    thread = fixation_thread(controller, head, ExposureHold(pair))
    thread.looks.submit(LookRequest(LookKind.TARGET, (255.0, 75.0, 0.0)))
    job = thread.looks.take()
    thread._look(job)
    assert job.state is LookState.DONE and len(job.result["fixations"]) >= 2  # corrective steps ran
    assert log[:2] == ["lock left", "lock right"] and log[-2:] == ["unlock left", "unlock right"]
    assert log.count("lock left") == 1 and set(log[2:-2]) == {"pair"}


def test_only_cameras_configured_lock_per_fixation_are_held(cameras):
    pair, log = cameras
    auto = LockableCamera("auto", log, control="auto")
    hold = ExposureHold([*pair, auto])
    assert hold.cameras == tuple(pair)
    with hold.held():
        pass
    assert "lock auto" not in log and hold.holds == 1


def test_a_camera_that_cannot_be_held_is_logged_and_the_fixation_goes_on(cameras, caplog):
    pair, log = cameras
    pair[1].close()  # lost meanwhile
    hold = ExposureHold(pair)
    ran = []
    with caplog.at_level(logging.WARNING, logger="headctl.service.exposure"):
        with hold.held():
            ran.append(True)
    assert ran and log == ["lock left", "unlock left"] and hold.failures == 1 and hold.holds == 0
    assert "right: exposure not held for this fixation: right: the device is closed" in caplog.text


def test_an_unlock_that_failed_is_tried_again_after_the_next_fixation(cameras):
    pair, log = cameras
    hold = ExposureHold(pair)
    pair[0].fail_unlock = 1
    with hold.held():
        pass
    assert pair[0].exposure_mode is ExposureMode.LOCKED and hold.failures == 1
    with hold.held():
        pass
    assert pair[0].exposure_mode is ExposureMode.AUTO
    # Held still, the left camera is not locked again; its unlock comes after the second fixation.
    assert log == ["lock left", "lock right", "unlock right", "lock right", "unlock left", "unlock right"]


def test_the_online_experiment_holds_the_exposure_over_each_fixation(cameras, monkeypatch):
    pair, log = cameras
    monkeypatch.setattr(online, "ExposureHold", lambda rig_cameras: ExposureHold(pair))
    result = run_online(OnlineSpec("short", 3), seed=0, landing_every=0)
    assert len(result.records) == 3
    assert log == ["lock left", "lock right", "unlock left", "unlock right"] * 3
    assert np.all([c.exposure_mode is ExposureMode.AUTO for c in pair])
