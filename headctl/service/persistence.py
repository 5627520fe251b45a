"""What the service keeps on disk: the gaze map (restored at start, checkpointed atomically),
the lens's magnification the looks learned, and the lock that allows one daemon per state
directory.

No map file can keep the service from starting: `restore_map` takes the main file, else its
`.prev`, else a fresh random map, and reports what it refused. `Checkpointer` saves a map
that changed every `checkpoint_every` adaptations or `checkpoint_interval_s` seconds,
whichever comes first, so a daemon killed often loses little. A state directory that is full
or read-only makes checkpoints fail (a fault naming the directory and the errno) while the
service goes on learning; the last good checkpoint stays as it was, and checkpoints resume by
themselves once the directory takes writes again.
"""
from __future__ import annotations

import errno
import fcntl
import json
import logging
import os
import threading
import time
from collections.abc import Callable
from pathlib import Path

from calib_free.map.gaze_map import GazeMap
from calib_free.map.adapter import MapAdapter
from calib_free.errors import MapFileError
from calib_free.gaze.magnification import LearnedMagnification, MagnificationFileError
from calib_free.map.file import read_map, temporary_files, write_map
from drivers.clock import SYSTEM_CLOCK, Clock
from headctl.config.head import HeadConfig
from headctl.errors import HeadctlError

log = logging.getLogger(__name__)


def remove_temporary_files(state_dir: Path) -> list[Path]:
    """Remove the temporary files of saves a killed process left in `state_dir`; those removed.
    Called at start with the state directory locked, when no save of this directory runs."""
    removed = []
    for leftover in temporary_files(state_dir):
        try:
            size = leftover.stat().st_size
            leftover.unlink()
        except OSError as err:
            log.error("%s: cannot remove this temporary file of an interrupted save: %s", leftover, err)
            continue
        log.warning("removed %s (%d bytes), the temporary file of an interrupted save", leftover, size)
        removed.append(leftover)
    return removed


def restore_map(config: HeadConfig) -> tuple[GazeMap, str, list[str]]:
    """The saved map (or its .prev, or a fresh random one); where it came from; problems found.

    Leftover temporary files of interrupted saves are removed first. A file that cannot be
    used (corrupt, malformed, saved for other map parameters) is reported and moved aside to
    `<file>.bad`, so that no checkpoint keeps it as `.prev`; when `.prev` is used, it is
    written back as the main file. Never raises for what a file holds.
    """
    path = config.map_path
    wanted = config.map_params()
    problems: list[str] = []
    remove_temporary_files(config.state_dir)
    main_refused = False
    for candidate in (path, Path(f"{path}.prev")):
        if not os.path.lexists(candidate):
            continue
        try:
            gm = read_map(candidate)
            if gm.params != wanted:
                raise MapFileError(f"{candidate}: saved for other map parameters (image size {gm.params.image_size}, "
                                   f"grid {gm.params.grid_shape}, profile {gm.params.profile}) than {config.path} sets")
        except Exception as err:  # MapFileError only, by read_map's contract; anything else is still a bad file
            problem = str(err) if isinstance(err, MapFileError) else \
                f"{candidate}: not a readable gaze map file ({type(err).__name__}: {err})"
            log.error("gaze map: %s", problem, exc_info=not isinstance(err, MapFileError))
            problems.append(problem)
            _move_aside(candidate)
            main_refused = main_refused or candidate == path
            continue
        log.info("gaze map restored from %s (%d adaptations)", candidate, gm.adaptations)
        if main_refused:
            try:
                write_map(gm, path, keep_previous=False)
            except OSError as err:
                problems.append(f"{path}: cannot write the restored map back: {err}")
                log.error("gaze map: %s", problems[-1])
        return gm, str(candidate), problems
    log.info("gaze map: none usable in %s; starting from a random map (seed %d)", config.state_dir,
             config.gaze_map.seed)
    return GazeMap(wanted, seed=config.gaze_map.seed), "new", problems


def _move_aside(path: Path) -> None:
    try:
        os.replace(path, f"{path}.bad")
    except OSError as err:
        log.error("%s: cannot move it aside to %s.bad: %s", path, path, err)


