"""The one restart policy of the service: which parts are restarted, how soon, and when the
service gives up and leaves it to systemd.

Every part that can die (the servo process, the fixation thread, the adapter thread, the
front end, a camera's stream) is a `Restartable`: it says whether it is alive, why not, and
restarts itself. `Restarts` watches them on the supervisor's rounds (`tick`), on the
service's monotonic clock:

- a part found dead is restarted after a back-off: `service.restart_backoff_s` for its first
  failure, doubling with each failure that follows within `service.restart_backoff_max_s` of
  its last restart, to at most `service.restart_backoff_max_s`; a part that ran that long
  since its last restart starts from the first back-off again;
- a restart that raises is one more failure, retried after the next back-off;
- every failure of a part that counts (`Restartable.counts`) goes into one window shared by
  all of them: more than `service.restart_limit` failures within `service.restart_window_s`
  and the service gives up (`gave_up`, the reason in `give_up_reason`); the supervisor then
  stops petting systemd's watchdog and the daemon exits with `EXIT_GAVE_UP`, so that systemd
  restarts the whole unit (its own rate limit then applies).

A camera's stream does not count: a camera unplugged is a fault the service outlives (it
stays `degraded` and reconnects when the camera is back), and a new unit could not bring the
camera back sooner.
"""
from __future__ import annotations

import collections
import dataclasses
import logging
from collections.abc import Callable, Iterable, Mapping
from typing import Protocol

from drivers.clock import Clock
from headctl.config.head import ServiceConfig

log = logging.getLogger(__name__)

EXIT_GAVE_UP = 3  # `headctl run`'s exit code once the service gave up (1: a device missing at start)


class Restartable(Protocol):
    """A part of the service that can die and be started again."""

    @property
    def name(self) -> str: ...

    @property
    def counts(self) -> bool:
        """Whether its failures count toward giving up."""

    def failure(self) -> str | None:
        """Why it is not running (it died, or its restart failed), None while it runs."""

    def restart(self) -> Mapping[str, object]:
        """Start it again; what changed, for the log and the event (e.g. the old and new process
        ids). Raises when it could not be started."""


@dataclasses.dataclass(frozen=True)
class RestartSettings:
    """The `service.restart_*` keys (`headctl.config.head.ServiceConfig`)."""

    limit: int
    window_s: float
    backoff_s: float
    backoff_max_s: float

    @classmethod
    def of(cls, service: ServiceConfig) -> "RestartSettings":
        return cls(service.restart_limit, service.restart_window_s, service.restart_backoff_s,
                   service.restart_backoff_max_s)


@dataclasses.dataclass
class _PartState:
    delay_s: float = 0.0  # the back-off of its last failure (0: none yet)
    due_s: float | None = None  # a restart is due at this time (None: the part runs)
    cause: str = ""
    restarted_s: float = -float("inf")
    restarts: int = 0


@dataclasses.dataclass(frozen=True)
class RestartRecord:
    """One restart done, as events and metrics tell it."""

    part: str
    cause: str
    detail: Mapping[str, object]
    restarts: int


class Restarts:
    """Watches `parts` and restarts the dead ones under one policy; see the module docstring.
    `on_restart` hears of every restart done (the event, the metric)."""

    def __init__(self, settings: RestartSettings, clock: Clock,
                 on_restart: Callable[[RestartRecord], None] | None = None) -> None:
        self.settings = settings
        self.clock = clock
        self.on_restart = on_restart
        self._parts: dict[str, Restartable] = {}
        self._state: dict[str, _PartState] = {}
        self._failures: collections.deque[tuple[float, str]] = collections.deque()  # (time, part) in the window
        self.give_up_reason: str | None = None

    def watch(self, parts: Iterable[Restartable]) -> None:
        for part in parts:
            self._parts[part.name] = part
            self._state.setdefault(part.name, _PartState())

    @property
    def gave_up(self) -> bool:
        return self.give_up_reason is not None

    def restarts(self) -> dict[str, int]:
        """Restarts done so far, by part."""
        return {name: state.restarts for name, state in self._state.items()}

    def pending(self, name: str) -> bool:
        """Whether the part `name` is down and its restart is scheduled (the service has not given up)."""
        state = self._state.get(name)
        return state is not None and state.due_s is not None and not self.gave_up

    def tick(self) -> None:
        """One round: note the parts that died, restart those whose back-off has passed."""
        if self.gave_up:
            return
        for name, part in self._parts.items():
            state = self._state[name]
            now = self.clock.monotonic()
            if state.due_s is None:
                cause = part.failure()
                if cause is None:
                    continue
                self._failed(part, state, cause, now)
            if self.gave_up:
                return
            if state.due_s is not None and now >= state.due_s:
                self._restart(part, state)
                if self.gave_up:
                    return

    def _failed(self, part: Restartable, state: _PartState, cause: str, now: float,
                retry: bool = False) -> None:
        s = self.settings
        again = retry or now - state.restarted_s < s.backoff_max_s  # a failed restart, or died soon after one
        state.delay_s = min(s.backoff_max_s, state.delay_s * 2.0) if again and state.delay_s else s.backoff_s
        state.due_s = now + state.delay_s
        state.cause = cause
        if part.counts:
            self._failures.append((now, part.name))
            while self._failures and now - self._failures[0][0] > s.window_s:
                self._failures.popleft()
            if len(self._failures) > s.limit:
                names = ", ".join(sorted({name for _, name in self._failures}))
                self.give_up_reason = (f"{len(self._failures)} failures within {s.window_s:g} s "
                                       f"(service.restart_limit: {s.limit}; {names}); last: {part.name}: {cause}")
                log.critical("giving up: %s; exiting so that systemd restarts the service", self.give_up_reason)
                return
        log.error("%s failed: %s; restarting it in %.1f s", part.name, cause, state.delay_s)

    def _restart(self, part: Restartable, state: _PartState) -> None:
        try:
            detail = part.restart()
        except Exception as err:  # the restart failed: one more failure, retried after the next back-off
            state.due_s = None
            self._failed(part, state, f"restart failed: {err}", self.clock.monotonic(), retry=True)
            return
        state.due_s = None
        state.restarted_s = self.clock.monotonic()
        state.restarts += 1
        log.warning("%s restarted (restart %d; it failed: %s): %s", part.name, state.restarts, state.cause,
                    ", ".join(f"{k} {v}" for k, v in detail.items()))
        if self.on_restart is not None:
            self.on_restart(RestartRecord(part.name, state.cause, detail, state.restarts))
