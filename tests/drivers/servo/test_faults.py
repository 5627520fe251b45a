"""The bus's record of hardware-error episodes (drivers.servo.faults), on the simulated bus and
on the Dynamixel backend against the emulator: every episode is seen, even one rebooted away
inside one read, says what recovery did, and can be read from another thread without losing
a record."""
from __future__ import annotations

import json
import pickle
import threading

import pytest

from drivers.errors import ServoTimeoutError
from drivers.servo.faults import (
    BITS_CHANGED,
    BY_AUTOMATIC_REBOOT,
    BY_HAND,
    BY_ITSELF,
    CLEARED,
    HELD_OFF,
    LEFT_TO_A_PERSON,
    REBOOT_FAILED,
    REBOOTED,
    REBOOTING,
    RECOVERY_CHANGED,
    REPORTED,
    SEEN,
    WAITING,
    FaultLog,
    HardwareErrorEpisode,
)
from tests.support.servo_rigs import IDS, EmulatorRig, make_rig

FAULT_BACKENDS = ["sim", "dynamixel-emulator"]


def _summary(records):
    return [(r.seq, r.episode, r.change, r.joint, r.bits, r.recovery, r.cleared_by) for r in records]


@pytest.mark.parametrize("make", FAULT_BACKENDS, indirect=True)
class TestEpisodes:
    def test_an_overload_rebooted_at_once_is_seen_and_cleared(self, make):
        rig = make(reboot_on_hardware_error=True)
        with rig.bus as bus:
            bus.enable()
            assert bus.fault_log.last_seq == 0 and bus.fault_log.since() == ()
            rig.hardware_error("tilt", 0x20)
            state = bus.read_state()
            # The state reads clear: the servo was rebooted inside this read...
            assert state["tilt"].hardware_error_bits == 0 and state["tilt"].torque_on and not state.faults
            # ...and the log still holds the error, the reboot and the clearing.
            records = bus.fault_log.since(0)
            assert _summary(records) == [
                (1, 1, SEEN, "tilt", 0x20, REBOOTING, None),
                (2, 1, RECOVERY_CHANGED, "tilt", 0x20, REBOOTED, None),
                (3, 1, CLEARED, "tilt", 0x20, REBOOTED, BY_AUTOMATIC_REBOOT),
            ]
            seen, _rebooted, cleared = records
            assert seen.servo_id == IDS["tilt"] and seen.meanings == ("overload",) and seen.torque_off
            assert seen.is_open and seen.reboots == 1 and seen.bus == bus.name
            assert "joint tilt (id 2)" in seen.detail and "overload" in seen.detail
            assert not cleared.is_open and cleared.cleared_s == rig.clock.monotonic()
            assert 0.0 <= cleared.duration_s <= bus.config.reboot_timeout_s  # the reboot's time, no more
            assert "cleared by an automatic reboot" in cleared.detail
            assert bus.fault_log.open_episodes() == {}
            assert bus.recovery.reboots == {("tilt", "overload"): 1} and not bus.recovery.given_up
            bus.read_state()
            assert bus.fault_log.last_seq == 3  # nothing new while nothing happens

    def test_a_voltage_error_that_lasts_waits_then_is_rebooted(self, make):
        rig = make(reboot_on_hardware_error=True)
        with rig.bus as bus:
            bus.enable()
            persist_s = bus.recovery.limits.persist_s
            rig.hardware_error("pan", 0x01)
            assert bus.read_state()["pan"].hardware_error_bits == 0x01
            [waiting] = bus.fault_log.since(0)
            assert (waiting.change, waiting.recovery, waiting.torque_off) == (SEEN, WAITING, False)
            assert f"rebooted if it lasts {persist_s:g} s" in waiting.detail
            for _ in range(3):  # it lasts: the same open episode, nothing new to record
                rig.advance(persist_s / 4)
                assert bus.read_state()["pan"].hardware_error_bits == 0x01
            assert bus.fault_log.last_seq == 1 and bus.fault_log.open_episodes() == {"pan": waiting}
            rig.advance(persist_s / 4)
            assert bus.read_state()["pan"].hardware_error_bits == 0  # lasted persist_s: rebooted
            assert _summary(bus.fault_log.since(1)) == [
                (2, 1, RECOVERY_CHANGED, "pan", 0x01, REBOOTING, None),
                (3, 1, RECOVERY_CHANGED, "pan", 0x01, REBOOTED, None),
                (4, 1, CLEARED, "pan", 0x01, REBOOTED, BY_AUTOMATIC_REBOOT),
            ]
            cleared = bus.fault_log.since(3)[0]
            assert persist_s <= cleared.duration_s <= persist_s + bus.config.reboot_timeout_s
            assert cleared.first_seen_s == waiting.first_seen_s and cleared.reboots == 1

    def test_without_automatic_reboot_an_error_lasts_until_a_person_reboots(self, make):
        rig = make(reboot_on_hardware_error=False)
        with rig.bus as bus:
            bus.enable()
            rig.hardware_error("left_eye", 0x01)
            for _ in range(5):
                assert bus.read_state()["left_eye"].hardware_error_bits == 0x01
                rig.advance(10.0)
            [reported] = bus.fault_log.since(0)
            assert (reported.recovery, reported.is_open) == (REPORTED, True)
            assert "automatic reboot is off" in reported.detail
            rig.hardware_error("left_eye", 0x04)  # overheating on top: cuts torque
            bus.read_state()
            [changed] = bus.fault_log.since(1)
            assert (changed.change, changed.bits, changed.meanings, changed.torque_off) == (
                BITS_CHANGED, 0x05, ("input voltage out of range", "overheating"), True)
            bus.reboot("left_eye")
            assert bus.fault_log.open_episodes()["left_eye"].is_open  # closed by the next read
            bus.read_state()
            [cleared] = bus.fault_log.since(2)
            assert cleared.cleared_by == BY_HAND and cleared.duration_s == pytest.approx(50.0, abs=0.5)
            assert bus.recovery.reboots == {}

    def test_a_repeating_overload_is_left_to_a_person_and_the_episode_says_so(self, make):
        rig = make(reboot_on_hardware_error=True)
        with rig.bus as bus:
            bus.enable()
            limits = bus.recovery.limits
            rig.hardware_error("pan", 0x20)
            bus.read_state()  # episode 1: rebooted at once
            rig.hardware_error("pan", 0x20)
            bus.read_state()  # episode 2: back within the holdoff: reported
            held = bus.fault_log.open_episodes()["pan"]
            assert (held.recovery, held.reboots) == (HELD_OFF, 0)
            for _ in range(limits.max_reboots - 1):  # rebooted once the holdoff has passed, and again
                rig.advance(limits.holdoff_s)
                bus.read_state()
                rig.hardware_error("pan", 0x20)
                bus.read_state()
            rig.advance(limits.holdoff_s)
            assert bus.read_state()["pan"].hardware_error_bits == 0x20  # the limit: not rebooted
            given_up = bus.fault_log.open_episodes()["pan"]
            assert given_up.recovery == LEFT_TO_A_PERSON and given_up.left_to_a_person
            assert "left to a person" in given_up.detail and "joint pan (id 1)" in given_up.detail
            assert bus.recovery.given_up == {"pan"}
            assert bus.recovery.reboots == {("pan", "overload"): limits.max_reboots}
            last = bus.fault_log.last_seq
            rig.advance(limits.window_s)
            bus.read_state()
            assert bus.fault_log.last_seq == last  # still a person's: no new verdict, nothing recorded
            episodes = bus.fault_log.episodes()
            assert [e.cleared_by for e in episodes.values()] == [BY_AUTOMATIC_REBOOT, BY_AUTOMATIC_REBOOT,
                                                                 BY_AUTOMATIC_REBOOT, None]
            bus.reboot("pan")
            bus.read_state()
            assert bus.fault_log.since(last)[-1].cleared_by == BY_HAND and not bus.recovery.given_up

    def test_an_error_found_at_enable_is_an_episode(self, make):
        rig = make(reboot_on_hardware_error=True)
        with rig.bus as bus:
            rig.hardware_error("right_eye", 0x20)
            bus.enable()
            bus.read_state()
            assert _summary(bus.fault_log.since(0)) == [
                (1, 1, SEEN, "right_eye", 0x20, REBOOTING, None),
                (2, 1, RECOVERY_CHANGED, "right_eye", 0x20, REBOOTED, None),
                (3, 1, CLEARED, "right_eye", 0x20, REBOOTED, BY_AUTOMATIC_REBOOT),
            ]
            assert bus.recovery.reboots == {("right_eye", "at enable: overload"): 1}


