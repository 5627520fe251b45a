"""The soak's faults: one table entry each (`FAULTS`), an injection, the soak's part in ending
it (none where the service must heal alone), how the status shows it and how to tell it healed.

A new fault of the service is one entry: its simulated fault's name (taken only when the
service's API schema offers it, else the fault is unsupported), or an action of its own.
"""
from __future__ import annotations

import os
import random
import signal
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Protocol

from headctl.api.client import ApiClient, ApiError

JOINTS = ("pan", "tilt", "left_eye", "right_eye")
SIDES = ("left", "right")


class Run(Protocol):
    """What a fault needs of the soak running it."""

    rng: random.Random
    offered: set[str]  # the simulated faults the service's API schema lists
    image_size: tuple[int, int]
    burst: int  # requests or looks in one burst

    @property
    def client(self) -> ApiClient: ...

    def servo_pid(self) -> int | None: ...

    def status(self) -> dict[str, Any] | None: ...


class Unsupported(Exception):
    """The service being measured does not offer this fault."""



@dataclass
class Episode:
    fault: str
    generation: int
    injected_s: float  # since the soak began
    injected_unix: float
    target: str = ""  # the joint, camera or pid it was given
    heal_from_s: float | None = None  # when healing was up to the service: after the soak's heal action
    reported_s: float | None = None
    healed_s: float | None = None
    unsupported: str = ""
    failures: list[str] = field(default_factory=list)
    log_bytes: int = 0  # the log's growth from the injection to the heal

    @property
    def time_to_heal_s(self) -> float | None:
        if self.healed_s is None or self.heal_from_s is None:
            return None
        return round(self.healed_s - self.heal_from_s, 3)



# --- the faults, and what they do -----------------------------------------------------------------------------------
Act = Callable[[Run, Episode], None]
Look = Callable[[Run, dict[str, Any], Episode], bool]


@dataclass(frozen=True)
class Fault:
    """One fault: `inject` (raises Unsupported), the soak's `heal` (None: the service heals alone),
    `seen` (the status shows it), `check` (healed beyond running with no fault listed)."""

    inject: Act
    heal: Act | None
    seen: Look
    hold_s: float = 3.0
    weight: float = 1.0
    check: Look = lambda soak, status, episode: True
    must_report: bool = True


def simulated(names: tuple[str, ...], target: str | None = None) -> Act:
    """Post the first of `names` the service offers as a simulated fault, with a joint or camera
    (`target`: "joint" or "camera", chosen at random and kept in the episode) or the episode's."""
    def act(soak: Run, episode: Episode) -> None:
        name = next((n for n in names if n in soak.offered), None)
        if name is None:
            raise Unsupported(f"none of {', '.join(names)} among the simulated faults offered "
                              f"({', '.join(sorted(soak.offered)) or 'none'})")
        body: dict[str, Any] = {"fault": name}
        if target is not None:
            episode.target = episode.target or soak.rng.choice(JOINTS if target == "joint" else SIDES)
            body[target] = episode.target
        try:
            soak.client.request("POST", "/api/v1/sim/faults", body)
        except ApiError as err:
            if err.status in (404, 422):
                raise Unsupported(f"{name}: {err}") from None
            raise
    return act


def mentions(*words: str) -> Look:
    """The status lists a fault, or an event since the injection, holding one of `words` (or the
    episode's target)."""
    def look(soak: Run, status: dict[str, Any], episode: Episode) -> bool:
        keys = [w.replace("{target}", episode.target) for w in words]
        texts = list(status.get("faults", []))
        texts += [e.get("message", "") for e in status.get("events", [])
                  if float(e.get("time", 0.0)) >= episode.injected_unix - 0.5]
        return any(k in text for k in keys for text in texts)
    return look


def hardware_episode(soak: Run, status: dict[str, Any], episode: Episode) -> bool:
    errors = status.get("hardware_errors", {})
    return any(e.get("joint") == episode.target and float(e.get("first_seen_unix", 0.0)) >= episode.injected_unix - 0.5
               for e in [*errors.get("open", []), *errors.get("ended", [])])


