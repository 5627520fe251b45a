"""The fault recovery policy of a servo bus: which servo reporting a hardware error is rebooted,
when, how often at most, and what is left to a person.

A Dynamixel servo latches its Hardware Error Status until it is rebooted; with its default
Shutdown setting, overload, overheating, encoder and electrical-shock errors also cut its
torque. The policy, applied by `ServoBus.read_state()` when `reboot_on_hardware_error` is on
(the default), and nowhere else:

- an error that cut the servo's torque: the servo is rebooted at once (which clears the error)
  and its torque restored at the position read back, so the joint does not jump;
- an error that left the torque on (input voltage, by default): rebooted once it has lasted
  `persist_s`, so that a passing reading does not drop the joint (on a bus not enabled the
  torque is off anyway: any error is rebooted at once);
- never a joint more often than once per `holdoff_s`: an error back sooner than that is
  reported, not rebooted (an overheating servo would otherwise reboot in a loop);
- at most `max_reboots` times per joint within `window_s`; after that the joint is left to a
  person: it stays faulted (the service holds it, or it has no torque), the log says so once,
  and only `ServoBus.reboot(joint)` or a power cycle brings it back.

With `reboot_on_hardware_error: false` nothing is rebooted automatically. Every automatic
reboot is counted by joint and reason (`reboots`); `given_up` lists the joints left to a person.
Both are replaced on each change, never changed in place, so another thread may take either
attribute and iterate it while the bus goes on. What the policy decided about each faulted
joint (`assess()`) is what the bus's fault log (`drivers.servo.faults`) records.
"""
from __future__ import annotations

import collections
import dataclasses
import logging
import math
from collections.abc import Mapping

from drivers.servo.faults import HELD_OFF, LEFT_TO_A_PERSON, REBOOTED, REBOOTING, REPORTED, WAITING

log = logging.getLogger(__name__)


@dataclasses.dataclass(frozen=True)
class RecoveryLimits:
    persist_s: float = 1.0  # an error that leaves torque on is rebooted once it lasted this long
    holdoff_s: float = 10.0  # at most one reboot of a joint per this long
    max_reboots: int = 3  # ... and at most this many within window_s; then left to a person
    window_s: float = 600.0


@dataclasses.dataclass(frozen=True)
class Fault:
    """One joint's hardware error as read: its meanings, and whether it cut the torque."""

    meanings: tuple[str, ...]
    torque_on: bool

    @property
    def reason(self) -> str:
        return ", ".join(self.meanings) or "hardware error"


class FaultRecovery:
    """Decides the reboots of the policy above; one per bus."""

    def __init__(self, limits: RecoveryLimits = RecoveryLimits()) -> None:
        self.limits = limits
        self.reboots: collections.Counter[tuple[str, str]] = collections.Counter()  # (joint, reason)
        self.given_up: frozenset[str] = frozenset()
        self._since: dict[str, float] = {}  # faulted joints, since when
        self._reboot_times: dict[str, collections.deque[float]] = collections.defaultdict(collections.deque)

    def explain(self, verdict: str) -> str:
        """What a verdict means for the joint, in the words of the fault log."""
        limits = self.limits
        return {
            REPORTED: "reported (automatic reboot is off: reboot it by hand)",
            WAITING: f"torque kept; rebooted if it lasts {limits.persist_s:g} s",
            HELD_OFF: f"back within {limits.holdoff_s:g} s of a reboot; reported, rebooted once that has passed",
            REBOOTING: "rebooting",
            REBOOTED: "rebooted, and the error is back",
            LEFT_TO_A_PERSON: f"{limits.max_reboots} automatic reboots within {limits.window_s:g} s; left to a "
                              "person (reboot it by hand once the cause is fixed)",
        }.get(verdict, verdict)

    def due(self, faults: Mapping[str, Fault], now_s: float) -> list[tuple[str, str]]:
        """The (joint, reason) pairs to reboot now, given the faults just read; each is counted."""
        return [(joint, faults[joint].reason) for joint, verdict in self.assess(faults, now_s).items()
                if verdict == REBOOTING]

    def assess(self, faults: Mapping[str, Fault], now_s: float) -> dict[str, str]:
        """What the policy decides for each joint of the faults just read: REBOOTING (counted
        as a reboot: the caller reboots it now), WAITING, HELD_OFF or LEFT_TO_A_PERSON
        (`drivers.servo.faults`)."""
        for joint in set(self._since) - set(faults):
            del self._since[joint]
        verdicts: dict[str, str] = {}
        for joint, fault in faults.items():
            since = self._since.setdefault(joint, now_s)
            if joint in self.given_up:
                verdicts[joint] = LEFT_TO_A_PERSON
            elif fault.torque_on and now_s - since < self.limits.persist_s:
                verdicts[joint] = WAITING
            else:
                verdicts[joint] = self._refusal(joint, fault, now_s) or REBOOTING
                if verdicts[joint] == REBOOTING:
                    self.note_reboot(joint, fault.reason, now_s)
        return verdicts

    def _refusal(self, joint: str, fault: Fault, now_s: float) -> str | None:
        """Why the joint may not be rebooted now (HELD_OFF, LEFT_TO_A_PERSON), or None."""
        times = self._reboot_times[joint]
        while times and now_s - times[0] > self.limits.window_s:
            times.popleft()
        if times and now_s - times[-1] < self.limits.holdoff_s:
            return HELD_OFF  # came back right after a reboot: reported, not rebooted again yet
        if len(times) >= self.limits.max_reboots:
            self.given_up = self.given_up | {joint}
            log.error("joint %s: %s again after %d automatic reboots within %.0f s; left to a person "
                      "(reboot it by hand once the cause is fixed)", joint, fault.reason, len(times),
                      self.limits.window_s)
            return LEFT_TO_A_PERSON
        return None

    def note_reboot(self, joint: str, reason: str, now_s: float) -> None:
        """Count a reboot (an automatic one, or one at enable)."""
        reboots = collections.Counter(self.reboots)
        reboots[(joint, reason)] += 1
        self.reboots = reboots
        self._reboot_times[joint].append(now_s)
        self._since.pop(joint, None)

    def rebooted_by_hand(self, joint: str) -> None:
        """A person rebooted the joint: automatic recovery applies to it again."""
        self.given_up = self.given_up - {joint}
        self._reboot_times[joint].clear()
        self._since.pop(joint, None)

    def last_reboot_s(self, joint: str) -> float:
        times = self._reboot_times.get(joint)
        return times[-1] if times else -math.inf
