"""Diagnostic: where a look's time goes, on the real-time daemon of `benchmarks.bench.looks_daemon`.

The looks of that benchmark (the same daemon, the same random pixels from a head near the
centre), with the fixation thread's time inside each of a look's parts summed per look: the
head coming to rest (`Head.wait_settled`: the saccade's and each vergence step's motion, and
the hold that says it is at rest), the stereo pairs waited for after it (`Head.wait_pair`:
a frame exposed after the rest, both cameras), the foveal match of fine vergence, the
fixation's correspondence and its stereo check, the target's patches judged in their own
view, and the target searches after each fixation. What is left of the look's own time
(`duration_s`) is the rest: goals sent, poses read, the map's commands.

Each rest the head came to is also split, as the head logs it at DEBUG, into the motion (until
the servos held still) and the hold that says they are at rest (`settle_s` at the goal, the
longer `short_settle_s` short of it), with how many rests were short of the goal.

Summarised over the looks on target, by how many corrective steps they took: each part's
median seconds a look, and the look time's.

    .venv/bin/python -m benchmarks.diag.look_time [--config configs/sim.yaml] [--state-dir DIR]
        [--explore-s 300] [--looks 60] [--spread 5] [--seed 0] [--json FILE]
"""
from __future__ import annotations

import collections
import contextlib
import logging
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any, Callable, Iterator

import numpy as np

import calib_free.gaze.fixation as fixation_module
import calib_free.gaze.look as look_module
from benchmarks.bench.looks_daemon import look_arguments, report, run_looks
from headctl.api.client import ApiClient
from headctl.api.compose import serve
from headctl.config.head import load_config
from headctl.service.head import Head

# (what owns it, its attribute, the part of a look it is)
PARTS: list[tuple[Any, str, str]] = [
    (Head, "wait_settled", "coming to rest"),
    (Head, "wait_pair", "waiting for a pair"),
    (fixation_module.FixationController, "foveal_offset", "vergence's foveal match"),
    (fixation_module, "match_fixation", "correspondence"),
    (fixation_module, "stereo_inconsistency", "stereo check"),
    (look_module, "identifying_patches", "patches judged in their own view"),
    (look_module, "find_first_sighting", "target searches"),
    (look_module, "find_later_sighting", "target searches"),
]
REST = "the rest"
FIXATION_THREAD = "fixation"
HEAD_LOGGER = "headctl.service.head"
AT_REST = "at rest after"  # how `Head.wait_settled` logs a rest: (seconds waited, still from, at goal or short of it, ...)


class RestLog(logging.Handler):
    """The rests the head logs on the fixation thread: (waited s, still from s, short of the goal)."""

    def __init__(self) -> None:
        super().__init__(logging.DEBUG)
        self._rests: list[tuple[float, float, bool]] = []
        self._guard = threading.Lock()

    def emit(self, record: logging.LogRecord) -> None:
        if threading.current_thread().name == FIXATION_THREAD and str(record.msg).startswith(AT_REST):
            waited, still, kind = record.args[:3]  # type: ignore[index]
            with self._guard:
                self._rests.append((float(waited), float(still), kind != "at goal"))
        if record.levelno >= logging.INFO:  # what the logger would have passed on
            for handler in logging.getLogger().handlers:
                if record.levelno >= handler.level:
                    handler.handle(record)

    def take(self) -> dict[str, float]:
        """The rests since the last take: how many, how many short of the goal, and the seconds
        of motion and of hold summed."""
        with self._guard:
            rests, self._rests = self._rests, []
        return {"rests": len(rests), "short of goal": sum(short for _, _, short in rests),
                "motion_s": round(sum(still for _, still, _ in rests), 4),
                "hold_s": round(sum(waited - still for waited, still, _ in rests), 4)}

    @contextlib.contextmanager
    def installed(self) -> Iterator["RestLog"]:
        """Listening to the head's logger at DEBUG (passing on what it logs at INFO and above), for the block."""
        logger = logging.getLogger(HEAD_LOGGER)
        level, propagate = logger.level, logger.propagate
        logger.addHandler(self)
        logger.setLevel(logging.DEBUG)
        logger.propagate = False
        try:
            yield self
        finally:
            logger.removeHandler(self)
            logger.setLevel(level)
            logger.propagate = propagate


