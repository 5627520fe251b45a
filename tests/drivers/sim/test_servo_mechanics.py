"""The simulated servos' mechanics (`servo_bus.mechanics`): play, dead band, the tilt's droop,
the encoder's wobble, the adapter's latency timer; the ideal preset as the servos were."""
from __future__ import annotations

import json
import math
import random
from pathlib import Path

import numpy as np
import pytest

from drivers.backends import check_servo_bus_config
from drivers.clock import ManualClock
from drivers.dynamixel.factory import dynamixel_bus_class
from drivers.errors import ServoConfigError
from drivers.servo.config import PartialServoBusConfig, ServoBusConfig
from drivers.servo.joints import JOINTS
from drivers.sim.servo_mechanics import TICK_DEG, ServoMechanics
from drivers.sim.servos import SimulatedServoBus, SimulatedServoProbe
from tests.support.servo_rigs import config_mapping

TRACE = Path(__file__).parents[2] / "data" / "servos" / "ideal-trace.json"
# Only the effect under test: the others off (the preset's values stay for the one asked).
NOTHING_ELSE = {"backlash_deg": 0.0, "dead_band_ticks": 0.0, "sag_deg_at_horizontal": 0.0, "read_wobble_ticks": 0,
                "encoder_ticks_per_rev": 0, "bus_timing": False}


def sim_bus(clock: ManualClock, mechanics: dict | None = None, **bus) -> SimulatedServoBus:
    data = config_mapping(**bus) if mechanics is None else config_mapping(mechanics=mechanics, **bus)
    sim = SimulatedServoBus(ServoBusConfig.from_mapping(data), clock=clock)
    sim.open()
    sim.enable()
    return sim


def only(**effect) -> dict:
    return {"model": "xm430_head", **NOTHING_ELSE, **effect}


def settle(sim: SimulatedServoBus, clock: ManualClock, goals: dict[str, float], seconds: float = 2.0) -> None:
    sim.write_goals(goals)
    clock.advance(seconds)


# --- the ideal preset: the servos as they were ---------------------------------------------
def ideal_run() -> list[dict]:
    """A command plan with reversals, small steps and a joint mounted reversed, read cycle by
    cycle at 100 Hz: what the bus reported, where the joints were, and 37 ms before."""
    clock = ManualClock(5.0)
    cfg = ServoBusConfig.from_mapping(config_mapping(joints={"tilt": {"direction": -1, "zero_offset": 7.5}}))
    sim = SimulatedServoBus(cfg, clock=clock, initial_positions={"pan": 3.0, "tilt": -2.0})
    sim.open()
    sim.enable()
    plan = {0: {"pan": 20.0, "tilt": 10.0, "left_eye": -5.0, "right_eye": 5.0},
            25: {"pan": -12.5, "tilt": -3.25}, 40: {"left_eye": 4.0, "right_eye": -4.0},
            41: {"pan": -12.4}, 70: {"pan": 0.3, "tilt": 0.05, "left_eye": 0.01}}
    out = []
    for cycle in range(120):
        if cycle in plan:
            sim.write_goals(plan[cycle])
        state = sim.read_state()
        now = clock.monotonic()
        out.append({"t": now, "read": {j: [s.position, s.velocity, s.moving] for j, s in state.joints.items()},
                    "true": {j: sim.true_position(j) for j in state.joints},
                    "past": sim.true_joints_at(now - 0.037)})
        clock.advance(0.01)
    sim.close()
    return out


def test_the_ideal_preset_reports_and_moves_bit_for_bit_as_the_servos_did():
    recorded = json.loads(TRACE.read_text())
    assert ideal_run() == recorded  # floats through JSON's repr: exact
    assert all(row["read"][j][0] == row["true"][j] for row in recorded for j in JOINTS)


def test_ideal_is_the_default_and_a_preset_value_can_be_overridden():
    assert ServoBusConfig.from_mapping(config_mapping()).mechanics.resolved().backlash_deg == 0.0
    mech = ServoBusConfig.from_mapping(config_mapping(mechanics={"model": "xm430_head", "backlash_deg": 0.6}))
    values = mech.mechanics.resolved()
    assert values.backlash_deg == 0.6 and values.read_wobble_ticks >= 1 and values.sag_deg_at_horizontal > 0


