"""Hardware-error episodes of a servo bus: every one recorded, readable from any thread.

An episode is one stretch of time during which a joint's servo reports a non-zero Hardware
Error Status, from the first read that shows the error to the first that no longer does. The
bus (`drivers.servo.bus.ServoBus`) opens, updates and closes episodes as it reads its state,
and records what its recovery policy (`drivers.servo.recovery`) did about each. An overload
that the bus reboots away inside one `read_state()` is an episode like any other: the state
returned reads clear, and the log still holds the error, the reboot and the clearing.

Every change to an episode is a new record in the bus's `FaultLog` (`bus.fault_log`): an
append-only, bounded sequence of `HardwareErrorEpisode` records numbered 1, 2, 3, ... A
reader keeps the last number it has seen and asks for what came after it:

    cursor = 0
    for record in bus.fault_log.since(cursor):   # at any rate, from any thread
        ...
        cursor = record.seq

The records of one episode share `episode` (the number of its first record); the latest one
says where the episode stands. Records are frozen dataclasses of builtins: they can be kept,
compared, pickled across a process boundary, or turned into JSON with `as_dict()`.
Reading takes no lock: the log is an immutable tuple replaced on each append (appends are
rare: a few records per episode), so a reader in another thread is never blocked by the bus
and never sees a half-made record.
"""
from __future__ import annotations

import dataclasses
import threading
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

# What recovery did about an episode, as of the record (`HardwareErrorEpisode.recovery`).
REPORTED = "reported"  # automatic reboot is off (`reboot_on_hardware_error: false`): reported only
WAITING = "waiting"  # the error left torque on: rebooted once it has lasted `persist_s`
HELD_OFF = "held off"  # back within `holdoff_s` of a reboot: reported, rebooted once that has passed
REBOOTING = "rebooting"  # an automatic reboot has been decided and is under way
REBOOTED = "rebooted"  # rebooted automatically (torque restored at the position read back if enabled)
REBOOT_FAILED = "reboot failed"  # the reboot raised (the servo did not come back, the bus went down)
LEFT_TO_A_PERSON = "left to a person"  # the reboot limit was reached: only a reboot by hand or a power cycle
RECOVERIES: tuple[str, ...] = (REPORTED, WAITING, HELD_OFF, REBOOTING, REBOOTED, REBOOT_FAILED, LEFT_TO_A_PERSON)

# How an episode ended (`HardwareErrorEpisode.cleared_by`).
BY_AUTOMATIC_REBOOT = "automatic reboot"
BY_HAND = "reboot by hand"  # `ServoBus.reboot(joint)`
BY_ITSELF = "itself"  # read clear without a reboot by this bus: a power cycle, or another program's reboot

# What a record records (`HardwareErrorEpisode.change`).
SEEN = "seen"  # the episode's first record: the error first read
BITS_CHANGED = "bits changed"  # the servo reports other bits, the episode goes on
RECOVERY_CHANGED = "recovery"  # recovery did something new about it
CLEARED = "cleared"  # the episode's last record: the error read clear