class Checkpointer:
    """Atomic checkpoints of the adapter's map: when it changed, every `every` adaptations or
    every `interval_s` seconds (0: by count only), whichever comes first; and on request
    (`save`: at shutdown, from the API).

    `maybe()` runs on the adapter thread after each adaptation; `maybe_on_time()` is for a
    thread that runs whether or not adaptations come (the supervisor). Both skip a checkpoint
    while one is being written, and both count from the last attempt, so a failing disk is
    retried at the same pace and not after every adaptation. A failed save leaves the files as
    they were (`calib_free.map.file.write_map` is atomic), so the last good checkpoint is never
    lost; `error` names the directory and the errno until a save succeeds again. `writer` writes
    one map file (tests give one that fails as a full or read-only disk does).
    """

    def __init__(self, adapter: MapAdapter, path: Path, every: int, clock: Clock = SYSTEM_CLOCK,
                 interval_s: float = 30.0, writer: Callable[[GazeMap, Path], None] = write_map) -> None:
        self.adapter = adapter
        self.writer = writer
        self.failures = 0  # failed attempts since the last good checkpoint
        self.clock = clock
        self.path = path
        self.every = every
        self.interval_s = interval_s
        self.count = 0
        self.last_adaptations = -1
        self.last_time_s: float | None = None
        self.last_duration_s: float | None = None
        self.error: str | None = None
        self._lock = threading.Lock()
        # The map as the state directory holds it (the restored one at start), and the last attempt.
        self._saved: tuple[GazeMap, int] = (adapter.map, adapter.map.adaptations)
        self._attempt: tuple[GazeMap, int, float] = (adapter.map, adapter.map.adaptations, clock.monotonic())

    def changed(self) -> bool:
        """The adapter's map differs from the last one saved (adapted since, or replaced)."""
        saved_map, saved_adaptations = self._saved
        gm = self.adapter.map
        return gm is not saved_map or gm.adaptations != saved_adaptations

    def due(self, now_s: float | None = None) -> bool:
        """A checkpoint is due: the map changed, and `every` adaptations or `interval_s` seconds
        have passed since the last attempt (`now_s` on this checkpointer's clock)."""
        if not self.changed():
            return False
        now_s = self.clock.monotonic() if now_s is None else now_s
        attempt_map, attempt_adaptations, attempt_s = self._attempt
        gm = self.adapter.map
        since = gm.adaptations - attempt_adaptations if gm is attempt_map else gm.adaptations
        return since >= self.every or (self.interval_s > 0 and now_s - attempt_s >= self.interval_s)

    def maybe(self, adaptations: int | None = None) -> bool:
        """After an adaptation (on the adapter thread): checkpoint if one is due. True if saved.
        `adaptations` is accepted for the caller's convenience; the count is read from the adapter."""
        return self._save_if_due(None)

    def maybe_on_time(self, now_s: float | None = None) -> bool:
        """Checkpoint if one is due, whether or not adaptations come (call it every second or
        so). True if saved."""
        return self._save_if_due(now_s)

    def _save_if_due(self, now_s: float | None) -> bool:
        if not self.due(now_s) or not self._lock.acquire(blocking=False):
            return False
        try:
            if not self.due(now_s):  # another thread saved it meanwhile
                return False
            return self._save()
        finally:
            self._lock.release()

    def save(self) -> None:
        """Checkpoint now, changed or not (at shutdown, on request); failures land in `error`."""
        with self._lock:
            self._save()

    def _save(self) -> bool:
        started = self.clock.monotonic()
        try:
            gm, adaptations = self.adapter.with_map(self._save_map)
        except OSError as err:
            self._attempt = (self.adapter.map, self.adapter.map.adaptations, started)
            self.failures += 1
            self.error = self._failure(err)
            log.error("%s", self.error)
            return False
        if self.failures:
            log.warning("gaze map: checkpoints resume in %s after %d failed attempt(s)", self.path.parent,
                        self.failures)
            self.failures = 0
        self._saved = (gm, adaptations)
        self._attempt = (gm, adaptations, started)
        self.error = None
        self.count += 1
        self.last_adaptations = adaptations
        self.last_time_s = time.time()  # wall clock: when, for people; durations use self.clock
        self.last_duration_s = self.clock.monotonic() - started
        log.info("gaze map checkpoint %d: %s (%d adaptations, %.0f ms)", self.count, self.path,
                 adaptations, self.last_duration_s * 1e3)
        return True

    def _save_map(self, gm: GazeMap) -> tuple[GazeMap, int]:
        self.writer(gm, self.path)
        return gm, gm.adaptations

    def _failure(self, err: OSError) -> str:
        """What a failed checkpoint tells: the directory, the errno and what is kept."""
        code = errno.errorcode.get(err.errno, str(err.errno)) if err.errno is not None else type(err).__name__
        kept = (f"the last good checkpoint ({self._saved[1]} adaptations) is kept" if self.count or
                os.path.lexists(self.path) else "no checkpoint saved yet")
        return (f"state directory {self.path.parent}: checkpoint of {self.path.name} failed: {code} "
                f"({err.strerror or err}); {kept}; retried every {self.every} adaptations"
                + (f" or {self.interval_s:g} s" if self.interval_s > 0 else ""))


def restore_magnification(path: Path) -> tuple[LearnedMagnification, list[str]]:
    """The lens's magnification as the looks learned it, saved in `path`; an empty profile
    when there is none, or when the file cannot be used (moved aside to `<file>.bad` and
    reported: the looks learn it again, searching every scale until they have). Never raises
    for what the file holds."""
    if not os.path.lexists(path):
        return LearnedMagnification(), []
    try:
        profile = LearnedMagnification.from_dict(json.loads(path.read_text(encoding="utf-8")), str(path))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError, MagnificationFileError) as err:
        problem = str(err) if isinstance(err, MagnificationFileError) else f"{path}: not readable: {err}"
        log.error("lens magnification: %s; the looks learn it again", problem)
        _move_aside(path)
        return LearnedMagnification(), [problem]
    log.info("lens magnification restored from %s", path)
    return profile, []


class MagnificationFile:
    """Saves the looks' lens magnification to `path` when it changed (`maybe_save`, from the
    supervisor's round, about once a second: a kill loses at most that) and on request (`save`,
    at shutdown). A save that fails is logged once until one succeeds again, and retried at the
    next round; the file is replaced atomically, so the last good one stays."""

    def __init__(self, path: Path, profile: LearnedMagnification) -> None:
        self.path = path
        self.profile = profile
        self.error: str | None = None
        self._saved_revision = profile.revision
        self._lock = threading.Lock()

    def maybe_save(self) -> bool:
        """Save if the profile changed since the last save. True if saved."""
        if self.profile.revision == self._saved_revision:
            return False
        return self.save()

    def save(self) -> bool:
        with self._lock:
            revision = self.profile.revision
            try:
                write_atomically(self.path, json.dumps(self.profile.as_dict()) + "\n")
            except OSError as err:
                problem = f"{self.path}: cannot save the lens magnification: {err}"
                if problem != self.error:
                    log.error("%s", problem)
                self.error = problem
                return False
            if self.error is not None:
                log.warning("%s: the lens magnification is saved again", self.path)
            self.error = None
            self._saved_revision = revision
            return True


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