def test_bad_mechanics_are_refused_naming_the_key_and_only_the_simulation_takes_them():
    with pytest.raises(ServoConfigError, match=r"servo_bus\.mechanics\.model.*ideal.*xm430_head"):
        ServoBusConfig.from_mapping(config_mapping(mechanics={"model": "mx28"}))
    with pytest.raises(ServoConfigError, match=r"servo_bus\.mechanics\.backlash_deg"):
        ServoBusConfig.from_mapping(config_mapping(mechanics={"backlash_deg": -0.1}))
    with pytest.raises(ServoConfigError, match=r"servo_bus\.mechanics\.encoder_ticks_per_rev"):
        ServoBusConfig.from_mapping(config_mapping(mechanics={"encoder_ticks_per_rev": 12}))
    real = ServoBusConfig.from_mapping(config_mapping(backend="dynamixel", mechanics={"model": "xm430_head"}))
    with pytest.raises(ServoConfigError, match=r"servo_bus\.mechanics.*not used by the 'dynamixel'"):
        check_servo_bus_config(real, dynamixel_bus_class(real))
    sim = config_mapping(mechanics={"model": "xm430_head"}, latency_timer_ms=16, baud=3_000_000)
    del sim["retries"]  # the simulation has no retries
    check_servo_bus_config(ServoBusConfig.from_mapping(sim), SimulatedServoBus)


# --- play ----------------------------------------------------------------------------------
def test_a_reversal_lags_by_the_play_which_the_encoder_does_not_see():
    play = 0.5
    clock = ManualClock()
    sim = sim_bus(clock, only(backlash_deg=play), joint_defaults={"profile_velocity": 10, "profile_acceleration": 0})
    settle(sim, clock, {"pan": 5.0})
    assert sim.read_state()["pan"].position == 5.0  # the encoder: where the shaft is
    assert sim.true_position("pan") == pytest.approx(5.0 - play / 2)  # the output trails the push
    sim.write_goals({"pan": 1.0})  # reverse at 10 deg/s: 1 ms moves the shaft 0.01 deg
    start_s = clock.monotonic()
    samples = []  # (time, shaft as read, true output)
    for _ in range(300):
        clock.advance(0.001)
        samples.append((clock.monotonic(), sim.read_state()["pan"].position, sim.true_position("pan")))
    shaft_back = [5.0 - shaft for _, shaft, _ in samples]
    out = np.array([true for *_, true in samples])
    still = out[[b < play - 0.011 for b in shaft_back]]
    moving = out[[b > play + 0.011 for b in shaft_back]]
    assert len(still) > 40 and np.all(still == 5.0 - play / 2)  # not moved for the play's width
    assert np.all(np.diff(moving) < 0) and moving[-1] < 5.0 - play / 2 - 0.5
    clock.advance(1.0)
    assert sim.read_state()["pan"].position == 1.0 and sim.true_position("pan") == pytest.approx(1.0 + play / 2)
    # The cameras' past truth replays the play from the trace.
    for time_s, _, true in samples[-100:]:
        assert sim.true_joints_at(time_s)["pan"] == pytest.approx(true, abs=1e-9)
    assert sim.true_joints_at(start_s + 0.02)["pan"] == 5.0 - play / 2
    sim.close()


def test_the_probe_the_setup_assistant_moves_has_the_same_play():
    play = 0.5
    clock = ManualClock()
    cfg = PartialServoBusConfig.from_mapping({"backend": "sim", "port": "sim:t", "mechanics": only(backlash_deg=play),
                                              "wiring": {7: {"joint": "pan"}, 8: {"joint": "tilt"},
                                                         9: {"joint": "left_eye"}, 10: {"joint": "right_eye"}}})
    probe = SimulatedServoProbe(cfg, clock=clock)
    probe.set_torque(7, True)
    probe.write_goal(7, 4.0)
    clock.advance(1.0)
    assert probe.status(7).position_deg == 4.0 and probe.true_position("pan") == pytest.approx(4.0 - play / 2)
    probe.write_goal(7, 3.8)  # back by less than the play: the output stays
    clock.advance(1.0)
    assert probe.status(7).position_deg == pytest.approx(3.8) and probe.true_position("pan") == 4.0 - play / 2