@dataclass(frozen=True)
class HardwareErrorEpisode:
    """One record of the fault log: an episode as it stood after one change.

    Times ending in `_s` are the bus's monotonic clock (`bus.clock`); `first_seen_unix` is
    wall-clock time, for people and files.
    """

    seq: int  # this record's place in the log: 1, 2, 3, ... with no gaps
    episode: int  # the episode's number: the seq of its first record
    change: str  # what this record records: SEEN, BITS_CHANGED, RECOVERY_CHANGED or CLEARED
    time_s: float  # when this change happened
    bus: str  # the bus's name (its port)
    joint: str
    servo_id: int
    bits: int  # Hardware Error Status as last read in the episode
    meanings: tuple[str, ...]  # the bits' meanings ("overload", ...)
    torque_off: bool  # torque was off when these bits were first read (on an enabled bus: the error cut it)
    first_seen_s: float
    first_seen_unix: float
    recovery: str  # what recovery did last: one of RECOVERIES
    reboots: int  # automatic reboots of this joint during the episode
    detail: str  # one line for people, naming the joint, servo id and port
    cleared_s: float | None = None  # when the error was first read clear; None while it lasts
    cleared_by: str | None = None  # BY_AUTOMATIC_REBOOT, BY_HAND or BY_ITSELF once cleared

    @property
    def is_open(self) -> bool:
        return self.cleared_s is None

    @property
    def left_to_a_person(self) -> bool:
        return self.recovery == LEFT_TO_A_PERSON

    @property
    def duration_s(self) -> float | None:
        """From first seen to cleared; None while the episode lasts."""
        return None if self.cleared_s is None else self.cleared_s - self.first_seen_s

    @property
    def key(self) -> str:
        """A name that stays the same for the whole episode: 'servo:<joint>:<episode>'."""
        return f"servo:{self.joint}:{self.episode}"

    def as_dict(self) -> dict[str, Any]:
        """The record as plain JSON-ready values (meanings as a list)."""
        out = dataclasses.asdict(self)
        out["meanings"] = list(self.meanings)
        return out


class FaultLog:
    """The bus's append-only, bounded log of `HardwareErrorEpisode` records.

    Readers (any thread, any rate): `since(seq)`, `last_seq`, `missed(seq)`,
    `open_episodes()`. The oldest records are dropped beyond `capacity`; `missed(seq)` says
    how many records after `seq` a reader that fell that far behind has lost (0 while it
    keeps up). Open episodes are kept apart from the records, so `open_episodes()` never
    loses one to the bound. One writer, the bus, appends (`EpisodeRecorder`).
    """

    DEFAULT_CAPACITY = 1024

    def __init__(self, capacity: int = DEFAULT_CAPACITY) -> None:
        if capacity < 1:
            raise ValueError(f"fault log capacity {capacity}: expected at least 1")
        self.capacity = capacity
        # Both replaced, never mutated: a reader takes the reference and has a consistent view.
        self._records: tuple[HardwareErrorEpisode, ...] = ()
        self._open: Mapping[str, HardwareErrorEpisode] = {}
        self._last_seq = 0
        self._append_lock = threading.Lock()

    @property
    def last_seq(self) -> int:
        """The seq of the newest record (0 before the first)."""
        return self._last_seq

    def since(self, seq: int = 0) -> tuple[HardwareErrorEpisode, ...]:
        """The records after `seq`, oldest first (those still held)."""
        records = self._records
        if not records:
            return ()
        start = max(0, seq + 1 - records[0].seq)
        return records[start:]

    def missed(self, seq: int) -> int:
        """How many records after `seq` have already been dropped for the bound."""
        records = self._records
        return max(0, records[0].seq - seq - 1) if records else 0

    def open_episodes(self) -> Mapping[str, HardwareErrorEpisode]:
        """Joint -> the latest record of its episode, for each joint whose error lasts."""
        return self._open

    def episodes(self) -> dict[int, HardwareErrorEpisode]:
        """Episode number -> its latest record, for every episode with a record still held."""
        return {record.episode: record for record in self._records}

    def _append(self, make: Callable[[int], HardwareErrorEpisode]) -> HardwareErrorEpisode:
        with self._append_lock:
            record = make(self._last_seq + 1)
            self._records = (self._records + (record,))[-self.capacity:]
            opened = dict(self._open)
            if record.is_open:
                opened[record.joint] = record
            else:
                opened.pop(record.joint, None)
            self._open = opened
            self._last_seq = record.seq
            return record


