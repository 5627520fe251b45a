"""The servos' hardware errors as the service tells them: events, reboot counters, the status.

The bus records every hardware-error episode in its fault log (`drivers.servo.faults`), also one
that its recovery policy rebooted away inside a single read. `HardwareFaults` is fed the new
records (`add`), wherever the bus runs (a thread of the service, or the servo process), and
turns them into:
- events: `fault` when an episode is first seen, `fault_update` when recovery does something
  about it (rebooting, rebooted, waiting, left to a person), `fault_cleared` when it is gone;
- counters: automatic reboots by joint and reason (`headctl_servo_reboots_total`);
- the status: the episodes open now and the last ones that ended.
"""
from __future__ import annotations

import collections
import threading
from collections.abc import Iterable

from drivers.servo.faults import CLEARED, REBOOTED, RECOVERY_CHANGED, SEEN, HardwareErrorEpisode
from headctl.json_types import JSONObject
from headctl.service.events import EventHub


class HardwareFaults:
    def __init__(self, hub: EventHub, keep_ended: int = 20) -> None:
        self.hub = hub
        self.cursor = 0  # the last record's seq taken from the bus's log
        self._open: dict[int, HardwareErrorEpisode] = {}
        self._ended: collections.deque[HardwareErrorEpisode] = collections.deque(maxlen=keep_ended)
        self._reboots: collections.Counter[tuple[str, str]] = collections.Counter()
        self._lock = threading.Lock()

    def add(self, records: Iterable[HardwareErrorEpisode]) -> None:
        """Take the records after `cursor`, in order (each is told once)."""
        with self._lock:
            for record in records:
                if record.seq <= self.cursor:
                    continue
                self.cursor = record.seq
                self._take(record)

    def _take(self, record: HardwareErrorEpisode) -> None:
        fields = {"key": record.key, "joint": record.joint, "servo_id": record.servo_id, "bits": record.bits,
                  "meanings": list(record.meanings), "recovery": record.recovery, "message": record.detail}
        if record.change == CLEARED:
            self._open.pop(record.episode, None)
            self._ended.append(record)
            self.hub.publish("fault_cleared", **fields, cleared_by=record.cleared_by)
            return
        self._open[record.episode] = record
        if record.change == SEEN:
            self.hub.publish("fault", **fields)
        else:
            self.hub.publish("fault_update", **fields)
        if record.change == RECOVERY_CHANGED and record.recovery == REBOOTED:
            self._reboots[(record.joint, ", ".join(record.meanings) or "hardware error")] += 1

    def reboots(self) -> dict[tuple[str, str], int]:
        """Automatic reboots so far, by (joint, reason)."""
        with self._lock:
            return dict(self._reboots)

    def status(self) -> JSONObject:
        with self._lock:
            return {"open": [r.as_dict() for r in self._open.values()],
                    "ended": [r.as_dict() for r in self._ended],
                    "reboots": [{"joint": j, "reason": reason, "count": n}
                                for (j, reason), n in sorted(self._reboots.items())]}