def test_a_failed_reboot_is_recorded_and_the_error_stays_open(tmp_path):
    rig = EmulatorRig(tmp_path, reboot_on_hardware_error=True)
    try:
        with rig.bus as bus:
            bus.enable()
            rig.hardware_error("tilt", 0x20)
            with _replies_lost_after_the_first(rig, IDS["tilt"]):  # the sync read answered, the reboot not
                with pytest.raises(ServoTimeoutError, match=r"joint tilt \(id 2\).*reboot"):
                    bus.read_state()
            failed = bus.fault_log.open_episodes()["tilt"]
            assert (failed.recovery, failed.is_open) == (REBOOT_FAILED, True)
            assert "automatic reboot failed" in failed.detail and "joint tilt (id 2)" in failed.detail
            # The instruction did arrive (only its reply was lost): the servo rebooted, and the
            # next read finds it clear, and restores the torque it lost.
            rig.advance(1.0)
            state = bus.read_state()
            assert state["tilt"].hardware_error_bits == 0 and state["tilt"].torque_on
            cleared = bus.fault_log.since(failed.seq)[-1]
            assert (cleared.change, cleared.cleared_by) == (CLEARED, BY_AUTOMATIC_REBOOT)
    finally:
        rig.close()


class _replies_lost_after_the_first:
    """The servo's first reply goes out; the ones after it (every retry) are lost."""

    def __init__(self, rig: EmulatorRig, servo_id: int) -> None:
        self.emulator, self.servo_id = rig.emulator, servo_id
        self.sent = 0

    def __enter__(self):
        self.emulator.wait_idle()
        original = self.original = self.emulator._send

        def send(servo_id, reply):
            if servo_id == self.servo_id:
                self.sent += 1
                if self.sent > 1:
                    return
            original(servo_id, reply)

        self.emulator._send = send
        return self

    def __exit__(self, *exc):
        self.emulator.wait_idle()
        self.emulator._send = self.original