# --- the tilt's droop ----------------------------------------------------------------------
def droop_at(sag: float, tilt_deg: float, mechanics: dict | None = None) -> tuple[float, float, float]:
    """(true - goal, read - goal, pan's true - goal) with the head held at `tilt_deg`."""
    clock = ManualClock()
    sim = sim_bus(clock, mechanics or only(sag_deg_at_horizontal=sag))
    settle(sim, clock, {"tilt": tilt_deg, "pan": 10.0})
    state = sim.read_state()
    result = (sim.true_position("tilt") - tilt_deg, state["tilt"].position - tilt_deg, sim.true_position("pan") - 10)
    sim.close()
    return result


def test_the_tilt_droops_more_under_more_load_and_the_ideal_head_not_at_all():
    light, level, light_pan = droop_at(0.35, 0.0)
    assert light < 0 and light_pan == 0.0  # down (tilt + is up); the pan carries no torque
    assert level == pytest.approx(light)  # the loop's own error: the encoder reads it
    heavy, _, _ = droop_at(0.7, 0.0)
    assert heavy == pytest.approx(2 * light)  # twice the head's mass x lever arm, twice the droop
    tilted, _, _ = droop_at(0.35, 60.0)  # the lever half as long horizontally
    assert tilted == pytest.approx(light / 2, rel=0.02)
    assert droop_at(0.35, -60.0)[0] == pytest.approx(tilted)
    assert droop_at(0.0, 0.0, {"model": "ideal"}) == (0.0, 0.0, 0.0)


def test_a_loaded_tilt_rests_on_its_downhill_flank_whichever_way_it_came():
    play, sag = 0.4, 0.3
    clock = ManualClock()
    sim = sim_bus(clock, only(backlash_deg=play, sag_deg_at_horizontal=sag))
    for goal in (5.0, -5.0, 0.0, 3.0, 0.0):
        settle(sim, clock, {"tilt": goal})
        shaft = sim.read_state()["tilt"].position
        assert sim.true_position("tilt") == pytest.approx(shaft - play / 2)
    sim.close()


# --- a bus rebuilt from its servos' states (a restarted servo process) --------------------------
def test_a_bus_built_from_the_servos_states_has_the_same_output_and_play():
    """`true_axis` of every joint, given to a new bus as `initial_axes`: each output, shaft and
    offset in the play as they were, and the next moves alike; frames mounted reversed and
    offset too."""
    play, sag = 0.5, 0.35
    clock = ManualClock()
    reversed_and_offset = {"pan": {"direction": -1, "zero_offset": -3.0}, "tilt": {"direction": -1, "zero_offset": 7.5}}
    config = ServoBusConfig.from_mapping(config_mapping(mechanics=only(backlash_deg=play, sag_deg_at_horizontal=sag),
                                                        joints=reversed_and_offset))
    old = SimulatedServoBus(config, clock=clock)
    old.open()
    old.enable()
    settle(old, clock, {"pan": 6.0, "tilt": 8.0, "left_eye": 7.0, "right_eye": -7.0})
    settle(old, clock, {"pan": 5.8, "tilt": 4.0, "left_eye": 3.0, "right_eye": -3.0})  # reversed: the output trails
    states = {joint: old.true_axis(joint) for joint in JOINTS}
    assert states["pan"].output == pytest.approx(6.0 - play / 2)  # back by less than the play: inside it
    assert states["left_eye"].output == pytest.approx(3.0 + play / 2)  # back by more: at its other end
    clock.advance(3.0)
    new = SimulatedServoBus(config, clock=clock, initial_axes=states)
    new.open()
    old_state, new_state = old.read_state(), new.read_state()
    for joint in JOINTS:
        assert new.true_axis(joint) == pytest.approx(states[joint], abs=1e-12)
        assert new.true_position(joint) == pytest.approx(old.true_position(joint), abs=1e-12)
        # Where the output sits in the play: the output against the shaft the encoder reads.
        assert (new.true_position(joint) - new_state[joint].position ==
                pytest.approx(old.true_position(joint) - old_state[joint].position, abs=1e-12))
    old.disable()
    for sim in (old, new):  # goal := present, torque on; then a step each way
        sim.enable()
        clock.advance(1.0)
    for goals in ({"pan": 5.6, "tilt": 3.8, "left_eye": 2.8, "right_eye": -2.8},
                  {"pan": 5.9, "tilt": 4.1, "left_eye": 3.1, "right_eye": -3.1}):
        for sim in (old, new):
            sim.write_goals(goals)
        clock.advance(1.0)
        for joint in JOINTS:
            assert new.true_position(joint) == pytest.approx(old.true_position(joint), abs=1e-12)
            assert new.read_state()[joint].position == pytest.approx(old.read_state()[joint].position, abs=1e-12)
    old.close()
    new.close()