class EpisodeRecorder:
    """The bus's side of the log: opens, updates and closes episodes as states are read.

    Called only by the bus, under its lock. Each call that changes an episode appends one
    record and returns it; calls that change nothing return None.
    """

    def __init__(self, log: FaultLog, bus: str, wall_clock: Callable[[], float] = time.time) -> None:
        self.log = log
        self.bus = bus
        self._wall_clock = wall_clock
        self._expect_clear: dict[str, str] = {}  # joint -> what will have cleared it (a reboot just done)

    def current(self, joint: str) -> HardwareErrorEpisode | None:
        return self.log.open_episodes().get(joint)

    def seen(self, joint: str, servo_id: int, bits: int, meanings: tuple[str, ...], torque_on: bool,
             now_s: float, recovery: str | None, detail: str) -> HardwareErrorEpisode | None:
        """The error read now. Opens an episode, or records new bits or a new `recovery`
        (None: recovery has nothing new to say, as on the read right after a reboot)."""
        self._expect_clear.pop(joint, None)
        current = self.current(joint)
        if current is None:
            unix = self._wall_clock()
            return self.log._append(lambda seq: HardwareErrorEpisode(
                seq=seq, episode=seq, change=SEEN, time_s=now_s, bus=self.bus, joint=joint, servo_id=servo_id,
                bits=bits, meanings=meanings, torque_off=not torque_on, first_seen_s=now_s, first_seen_unix=unix,
                recovery=recovery or REPORTED, reboots=1 if recovery == REBOOTING else 0, detail=detail,
            ))
        if bits != current.bits:
            change, torque_off = BITS_CHANGED, not torque_on
        elif recovery is not None and recovery != current.recovery:
            # Torque as first read says whether the error cut it; later it may be off for
            # other reasons (the bus disabled), so it is taken again only with new bits.
            change, torque_off = RECOVERY_CHANGED, current.torque_off
        else:
            return None
        new_recovery = recovery or current.recovery
        reboots = current.reboots + (recovery == REBOOTING)
        return self.log._append(lambda seq: dataclasses.replace(
            current, seq=seq, change=change, time_s=now_s, bits=bits, meanings=meanings, torque_off=torque_off,
            recovery=new_recovery, reboots=reboots, detail=detail,
        ))

    def acted(self, joint: str, recovery: str, now_s: float, detail: str) -> HardwareErrorEpisode | None:
        """Recovery did something about the joint's open episode (REBOOTED, REBOOT_FAILED)."""
        current = self.current(joint)
        if current is None:
            return None
        if recovery in (REBOOTED, REBOOT_FAILED):
            # A reboot whose reply was lost may still have happened: if the next read
            # finds the joint clear, that reboot cleared it.
            self._expect_clear[joint] = BY_AUTOMATIC_REBOOT
        return self.log._append(lambda seq: dataclasses.replace(
            current, seq=seq, change=RECOVERY_CHANGED, time_s=now_s, recovery=recovery, detail=detail,
        ))

    def rebooted_by_hand(self, joint: str) -> None:
        """A person rebooted the joint: if the next read finds it clear, that cleared it."""
        if self.current(joint) is not None:
            self._expect_clear[joint] = BY_HAND

    def clear(self, joint: str, now_s: float, detail: Callable[[HardwareErrorEpisode, str], str]
              ) -> HardwareErrorEpisode | None:
        """The joint read clear: closes its episode, if one is open."""
        current = self.current(joint)
        by = self._expect_clear.pop(joint, BY_ITSELF)
        if current is None:
            return None
        return self.log._append(lambda seq: dataclasses.replace(
            current, seq=seq, change=CLEARED, time_s=now_s, cleared_s=now_s, cleared_by=by,
            detail=detail(current, by),
        ))


def cleared_detail(describe: Callable[[str], str], now_s: float, episode: HardwareErrorEpisode, by: str) -> str:
    """The fault log's words for an episode that ended (`by`: how), `describe` naming the joint."""
    how = {BY_AUTOMATIC_REBOOT: "by an automatic reboot", BY_HAND: "by a reboot by hand",
           BY_ITSELF: "without a reboot by this bus"}.get(by, by)
    return (f"{describe(episode.joint)}: hardware error 0x{episode.bits:02x} "
            f"({'; '.join(episode.meanings)}) cleared {how} after {now_s - episode.first_seen_s:.3f} s")
