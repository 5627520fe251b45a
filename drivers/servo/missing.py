"""Servos that do not answer: which joints are off the bus, why, and when to ping them again.

A servo bus (`drivers.servo.bus.ServoBus`) opens with a servo missing rather than failing:
the joints that answered are driven, the missing ones are recorded here (`MissingServo`:
joint, id, port, reason, since when) and pinged again with a back-off (0.1 s doubling to
5 s, `drivers.clock.Backoff`) from the bus's reads. A servo that leaves the bus while
running (its cable unplugged, its power gone) is recorded too, once the bus's reads have
failed blaming it alone for `DROP_AFTER_S`: a single failed read stays a failed read.

`MissingServos` holds no lock of its own: the bus calls it under its lock, and `snapshot()`
returns a mapping that is replaced, never changed, so any thread may read it.
"""
from __future__ import annotations

import logging
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from types import MappingProxyType

from drivers.clock import Backoff
from drivers.errors import BusDownError, ServoCommError, ServoError

log = logging.getLogger(__name__)

# Pinging a missing servo again: first after this, doubling up to the maximum.
PING_BACKOFF_FIRST_S = 0.1
PING_BACKOFF_MAX_S = 5.0
# Reads failing for one servo (the others answering) this long: it has left the bus.
DROP_AFTER_S = 0.5


@dataclass(frozen=True)
class MissingServo:
    """One joint whose servo does not answer."""

    joint: str
    servo_id: int
    port: str
    reason: str
    since_s: float  # monotonic clock

    def describe(self) -> str:
        """'joint left_eye (id 3) on /dev/head-servos: not answering (<reason>)'."""
        return f"joint {self.joint} (id {self.servo_id}) on {self.port}: not answering ({self.reason})"


class MissingServos:
    """The missing joints of one bus (`ids`: joint -> servo id, on `port`), their back-offs
    and the reads failing for one servo; it logs what changes."""

    def __init__(self, ids: Mapping[str, int], port: str, first_s: float = PING_BACKOFF_FIRST_S,
                 max_s: float = PING_BACKOFF_MAX_S, drop_after_s: float = DROP_AFTER_S) -> None:
        self.ids = dict(ids)
        self.port = port
        self.first_s = first_s
        self.max_s = max_s
        self.drop_after_s = drop_after_s
        self._entries: Mapping[str, MissingServo] = MappingProxyType({})
        self._backoff: dict[str, Backoff] = {}
        self._next_ping_s: dict[str, float] = {}
        self._failing_since: dict[str, float] = {}  # joint -> first of the failed reads blaming it alone

    def snapshot(self) -> Mapping[str, MissingServo]:
        """The missing joints now (a read-only mapping that is never changed in place)."""
        return self._entries

    def __contains__(self, joint: object) -> bool:
        return joint in self._entries

    def reset(self) -> None:
        """Forget everything (the bus is opened or reopened and pings every servo)."""
        self._entries = MappingProxyType({})
        self._backoff.clear()
        self._next_ping_s.clear()
        self._failing_since.clear()

    def reason_of(self, joint: str, err: BaseException) -> str:
        """An error's message without the joint's description it starts with."""
        text, prefix = str(err), f"joint {joint} (id {self.ids[joint]}) on {self.port}: "
        return text[len(prefix):] if text.startswith(prefix) else text

    def add(self, joint: str, err: BaseException, now_s: float, how: str) -> None:
        """Record a missing joint (`how` it was found missing, for the log); its first ping
        again is `first_s` from now."""
        entry = MissingServo(joint, self.ids[joint], self.port, self.reason_of(joint, err), now_s)
        log.error("%s%s; the other joints go on, it is pinged again with back-off", entry.describe(), how)
        self._entries = MappingProxyType({**self._entries, joint: entry})
        backoff = self._backoff.setdefault(entry.joint, Backoff(self.first_s, self.max_s))
        self._next_ping_s[entry.joint] = now_s + backoff.failed()
        self._failing_since.pop(entry.joint, None)

    def probe_all(self, joints: Sequence[str], probe: Callable[[str], None], now_s: float, name: str) -> None:
        """Ping each of `joints` (at open): record the silent ones (`probe` raised
        `ServoCommError`); raise when none answers. Other errors (the port, a servo of the
        wrong model) propagate."""
        self.reset()
        failures: dict[str, ServoCommError] = {}
        for joint in joints:
            try:
                probe(joint)
            except BusDownError:
                raise
            except ServoCommError as err:
                failures[joint] = err
        if failures and len(failures) == len(joints):
            first = next(iter(failures.values()))
            raise type(first)(f"{name}: no servo answered: " + "; ".join(map(str, failures.values())))
        for joint, failure in failures.items():
            self.add(joint, failure, now_s, " at open")

    def ping_due(self, now_s: float, attempt: Callable[[str], None]) -> list[MissingServo]:
        """`attempt` (ping and configure) each missing joint whose back-off has passed; the
        ones that answered, forgotten here, as they were recorded."""
        found = []
        for joint in self.due(now_s):
            try:
                attempt(joint)
            except BusDownError:
                raise
            except ServoError as err:
                self.ping_failed(joint, now_s, err)
                continue
            found.append(self.found(joint))
        return found

    def due(self, now_s: float) -> list[str]:
        """The missing joints whose next ping is due."""
        return [joint for joint in self._entries if now_s >= self._next_ping_s[joint]]

    def ping_failed(self, joint: str, now_s: float, err: BaseException) -> None:
        """A ping of a missing joint failed: the next one after the back-off."""
        delay_s = self._backoff[joint].failed()
        self._next_ping_s[joint] = now_s + delay_s
        entry, reason = self._entries[joint], self.reason_of(joint, err)
        log.debug("%s; next ping in %.2f s", entry.describe(), delay_s)
        if reason != entry.reason:
            self._entries = MappingProxyType({**self._entries, joint: MissingServo(
                entry.joint, entry.servo_id, entry.port, reason, entry.since_s)})

    def found(self, joint: str) -> MissingServo:
        """A missing joint answers again: forget it; returns what was recorded."""
        entry = self._entries[joint]
        self._entries = MappingProxyType({j: e for j, e in self._entries.items() if j != joint})
        self._backoff.pop(joint, None)
        self._next_ping_s.pop(joint, None)
        return entry

    def read_failed(self, blamed: Iterable[str], present: Iterable[str], now_s: float) -> list[str]:
        """A state read failed blaming `blamed`: the joints that have now failed alone, the
        other joints answering, for `drop_after_s` (to be recorded as missing). A read that
        blames every present joint (power, wiring, the adapter) or none drops nobody."""
        blamed, present = set(blamed), set(present)
        if not blamed or not blamed < present:
            self._failing_since.clear()
            return []
        for joint in set(self._failing_since) - blamed:
            del self._failing_since[joint]
        dropped = []
        for joint in sorted(blamed):
            since_s = self._failing_since.setdefault(joint, now_s)
            if now_s - since_s >= self.drop_after_s:
                dropped.append(joint)
        return dropped

    def read_ok(self) -> None:
        """A state read worked: no servo is failing."""
        self._failing_since.clear()
