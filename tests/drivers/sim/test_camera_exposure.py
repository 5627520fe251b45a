"""A simulated frame shows the world at its timestamp, however late its capture thread renders
it: the moving objects and the joints where they were then (the servos' trace of their true
motion), and both eyes of a pair the same instant."""
from __future__ import annotations

import math
from collections.abc import Callable, Iterator

import numpy as np
import pytest

from calib_free.sim.head_model import HeadModel
from drivers.cameras.camera import create_camera
from drivers.cameras.config import CameraConfig
from drivers.clock import ManualClock
from drivers.servo.config import ServoBusConfig
from drivers.sim.camera import SimulatedCamera, TimedPoseSource, fixed_pose
from drivers.sim.motion import MovingObject, moving_scene
from drivers.sim.scene import Scene
from drivers.sim.servo_motion import JointTrace
from drivers.sim.servos import SimulatedServoBus
from tests.support.servo_rigs import config_mapping

HEAD = HeadModel.default(160, 120)
FPS = 30.0
REST = {"pan": 0.0, "tilt": 0.0, "left_eye": 3.0, "right_eye": -3.0}
# A cube 0.45 m ahead sweeping at 90 deg/s through the middle of the view: 3 deg (about 6 px
# here) between two frames.
CUBE = MovingObject(speed_deg_s=90.0, sweep_deg=60.0, turn_deg_s2=1e5)
ZERO_VELOCITY = dict.fromkeys(REST, 0.0)


# --- the servos' trace ---------------------------------------------------------------------
def test_the_trace_replays_the_motion_model_from_the_last_row_before_the_time():
    trace = JointTrace(size=4)
    assert trace.at(1.0) is None
    still = {joint: (angle, 0.0, angle, 100.0, math.inf) for joint, angle in REST.items()}
    trace.add(1.0, {**still, "pan": (10.0, 100.0, 20.0, 100.0, math.inf)})  # at 100 deg/s toward 20
    assert trace.at(1.0025)["pan"] == pytest.approx(10.25)
    assert trace.at(1.05)["pan"] == pytest.approx(15.0) and trace.at(1.05)["tilt"] == 0.0
    assert trace.at(1.2)["pan"] == 20.0  # arrived at 1.1 s
    assert trace.at(0.5)["pan"] == 10.0  # before the oldest row: its position
    trace.add(1.001, {**still, "pan": (99.0, 0.0, 99.0, 100.0, math.inf)})  # a read 1 ms later: not kept
    assert trace.at(1.05)["pan"] == pytest.approx(15.0)
    trace.add(1.03, {**still, "pan": (13.0, 100.0, 5.0, 100.0, math.inf)})  # turned back at 1.03 s
    trace.add(1.031, {**still, "pan": (13.0, 0.0, 13.0, 100.0, math.inf)}, change=True)  # held: replaces it
    assert trace.at(1.02)["pan"] == pytest.approx(12.0) and trace.at(1.1)["pan"] == 13.0
    for i in range(4):  # the ring keeps the newest four rows
        trace.add(2.0 + i, {**still, "pan": (float(i), 0.0, float(i), 100.0, math.inf)})
    assert trace.at(1.5)["pan"] == 0.0 and trace.at(4.5)["pan"] == 2.0


@pytest.fixture
def make_bus() -> Iterator[Callable[[ManualClock], SimulatedServoBus]]:
    """Simulated buses on a clock, opened and enabled; all closed at the end of the test."""
    made: list[SimulatedServoBus] = []

    def make(clock: ManualClock) -> SimulatedServoBus:
        bus = SimulatedServoBus(ServoBusConfig.from_mapping(config_mapping(
            joint_defaults={"profile_velocity": 240, "profile_acceleration": 2400})), clock=clock,
            initial_positions=REST)
        made.append(bus)
        bus.open()
        bus.enable()
        return bus

    yield make
    for bus in made:
        bus.close()


def test_the_bus_tells_where_the_joints_were_while_the_servo_loop_moved_them_on(make_bus):
    clock, truth_clock = ManualClock(0.0), ManualClock(0.0)
    bus, twin = make_bus(clock), make_bus(truth_clock)  # the twin makes the same move, watched closely
    for each in (bus, twin):
        each.write_goals({"pan": 30.0, "tilt": -12.0})
    truth: list[tuple[float, float, float]] = []
    for step in range(1, 101):  # 250 ms in 2.5 ms steps; the servo loop reads every 10 ms
        clock.advance(0.0025)
        truth_clock.advance(0.0025)
        truth.append((truth_clock.monotonic(), twin.true_position("pan"), twin.true_position("tilt")))
        if step % 4 == 0:
            bus.read_state()
    assert truth[-1][1:] == pytest.approx((30.0, -12.0))  # the move is over
    for time_s, pan, tilt in truth:
        joints = bus.true_joints_at(time_s)
        # Replayed from the goal write or the last read (10 ms apart). The motion model integrates
        # in 1 ms steps from wherever it was last looked at, so the twin, looked at every 2.5 ms,
        # moves a little differently: up to 0.012 deg here (a linear interpolation of the reads
        # would be 0.07 deg off).
        assert joints["pan"] == pytest.approx(pan, abs=0.015) and joints["tilt"] == pytest.approx(tilt, abs=0.015)