class PartTimer:
    """Sums, per part, the fixation thread's wall time inside the `PARTS` since `start`."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._spent: collections.Counter[str] = collections.Counter()

    def start(self) -> None:
        with self._lock:
            self._spent = collections.Counter()

    def take(self) -> dict[str, float]:
        with self._lock:
            spent, self._spent = self._spent, collections.Counter()
        return dict(spent)

    def _timed(self, function: Callable[..., Any], part: str) -> Callable[..., Any]:
        timer = self

        def timed(*args: Any, **kwargs: Any) -> Any:
            if threading.current_thread().name != FIXATION_THREAD:
                return function(*args, **kwargs)
            started = time.perf_counter()
            try:
                return function(*args, **kwargs)
            finally:
                with timer._lock:
                    timer._spent[part] += time.perf_counter() - started
        return timed

    @contextlib.contextmanager
    def installed(self) -> Iterator["PartTimer"]:
        """Each of `PARTS` wrapped to be timed, for the block."""
        originals = [(owner, name, getattr(owner, name)) for owner, name, _ in PARTS]
        for (owner, name, part), (_, _, original) in zip(PARTS, originals):
            setattr(owner, name, self._timed(original, part))
        try:
            yield self
        finally:
            for owner, name, original in originals:
                setattr(owner, name, original)


def summary(looks: list[dict[str, Any]]) -> dict[str, Any]:
    """Over the looks on target, by corrective steps taken: how many, and each part's median
    seconds a look (with `REST`, the look's time not in any part, and `duration_s`)."""
    groups: dict[str, list[dict[str, Any]]] = collections.defaultdict(list)
    for lk in looks:
        if lk.get("on_target") and lk.get("duration_s") is not None:
            steps = lk["corrective_steps"]
            groups[str(steps) if steps < 2 else "2+"].append(lk)
    parts = list(dict.fromkeys(part for _, _, part in PARTS))
    out: dict[str, Any] = {}
    for key in sorted(groups):
        rows = groups[key]

        def median(values: list[float]) -> float:
            return round(float(np.median(values)), 4)

        out[f"corrective steps {key}"] = {
            "looks": len(rows), "duration_s": median([r["duration_s"] for r in rows]),
            **{part: median([r["parts_s"].get(part, 0.0) for r in rows]) for part in parts},
            REST: median([r["duration_s"] - sum(r["parts_s"].values()) for r in rows]),
            **{f"rests: {key}": median([r["rests"][key] for r in rows])
               for key in ("rests", "short of goal", "motion_s", "hold_s") if all("rests" in r for r in rows)}}
    return out


def main() -> int:
    parser = look_arguments(__doc__)
    parser.add_argument("--state-dir", type=Path, help="the daemon's state (its map) kept here (default: temporary)")
    args = parser.parse_args()
    rng = np.random.default_rng(args.seed)
    with contextlib.ExitStack() as stack:
        state = args.state_dir or Path(stack.enter_context(tempfile.TemporaryDirectory(prefix="diag-look-time-")))
        config = load_config(args.config).with_state_dir(state).with_api(port=0)
        timer = stack.enter_context(PartTimer().installed())
        rests = stack.enter_context(RestLog().installed())
        daemon = stack.enter_context(serve(config))
        client = ApiClient(daemon.api_url)
        world = daemon.parts.devices.world
        lens = daemon.parts.devices.cameras["left"].unit_lens
        time.sleep(args.explore_s)
        client.set_exploration(False)
        done: list[int] = []

        def before_post(before: dict[str, float], xy: tuple[float, float]) -> None:
            timer.start()
            rests.take()

        def with_parts(row: dict[str, Any]) -> dict[str, Any]:
            done.append(1)
            print(f"look {len(done)}/{args.looks}: {row['state']}, {row['outcome']}", file=sys.stderr, flush=True)
            return {**row, "parts_s": {part: round(s, 4) for part, s in timer.take().items()}, "rests": rests.take()}

        looks = run_looks(client, config, world, lens, rng, args.spread, args.looks,
                          before_post=before_post, after_look=with_parts)
    report(summary(looks), {"looks": looks}, args.json)
    return 0


if __name__ == "__main__":
    sys.exit(main())