# --- dead band -----------------------------------------------------------------------------
def test_the_controller_does_not_correct_an_error_within_its_dead_band():
    clock = ManualClock()
    sim = sim_bus(clock, only(dead_band_ticks=2.0))
    settle(sim, clock, {"pan": 10.0})
    for small in (1.0, 2.0, -1.5):  # ticks from where it rests: no motion
        settle(sim, clock, {"pan": 10.0 + small * TICK_DEG})
        assert sim.read_state()["pan"].position == 10.0 and sim.true_position("pan") == 10.0
    settle(sim, clock, {"pan": 10.0 + 3 * TICK_DEG})
    assert sim.read_state()["pan"].position == pytest.approx(10.0 + 3 * TICK_DEG)
    sim.close()
    ideal = sim_bus(clock)
    settle(ideal, clock, {"pan": 10.0})
    settle(ideal, clock, {"pan": 10.0 + 0.5 * TICK_DEG})
    assert ideal.read_state()["pan"].position == 10.0 + 0.5 * TICK_DEG
    ideal.close()


# --- the encoder's reading -----------------------------------------------------------------
def readings(seed: int, n: int = 3000) -> tuple[np.ndarray, float]:
    clock = ManualClock()
    sim = sim_bus(clock, only(read_wobble_ticks=1, encoder_ticks_per_rev=4096, seed=seed))
    settle(sim, clock, {"pan": 12.34})
    reads = np.array([sim.read_state()["pan"].position for _ in range(n)])
    true = sim.true_position("pan")
    sim.close()
    return reads, true


def test_the_reading_wobbles_by_a_tick_at_most_and_averages_out():
    reads, true = readings(seed=3)
    assert true == 12.34  # the wobble is the reading's, not the joint's
    ticks = reads / TICK_DEG
    assert np.all(ticks == np.round(ticks))  # whole ticks
    assert np.all(np.abs(reads - true) <= 1.5 * TICK_DEG)  # within a tick of the encoder's tick
    assert len(np.unique(reads)) == 3
    assert abs(reads.mean() - true) < 0.6 * TICK_DEG  # the mean: the tick the shaft is in
    again, _ = readings(seed=3)
    other, _ = readings(seed=4)
    assert np.array_equal(reads, again) and not np.array_equal(reads, other)


# --- the adapter's latency timer -----------------------------------------------------------
def cycle_rate_hz(latency_timer_ms: float, rate_hz: float = 100.0, seconds: float = 2.0) -> float:
    """Cycles a second of a servo loop at `rate_hz` (one read, one write, then a wait for the
    next period, as `ServoLoop.run` does) on a ManualClock."""
    clock = ManualClock()
    sim = sim_bus(clock, {"model": "xm430_head"}, latency_timer_ms=latency_timer_ms, baud=1_000_000)
    period_s, next_s, cycles = 1.0 / rate_hz, clock.monotonic(), 0
    while clock.monotonic() < seconds:
        sim.read_state()
        sim.write_goals({"pan": 5.0 * math.sin(clock.monotonic())})
        cycles += 1
        next_s += period_s
        delay = next_s - clock.monotonic()
        if delay > 0:
            clock.advance(delay)
        else:
            next_s = clock.monotonic()  # no catch-up burst
    sim.close()
    return cycles / clock.monotonic()