def no_open_hardware_episode(soak: Run, status: dict[str, Any], episode: Episode) -> bool:
    return not any(e.get("joint") == episode.target for e in status.get("hardware_errors", {}).get("open", []))


def kill_servo_process(soak: Run, episode: Episode) -> None:
    pid = soak.servo_pid()
    if pid is None:
        raise Unsupported("no servo process (service.servo_process: false?)")
    episode.target = str(pid)
    os.kill(pid, signal.SIGKILL)


def new_servo_process(soak: Run, status: dict[str, Any], episode: Episode) -> bool:
    pid = soak.servo_pid()
    return pid is not None and str(pid) != episode.target


def unanswered(err: ApiError) -> bool:
    """No answer, or an internal error; a refusal (4xx, 503: what is missing now) is an answer."""
    return err.status is None or err.status == 500


def api_burst(soak: Run, episode: Episode) -> None:
    """A burst of reads: status, learning, metrics, both eyes' frames, the event stream's backlog."""
    for i in range(soak.burst):
        path = soak.rng.choice(["/api/v1/state", "/api/v1/learning", "/metrics", "/api/v1/eyes/left.jpg",
                                "/api/v1/eyes/right.jpg", "events"])
        try:
            if path == "events":
                seq = int((soak.status() or {}).get("events_seq", 0))
                stream = soak.client.events(after=max(0, seq - 3), timeout_s=2.0)
                try:
                    next(stream, None)
                finally:
                    getattr(stream, "close", lambda: None)()  # the generator's close ends the connection
            else:
                soak.client.request("GET", path)
        except ApiError as err:
            if unanswered(err):
                episode.failures.append(f"GET {path}: {err}")
        except OSError as err:  # the event stream's own connection
            episode.failures.append(f"GET /api/v1/events: {err!r}")
        except ValueError:  # answered, with a frame or the metrics: not the JSON the client parses
            pass


def look_burst(soak: Run, episode: Episode) -> None:
    """Looks at random pixels, some replacing the one queued; refusals (429, 422) are answers."""
    width, height = soak.image_size
    for i in range(soak.burst):
        body = {"x": soak.rng.uniform(0, width - 1), "y": soak.rng.uniform(0, height - 1),
                "replace": soak.rng.random() < 0.3}
        try:
            soak.client.request("POST", "/api/v1/look/target", body)
        except ApiError as err:
            if unanswered(err):
                episode.failures.append(f"POST /api/v1/look/target: {err}")


FAULTS: dict[str, Fault] = {
    "bus_down": Fault(simulated(("bus_down",)), simulated(("restore_bus",)), mentions("servo bus down")),
    "hardware_error": Fault(simulated(("hardware_error",), "joint"), None, hardware_episode, hold_s=1.0,
                            check=no_open_hardware_episode),
    "camera_stall": Fault(simulated(("camera_stall",), "camera"), simulated(("camera_resume",), "camera"),
                          mentions("camera {target}"), hold_s=4.0),
    "servo_kill": Fault(kill_servo_process, None, mentions("servo process", "servo loop failed"), hold_s=1.0,
                        weight=0.5, check=new_servo_process),
    "camera_unplug": Fault(simulated(("camera_unplug",), "camera"), simulated(("camera_replug",), "camera"),
                           mentions("camera {target}"), hold_s=4.0),
    "brown_out": Fault(simulated(("power_loss",)), simulated(("power_back",)),
                       mentions("servo reads failing", "lost power"), hold_s=2.0),
    "servo_missing": Fault(simulated(("servo_remove", "remove_servo", "servo_missing"), "joint"),
                           simulated(("servo_add", "add_servo", "servo_back"), "joint"), mentions("{target}")),
    "state_dir_read_only": Fault(simulated(("state_dir_read_only", "state_dir_readonly", "state_dir_full")),
                                 simulated(("state_dir_writable", "state_dir_ok")), mentions("state", "checkpoint"),
                                 hold_s=10.0),
    "api_burst": Fault(api_burst, None, lambda soak, status, episode: True, hold_s=0.0, must_report=False),
    "look_burst": Fault(look_burst, None, lambda soak, status, episode: True, hold_s=0.0, must_report=False),
}