# --- the log as data -------------------------------------------------------------------------
def _record(seq: int, episode: int = 1, **changes) -> HardwareErrorEpisode:
    fields = dict(seq=seq, episode=episode, change=SEEN, time_s=float(seq), bus="/dev/x", joint="pan", servo_id=1,
                  bits=0x20, meanings=("overload",), torque_off=True, first_seen_s=0.0, first_seen_unix=1.7e9,
                  recovery=REBOOTING, reboots=1, detail="joint pan (id 1) on /dev/x: overload")
    fields.update(changes)
    return HardwareErrorEpisode(**fields)


def test_records_cross_a_process_boundary_and_become_json():
    record = _record(3, cleared_s=1.5, cleared_by=BY_ITSELF, change=CLEARED)
    assert pickle.loads(pickle.dumps(record)) == record
    data = json.loads(json.dumps(record.as_dict()))
    assert data["meanings"] == ["overload"] and data["cleared_by"] == BY_ITSELF and data["seq"] == 3
    assert HardwareErrorEpisode(**{**data, "meanings": tuple(data["meanings"])}) == record
    assert record.key == "servo:pan:1" and record.duration_s == 1.5
    with pytest.raises(AttributeError):
        record.bits = 0  # type: ignore[misc]


def test_a_bounded_log_says_how_much_a_slow_reader_missed():
    log = FaultLog(capacity=4)
    for seq in range(1, 11):
        log._append(lambda s: _record(s, episode=s, change=CLEARED, cleared_s=float(s), cleared_by=BY_ITSELF))
    assert log.last_seq == 10
    assert [r.seq for r in log.since(0)] == [7, 8, 9, 10]
    assert log.missed(0) == 6 and log.missed(5) == 1 and log.missed(6) == 0 and log.missed(10) == 0
    assert [r.seq for r in log.since(8)] == [9, 10] and log.since(10) == ()
    with pytest.raises(ValueError):
        FaultLog(capacity=0)


def test_a_reader_in_another_thread_misses_no_record_while_the_bus_runs(tmp_path):
    """The bus thread makes episodes as fast as it can; a reader polls `since()` without any
    pause (a slow reader would only see more at once) and must see every record, in order."""
    rig = make_rig("sim", tmp_path, reboot_on_hardware_error=True)
    episodes = 200
    done = threading.Event()
    seen: list[HardwareErrorEpisode] = []
    errors: list[BaseException] = []

    def reader() -> None:
        try:
            cursor = 0
            while True:
                finished = done.is_set()  # read before the log: nothing is appended after it is set
                for record in rig.bus.fault_log.since(cursor):
                    seen.append(record)
                    cursor = record.seq
                if finished and cursor == rig.bus.fault_log.last_seq:
                    return
        except BaseException as err:  # reported to the test thread
            errors.append(err)

    with rig.bus as bus:
        bus.enable()
        thread = threading.Thread(target=reader, name="fault-log-reader")
        thread.start()
        try:
            joints = ["pan", "tilt", "left_eye", "right_eye"]
            for i in range(episodes):
                rig.hardware_error(joints[i % 4], (0x20, 0x04, 0x10)[i % 3])  # each cuts torque
                bus.read_state()
                rig.advance(bus.recovery.limits.window_s)  # outside every limit: each is rebooted
        finally:
            done.set()
            thread.join(30)
    assert not thread.is_alive() and not errors
    assert [r.seq for r in seen] == list(range(1, bus.fault_log.last_seq + 1))
    assert bus.fault_log.missed(0) == 0
    closed = [r for r in seen if r.change == CLEARED]
    assert len(closed) == episodes and all(r.cleared_by == BY_AUTOMATIC_REBOOT for r in closed)
    assert sum(bus.recovery.reboots.values()) == episodes