def test_the_latency_timer_bounds_the_servo_loop_rate():
    assert cycle_rate_hz(16.0) < 1000.0 / 16.0  # an FTDI adapter at its default cannot keep 100 Hz
    assert cycle_rate_hz(1.0) == pytest.approx(100.0, rel=0.01)  # the udev rule's 1 ms can
    clock = ManualClock()
    instant = sim_bus(clock, {"model": "ideal"}, latency_timer_ms=16.0)
    instant.read_state()
    assert clock.monotonic() == 0.0  # the ideal bus takes no time
    instant.close()


def test_a_read_costs_the_latency_timer_plus_the_bytes_on_the_wire():
    mech = ServoMechanics(ServoBusConfig.from_mapping(config_mapping(mechanics={"model": "xm430_head"})).mechanics,
                          baud=1_000_000, latency_timer_ms=16.0)
    # 18 bytes out, 4 x 27 back at 10 bits a byte: 1.26 ms; the goals: 34 bytes.
    assert mech.read_cost_s(4) == pytest.approx(0.016 + 126e-5)
    assert mech.write_cost_s(4) == pytest.approx(34e-5)


# --- safety --------------------------------------------------------------------------------
@pytest.fixture
def received(monkeypatch) -> list[tuple[object, float]]:
    """(the servo's axis, the goal its controller got), for every goal a servo's controller gets."""
    got: list[tuple[object, float]] = []
    command = ServoMechanics.command

    def spy(self, axis, goal_deg):
        got.append((axis, goal_deg))
        command(self, axis, goal_deg)
    monkeypatch.setattr(ServoMechanics, "command", spy)
    return got


def test_no_goal_outside_the_joint_limits_reaches_a_servo_whatever_the_mechanics(received):
    clock = ManualClock()
    limits = {"pan": (-40, 40), "tilt": (-25, 25), "left_eye": (-15, 15), "right_eye": (-15, 15)}
    joints = {j: {"min_angle": lo, "max_angle": hi, "direction": -1 if j == "tilt" else 1, "zero_offset": 4.0}
              for j, (lo, hi) in limits.items()}
    sim = sim_bus(clock, {"model": "xm430_head", "backlash_deg": 1.0, "sag_deg_at_horizontal": 2.0}, joints=joints)
    joint_of = {id(sim._servos[j].axis): j for j in JOINTS}
    rng = random.Random(5)
    for _ in range(300):
        sim.write_goals({j: rng.uniform(-80, 80) for j in JOINTS if rng.random() < 0.7})
        clock.advance(rng.uniform(0.0, 0.05))
        sim.read_state()
    assert len(received) > 300
    for axis, servo_goal in received:
        joint = joint_of[id(axis)]
        lo, hi = limits[joint]
        assert lo <= sim.config.joints[joint].joint_angle(servo_goal) <= hi, joint
    sim.close()


def test_torque_back_on_at_a_limit_holds_within_it_however_the_reading_wobbles(received):
    clock = ManualClock()
    joints = {"pan": {"min_angle": -40, "max_angle": 40}}
    sim = sim_bus(clock, {"model": "xm430_head", "read_wobble_ticks": 2}, joints=joints)
    settle(sim, clock, {"pan": 40.0})  # on its upper limit
    pan_axis = sim._servos["pan"].axis
    readings = []
    for _ in range(40):  # goal := present each time torque comes back, on a reading that wobbles
        sim.disable()
        sim.enable()
        readings.append(sim.read_state().joints["pan"].position)
        clock.advance(0.01)
    assert max(readings) > 40.0  # the reading did go beyond the limit
    goals = [sim.config.joints["pan"].joint_angle(g) for axis, g in received if axis is pan_axis]
    assert goals and max(goals) <= 40.0 + 1e-9
    sim.close()