def test_the_bus_is_exact_at_a_time_no_servo_has_moved_past(make_bus):
    clocks = ManualClock(0.0), ManualClock(0.0)
    late, prompt = (make_bus(clock) for clock in clocks)
    for bus, clock in zip((late, prompt), clocks):
        bus.write_goals({"pan": 30.0})
        clock.advance(0.05)
    clocks[0].advance(0.03)  # the late one is asked 30 ms after the moment
    assert late.true_joints_at(0.05) == {joint: prompt.true_position(joint) for joint in REST}
    assert late.true_joints_at(0.08)["pan"] > late.true_joints_at(0.05)["pan"] + 3.0  # it did move on


# --- the cameras ---------------------------------------------------------------------------
class BusPose:
    """A timed pose source over a simulated bus, as the service's simulated world is."""

    def __init__(self, bus: SimulatedServoBus) -> None:
        self.bus = bus

    def __call__(self) -> dict[str, float]:
        return {joint: self.bus.true_position(joint) for joint in REST}

    def at(self, time_s: float) -> dict[str, float]:
        return self.bus.true_joints_at(time_s)


def _camera(eye: str, clock: ManualClock, scene: Scene, pose) -> SimulatedCamera:
    config = CameraConfig.from_mapping({"backend": "sim", "eye": eye, "fps": FPS, "image": "grey",
                                        "width": 160, "height": 120, "seed": 3})
    camera = create_camera(config, clock=clock, head=HEAD, pose_source=pose, scene=scene, paced_by_clock=False)
    assert isinstance(camera, SimulatedCamera)
    camera.open()
    return camera


def _to(clock: ManualClock, time_s: float) -> None:
    """Move the clock to exactly `time_s` (a frame time on the grid is then reached exactly)."""
    clock.advance(time_s - clock.monotonic())


def _world(clock: ManualClock, make_bus: Callable[[ManualClock], SimulatedServoBus]) -> tuple[Scene, SimulatedServoBus]:
    """The cube sweeping from t = 0 and the head panning toward it from 0.95 s."""
    scene = moving_scene(Scene(seed=3, colour=False), [CUBE], clock)
    bus = make_bus(clock)
    _to(clock, 0.95)
    bus.write_goals({"pan": 30.0})
    return scene, bus


def _frame(camera: SimulatedCamera, time_s: float) -> np.ndarray:
    frame = camera.wait_frame(after_s=time_s - 1e-9, timeout_s=10.0)
    assert frame.time_s == pytest.approx(time_s)
    return frame.image


def test_a_frame_rendered_late_shows_the_moving_object_at_its_timestamp():
    on_time_clock, late_clock = ManualClock(0.0), ManualClock(0.0)
    still = fixed_pose(**REST)
    with _camera("left", on_time_clock, moving_scene(Scene(seed=3, colour=False), [CUBE], on_time_clock),
                 still) as on_time, \
            _camera("left", late_clock, moving_scene(Scene(seed=3, colour=False), [CUBE], late_clock), still) as late:
        _to(on_time_clock, 1.0)
        on_time.enable()
        expected = _frame(on_time, 1.0)
        _to(on_time_clock, 31 / FPS)
        next_frame = _frame(on_time, 31 / FPS)
        _to(late_clock, 1.025)  # the capture thread first runs 25 ms after frame 30's time
        late.enable()
        shown = _frame(late, 1.0)
    assert np.mean(np.abs(next_frame.astype(int) - expected)) > 1.0  # the cube moves visibly in a frame
    np.testing.assert_array_equal(shown, expected)


def test_both_eyes_of_a_pair_show_the_same_instant_of_a_moving_head_and_object(make_bus):
    """The right eye renders frame 1.0 s on time, the left one 20 ms late while the servo
    loop has moved the head on; both equal a pair rendered on time in an identical world."""
    clock, reference_clock = ManualClock(0.0), ManualClock(0.0)
    (scene, bus), (reference_scene, reference_bus) = _world(clock, make_bus), _world(reference_clock, make_bus)
    with _camera("left", clock, scene, BusPose(bus)) as left, _camera("right", clock, scene, BusPose(bus)) as right, \
            _camera("left", reference_clock, reference_scene, BusPose(reference_bus)) as reference_left, \
            _camera("right", reference_clock, reference_scene, BusPose(reference_bus)) as reference_right:
        assert isinstance(left.pose_source, TimedPoseSource)
        right.enable()
        for time_s in (0.96, 0.97, 0.98, 0.99, 1.0):  # the servo loop's reads every 10 ms, in both worlds
            for world_clock, world_bus in ((clock, bus), (reference_clock, reference_bus)):
                _to(world_clock, time_s)
                world_bus.read_state()
        pair_right = _frame(right, 1.0)  # on time, the head panning at over 100 deg/s
        for time_s in (1.01, 1.02):
            _to(clock, time_s)
            bus.read_state()
        left.enable()
        pair_left = _frame(left, 1.0)  # 20 ms late: the head has panned 3 deg further by now
        reference_left.enable()
        reference_right.enable()
        expected = _frame(reference_left, 1.0), _frame(reference_right, 1.0)
    assert bus.true_position("pan") > bus.true_joints_at(1.0)["pan"] + 2.0
    np.testing.assert_array_equal(pair_left, expected[0])
    np.testing.assert_array_equal(pair_right, expected[1])


def test_the_moving_objects_rest_at_their_start_until_the_motion_starts():
    clock = ManualClock(5.0)
    motion = moving_scene(Scene(seed=3, colour=False), [CUBE], clock).motion
    assert motion is not None
    motion.start_s = 6.0
    assert not np.any(motion.box_offsets(5.5)) and not np.any(motion.box_offsets())
    assert motion.offset_of(CUBE.name, 6.1)[1] == pytest.approx(0.45 * np.sin(np.radians(9.0)), abs=1e-3)
