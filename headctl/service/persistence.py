"""What the service keeps on disk: the gaze map (restored at start, checkpointed atomically)
and the lock that allows one daemon per state directory."""
from __future__ import annotations

import fcntl
import logging
import os
import threading
import time
from pathlib import Path

from calib_free import GazeMap
from calib_free.adapter import MapAdapter
from calib_free.errors import MapFileError
from drivers.clock import SYSTEM_CLOCK, Clock
from headctl.config import HeadConfig
from headctl.errors import HeadctlError

log = logging.getLogger(__name__)


def restore_map(config: HeadConfig) -> tuple[GazeMap, str, list[str]]:
    """The saved map (or its .prev, or a fresh random one); where it came from; problems found.

    A corrupt or incompatible main file is moved aside to `<path>.bad` so the next checkpoint
    does not keep it as `.prev`.
    """
    path = config.map_path
    wanted = config.map_params()
    problems: list[str] = []
    moved_aside = False
    for candidate in (path, Path(f"{path}.prev")):
        if not candidate.exists():
            continue
        try:
            gm = GazeMap.load(candidate)
            if gm.params != wanted:
                raise MapFileError(f"{candidate}: saved for other map parameters (image size {gm.params.image_size}, "
                                   f"grid {gm.params.grid_shape}, profile {gm.params.profile}) than {config.path} sets")
        except MapFileError as err:
            log.error("gaze map: %s", err)
            problems.append(str(err))
            if candidate == path:
                os.replace(path, f"{path}.bad")
                moved_aside = True
            continue
        log.info("gaze map restored from %s (%d adaptations)", candidate, gm.adaptations)
        if moved_aside:
            gm.save(path, keep_previous=False)
        return gm, str(candidate), problems
    log.info("gaze map: none saved in %s; starting from a random map (seed %d)", config.state_dir,
             config.gaze_map.seed)
    return GazeMap(wanted, seed=config.gaze_map.seed), "new", problems


class Checkpointer:
    """Atomic map checkpoints every N adaptations (on the adapter thread) and at shutdown."""

    def __init__(self, adapter: MapAdapter, path: Path, every: int, clock: Clock = SYSTEM_CLOCK) -> None:
        self.adapter = adapter
        self.clock = clock
        self.path = path
        self.every = every
        self.count = 0
        self.last_adaptations = -1
        self.last_time_s: float | None = None
        self.last_duration_s: float | None = None
        self.error: str | None = None
        self._lock = threading.Lock()

    def maybe(self, adaptations: int) -> None:
        if adaptations > 0 and adaptations % self.every == 0:
            self.save()

    def save(self) -> None:
        with self._lock:
            started = self.clock.monotonic()
            try:
                adaptations = self.adapter.with_map(self._save_map)
            except OSError as err:
                self.error = f"{self.path}: checkpoint failed: {err}"
                log.error("%s", self.error)
                return
            self.error = None
            self.count += 1
            self.last_adaptations = int(adaptations)
            self.last_time_s = time.time()
            self.last_duration_s = self.clock.monotonic() - started
            log.info("gaze map checkpoint %d: %s (%d adaptations, %.0f ms)", self.count, self.path,
                     adaptations, self.last_duration_s * 1e3)

    def _save_map(self, gm: GazeMap) -> int:
        gm.save(self.path)
        return gm.adaptations


def write_atomically(path: Path, text: str) -> None:
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_text(text, encoding="utf-8")
    os.replace(tmp, path)


class StateDirLock:
    """One daemon per state directory: an exclusive flock(2) on `headctl.lock`, released by the
    kernel however the process ends (a kill -9 leaves no stale lock)."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self._fd: int | None = None

    def __enter__(self) -> "StateDirLock":
        fd = os.open(self.path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = os.read(fd, 32).decode(errors="replace").strip() or "?"
            os.close(fd)
            raise HeadctlError(f"{self.path.parent}: another headctl daemon (pid {holder}) is running with "
                               "this state directory") from None
        os.ftruncate(fd, 0)
        os.write(fd, f"{os.getpid()}\n".encode())
        self._fd = fd
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        if self._fd is not None:
            os.close(self._fd)
            self._fd = None
