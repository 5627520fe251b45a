"""Diagnostic: every step of the looks of `benchmarks.bench.looks_daemon`, against the truth.

The looks of the real-time daemon benchmark (the same daemon, the same random pixels from a
head near the centre), with each of a look's fixations recorded as it ends, on the fixation
thread: its aim (x, y, d), outcome and its detail, whether the eyes converged and in how
many vergence steps, the pose before and after, and the truth, the distance from the left
fovea of the world point the pixel showed before the look, projected at the servos' true
position then; and after each fixation the target search's answer (the patch's distance from
the fovea, or why it was not found). Summarised: how far the first saccade truly left the
target in the looks that failed, the outcomes of the looks' fixations, and how far the
vergence moved in the corrective steps (each degree of vergence turns the left eye half a
degree, which moves the target on the left fovea: about 2 px a degree of vergence at the
fovea).

`--state-dir` keeps the daemon's map between runs (a map explored before, explored further
for `--explore-s`); without it the daemon starts from a random map in a temporary directory.

    .venv/bin/python -m benchmarks.diag.look_steps [--config configs/sim.yaml] [--state-dir DIR]
        [--explore-s 300] [--looks 60] [--spread 5] [--seed 0] [--json FILE]
"""
from __future__ import annotations

import collections
import contextlib
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any, Iterator

import numpy as np

import calib_free.gaze.look as look_module
from benchmarks.bench.looks import world_error_px
from benchmarks.bench.looks_daemon import look_arguments, report, run_looks
from headctl.api.client import ApiClient
from headctl.api.compose import serve
from headctl.config.head import load_config


class StepRecorder:
    """Records the steps of the look running; `look_posted` starts a look's record."""

    def __init__(self, world: Any, lens: Any) -> None:
        self.world, self.lens = world, lens
        self.steps: list[dict[str, Any]] = []
        self._lock = threading.Lock()
        self._before: dict[str, float] | None = None
        self._xy: tuple[float, float] | None = None

    def look_posted(self, before: dict[str, float], xy: tuple[float, float]) -> None:
        with self._lock:
            self.steps, self._before, self._xy = [], before, xy

    def take(self) -> list[dict[str, Any]]:
        with self._lock:
            steps, self.steps = self.steps, []
            return steps

    def _truth_px(self) -> float | None:
        if self._before is None or self._xy is None:
            return None
        error, hidden = world_error_px(self.world.model, self.world.scene, self.lens, self._before,
                                       self.world.true_joints(), self._xy)
        return None if error is None or hidden else round(float(error), 2)

    @contextlib.contextmanager
    def installed(self) -> Iterator["StepRecorder"]:
        """The look module's target search and fixations wrapped to record, for the block."""
        find_target, fixate = look_module.find_target, look_module.LookController._fixate
        recorder = self

        def recorded_find(source, source_xy, image, *args, **kwargs):  # type: ignore[no-untyped-def]
            sighting, why = find_target(source, source_xy, image, *args, **kwargs)
            h, w = image.shape[:2]
            with recorder._lock:
                recorder.steps.append({"search": None if sighting is None else round(float(np.hypot(
                    sighting.x - (w - 1) / 2.0, sighting.y - (h - 1) / 2.0)), 2), "why": why})
            return sighting, why

        def recorded_fixate(controller, record, target, reference_pose=None, continues=False):  # type: ignore[no-untyped-def]
            fixation = fixate(controller, record, target, reference_pose, continues)

            def pose(p: Any) -> list[float] | None:
                return None if p is None else [round(float(v), 3) for v in p]

            with recorder._lock:
                recorder.steps.append({
                    "aim": [round(float(v), 2) for v in target], "outcome": str(fixation.outcome),
                    "detail": fixation.detail,
                    "converged": fixation.converged, "vergence_steps": fixation.vergence_steps,
                    "pose_before": pose(fixation.pose_before), "pose_after": pose(fixation.pose_after),
                    "true_error_px": recorder._truth_px()})
            return fixation

        look_module.find_target = recorded_find
        look_module.LookController._fixate = recorded_fixate  # type: ignore[method-assign]
        try:
            yield self
        finally:
            look_module.find_target = find_target
            look_module.LookController._fixate = fixate  # type: ignore[method-assign]


def summary(looks: list[dict[str, Any]]) -> dict[str, Any]:
    taken = [lk for lk in looks if lk["state"] != "refused"]
    failed = [lk for lk in taken if not lk["on_target"]]
    first_truth = collections.Counter()
    for lk in failed:
        fixations = [s for s in lk["steps"] if "aim" in s]
        truth = fixations[0]["true_error_px"] if fixations else None
        first_truth["unknown" if truth is None else "<= 1 px" if truth <= 1 else "1-2 px" if truth <= 2
                    else "> 2 px"] += 1
    outcomes = collections.Counter(s["outcome"] for lk in taken for s in lk["steps"] if "aim" in s)
    turned = [abs(s["pose_after"][2] - s["pose_before"][2]) for lk in taken
              for s in [s for s in lk["steps"] if "aim" in s][1:] if s["pose_after"] and s["pose_before"]]
    return {"looks": len(looks), "taken_on": len(taken), "on_target": len(taken) - len(failed),
            "failed_by_first_saccade_true_error": dict(first_truth),
            "fixation_outcomes": dict(outcomes.most_common()),
            "corrective_steps": len(turned),
            "corrective_vergence_change_deg": {
                "p50": float(np.median(turned)) if turned else None,
                "p90": float(np.percentile(turned, 90)) if turned else None,
                "over_0.5": sum(t > 0.5 for t in turned)}}


def main() -> int:
    parser = look_arguments(__doc__)
    parser.add_argument("--state-dir", type=Path, help="the daemon's state (its map) kept here (default: temporary)")
    args = parser.parse_args()
    rng = np.random.default_rng(args.seed)
    with contextlib.ExitStack() as stack:
        state = args.state_dir or Path(stack.enter_context(tempfile.TemporaryDirectory(prefix="diag-looks-")))
        config = load_config(args.config).with_state_dir(state).with_api(port=0)
        daemon = stack.enter_context(serve(config))
        client = ApiClient(daemon.api_url)
        world = daemon.parts.devices.world
        lens = daemon.parts.devices.cameras["left"].unit_lens
        recorder = stack.enter_context(StepRecorder(world, lens).installed())
        time.sleep(args.explore_s)
        client.set_exploration(False)
        done: list[int] = []

        def with_steps(row: dict[str, Any]) -> dict[str, Any]:
            done.append(1)
            print(f"look {len(done)}/{args.looks}: {row['state']}, {row['outcome']}", file=sys.stderr, flush=True)
            return {**row, "steps": recorder.take()}

        looks = run_looks(client, config, world, lens, rng, args.spread, args.looks,
                          before_post=recorder.look_posted, after_look=with_steps)
    report(summary(looks), {"looks": looks}, args.json)
    return 0


if __name__ == "__main__":
    sys.exit(main())
