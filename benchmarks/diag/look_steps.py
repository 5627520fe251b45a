"""Diagnostic: every step of the looks of `benchmarks.bench.looks_daemon`, against the truth.

The looks of the real-time daemon benchmark (the same daemon, the same random pixels from a
head near the centre), with each of a look's fixations recorded as it ends, on the fixation
thread: its aim (x, y, d) and, for a corrective step, the d measured at the target before it
(the aim's d is that one unless the step held the eyes at the target's depth), outcome and
its detail, whether the eyes converged and in how many vergence steps (and the foveal
disparity before each), the saccade's planned command, the pose before and after, and the
truth: where the world point the pixel showed before the look lies from the left fovea,
projected at the servos' true position then (x, y, and its distance); and after each
fixation the target search's answer (the patch's distance from the fovea and its offset, or
why it was not found), with the patch's size, how much less well it matches the best other
place of its own view than its own, and how far the target lay from the image
centre, the scales of the warp it was found with (its singular values), and the landing error
the search was told to expect (measured, or a corrective step's own) and, after a corrective
step, the step's own expected error, which bounds the search. Summarised: how
far the first saccade truly left the target in the looks that failed, the outcomes of the
looks' fixations, and how far the vergence moved in the corrective steps (each degree of
vergence turns the left eye half a degree, which moves the target on the left fovea: about 2
px a degree of vergence at the fovea), and the first sightings against the truth: the lens's
magnification by the target's distance from the image centre where they agree, and the
sightings the truth refutes.

`--state-dir` keeps the daemon's map between runs (a map explored before, explored further
for `--explore-s`); without it the daemon starts from a random map in a temporary directory.

    .venv/bin/python -m benchmarks.diag.look_steps [--config configs/sim.yaml] [--state-dir DIR]
        [--explore-s 300] [--looks 60] [--spread 5] [--seed 0] [--json FILE] [--images DIR]
"""
from __future__ import annotations

import argparse
import collections
import contextlib
import json
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any, Iterator

import numpy as np

import calib_free.gaze.look as look_module
from benchmarks.bench.looks import world_offset_px
from benchmarks.bench.looks_daemon import look_arguments, report, run_looks
from calib_free.gaze.target_patch import own_view_peaks
from calib_free.gaze.step_disparity import StepDisparity
from headctl.api.client import ApiClient
from headctl.api.compose import serve
from headctl.config.head import load_config


class StepRecorder:
    """Records the steps of the look running; `look_posted` starts a look's record."""

    def __init__(self, world: Any, lens: Any, images_dir: Path | None = None) -> None:
        self.world, self.lens, self.images_dir = world, lens, images_dir
        self.searches_saved = 0
        self.steps: list[dict[str, Any]] = []
        self._lock = threading.Lock()
        self._before: dict[str, float] | None = None
        self._xy: tuple[float, float] | None = None

    def look_posted(self, before: dict[str, float], xy: tuple[float, float]) -> None:
        with self._lock:
            self.steps, self._before, self._xy = [], before, xy

    @property
    def joints_before(self) -> dict[str, float] | None:
        """The servos' true joints as the look running began; None before a look."""
        with self._lock:
            return None if self._before is None else dict(self._before)

    def take(self) -> list[dict[str, Any]]:
        with self._lock:
            steps, self.steps = self.steps, []
            return steps

    def _truth_px(self) -> tuple[float, float] | None:
        """The truth now: where the world point the look's pixel showed lies from the left
        fovea (x, y); None before a look, or where the point is hidden."""
        if self._before is None or self._xy is None:
            return None
        offset, hidden = world_offset_px(self.world.model, self.world.scene, self.lens, self._before,
                                         self.world.true_joints(), self._xy)
        return None if hidden else offset

    def _record_search(self, source: np.ndarray, source_xy: tuple[float, float], image: np.ndarray, params: Any,
                       warps: list[np.ndarray] | None, expected: float | None,
                       offset: tuple[float, float] | None, sighting: Any, why: str,
                       step: float | None = None) -> None:
        h, w = image.shape[:2]
        peaks, _ = own_view_peaks(source, source_xy, params)
        saved = None
        if self.images_dir is not None:
            self.images_dir.mkdir(parents=True, exist_ok=True)
            np.savez_compressed(self.images_dir / f"search-{self.searches_saved:03d}.npz",
                                source=source, source_xy=np.asarray(source_xy), image=image,
                                patch=np.asarray(params.target_patch_size),
                                warps=np.asarray(warps if warps is not None else []),
                                expected=np.asarray(np.nan if expected is None else expected, dtype=float),
                                offset=np.asarray((np.nan, np.nan) if offset is None else offset, dtype=float),
                                step=np.asarray(np.nan if step is None else step, dtype=float))
            saved, self.searches_saved = self.searches_saved, self.searches_saved + 1
        with self._lock:
            self.steps.append({
                "saved": saved,
                "expected_error_px": None if expected is None else round(float(expected), 2),
                "expected_offset_px": None if offset is None else [round(float(v), 2) for v in offset],
                "step_error_px": None if step is None else round(float(step), 2),
                "search": None if sighting is None else round(float(np.hypot(
                    sighting.x - (w - 1) / 2.0, sighting.y - (h - 1) / 2.0)), 2), "why": why,
                "seen_at_px": None if sighting is None else [round(float(sighting.x - (w - 1) / 2.0), 2),
                                                             round(float(sighting.y - (h - 1) / 2.0), 2)],
                "patch": list(params.target_patch_size),
                "warp_scales": None if sighting is None else [
                    round(float(v), 3) for v in np.linalg.svd(sighting.warp, compute_uv=False)],
                "own_view_margin": None if peaks is None else round(peaks[0] - peaks[1], 3),
                "target_radius_px": round(float(np.hypot(source_xy[0] - (w - 1) / 2.0,
                                                         source_xy[1] - (h - 1) / 2.0)), 1)})

    @contextlib.contextmanager
    def installed(self) -> Iterator["StepRecorder"]:
        """The look module's target searches and fixations wrapped to record, for the block."""
        find_first, find_later = look_module.find_first_sighting, look_module.find_later_sighting
        fixate = look_module.LookController._fixate
        disparity_at = StepDisparity.measured_at
        recorder = self
        measured: list[float] = []  # the d measured for the corrective step about to be taken

        def recorded_disparity(chooser, fixation, sighting):  # type: ignore[no-untyped-def]
            d = disparity_at(chooser, fixation, sighting)
            measured[:] = [float(d)]
            return d

        def recorded_first(source, source_xy, image, variants, magnification, expected=None, offset=None):  # type: ignore[no-untyped-def]
            sighting, variant, why = find_first(source, source_xy, image, variants, magnification, expected, offset)
            recorder._record_search(source, source_xy, image, variant, None, expected, offset, sighting, why)
            return sighting, variant, why

        def recorded_later(source, source_xy, image, variants, warps, expected, offset, step):  # type: ignore[no-untyped-def]
            sighting, variant, why = find_later(source, source_xy, image, variants, warps, expected, offset, step)
            recorder._record_search(source, source_xy, image, variant, warps, expected, offset, sighting, why, step)
            return sighting, variant, why

        def recorded_fixate(controller, record, target, reference_pose=None, continues=False,  # type: ignore[no-untyped-def]
                            target_check=None):
            fixation = fixate(controller, record, target, reference_pose, continues, target_check)

            def pose(p: Any) -> list[float] | None:
                return None if p is None else [round(float(v), 3) for v in p]

            step_d = measured.pop() if continues and measured else None
            truth = recorder._truth_px()
            with recorder._lock:
                recorder.steps.append({
                    "aim": [round(float(v), 2) for v in target],
                    "measured_d": None if step_d is None else round(step_d, 2), "outcome": str(fixation.outcome),
                    "detail": fixation.detail,
                    "converged": fixation.converged, "vergence_steps": fixation.vergence_steps,
                    "pose_before": pose(fixation.pose_before), "pose_after": pose(fixation.pose_after),
                    "planned": pose(fixation.planned), "vergence_disparities_px": [
                        round(float(v), 2) for v in fixation.vergence_disparities_px],
                    "true_error_px": None if truth is None else round(float(np.hypot(*truth)), 2),
                    "true_offset_px": None if truth is None else [round(v, 2) for v in truth]})
            return fixation

        look_module.find_first_sighting, look_module.find_later_sighting = recorded_first, recorded_later
        look_module.LookController._fixate = recorded_fixate  # type: ignore[method-assign]
        StepDisparity.measured_at = recorded_disparity  # type: ignore[method-assign]
        try:
            yield self
        finally:
            look_module.find_first_sighting, look_module.find_later_sighting = find_first, find_later
            look_module.LookController._fixate = fixate  # type: ignore[method-assign]
            StepDisparity.measured_at = disparity_at  # type: ignore[method-assign]


def saved_first_search(look: dict[str, Any], images: Path) -> tuple[dict[str, Any], dict[str, Any], Any] | None:
    """A recorded look's first fixation, its first target search and that search's saved inputs
    (`--images`: source, source_xy, image, ...); None for a look refused, or whose first search
    was not saved."""
    steps = look.get("steps") or []
    fixation = next((s for s in steps if "aim" in s), None)
    search = next((s for s in steps if "search" in s), None)
    if look["state"] == "refused" or fixation is None or search is None or search.get("saved") is None:
        return None
    return fixation, search, np.load(images / f"search-{search['saved']:03d}.npz")


def saved_first_searches(steps_json: Path, images: Path,
                         ) -> Iterator[tuple[dict[str, Any], dict[str, Any], dict[str, Any], Any]]:
    """(look, its first fixation, its first search, that search's saved inputs) for each look of
    a recording (`--json`, `--images`) whose first search was saved (`saved_first_search`)."""
    for look in json.loads(steps_json.read_text())["looks"]:
        first = saved_first_search(look, images)
        if first is not None:
            yield (look, *first)


def recording_arguments(parser: argparse.ArgumentParser) -> None:
    """`--steps FILE --images DIR`, given once for each recording a diagnostic reads."""
    parser.add_argument("--steps", type=Path, action="append", required=True, help="a look_steps --json file")
    parser.add_argument("--images", type=Path, action="append", required=True, help="its --images directory")


def recording_files(description: str, argv: list[str] | None) -> list[Path]:
    """The look_steps `--json` files named on a diagnostic's command line (`argv`), each checked
    to exist; a usage error naming those that do not."""
    parser = argparse.ArgumentParser(description=description)
    parser.add_argument("recordings", type=Path, nargs="+", help="look_steps --json files")
    args = parser.parse_args(argv)
    missing = [str(p) for p in args.recordings if not p.is_file()]
    if missing:
        parser.error(f"no such recording: {', '.join(missing)}")
    return list(args.recordings)


def recordings(parser: argparse.ArgumentParser, args: argparse.Namespace) -> list[tuple[Path, Path]]:
    """The (steps, images) pairs of `recording_arguments`; a usage error where they do not pair up."""
    if len(args.steps) != len(args.images):
        parser.error(f"--steps given {len(args.steps)} times and --images {len(args.images)}: one each a recording")
    return list(zip(args.steps, args.images))


def first_sightings(looks: list[dict[str, Any]], agree_px: float = 2.0, bin_px: float = 20.0) -> dict[str, Any]:
    """The first sighting of each look (the target found after the first saccade) against the
    truth: agreeing within `agree_px` of the first fixation's true error, the median largest
    scale of their warps (the lens's magnification of a patch brought to the fovea, along the
    radius) in bins of `bin_px` of the target's distance from the image centre; and those the
    truth refutes, each with its distance, scale and the truth."""
    agreed: dict[int, list[float]] = collections.defaultdict(list)
    refuted: list[dict[str, float]] = []
    for lk in looks:
        steps = lk["steps"]
        first = next((k for k, s in enumerate(steps) if "search" in s), None)
        if first is None or steps[first]["search"] is None or not steps[first].get("warp_scales"):
            continue
        truths = [s["true_error_px"] for s in steps[:first] if "aim" in s]
        truth = truths[-1] if truths else None
        if truth is None:
            continue
        search, radius, scale = steps[first]["search"], steps[first]["target_radius_px"], steps[first]["warp_scales"][0]
        if abs(search - truth) <= agree_px:
            agreed[int(radius // bin_px)].append(scale)
        else:
            refuted.append({"target_radius_px": radius, "scale": scale, "search_px": search, "true_px": truth})
    return {"agreeing_scale_by_radius_px": {f"{k * bin_px:g}-{(k + 1) * bin_px:g}": {
                "n": len(v), "p50": float(np.median(v)), "min": min(v), "max": max(v)} for k, v in sorted(agreed.items())},
            "refuted_by_truth": refuted}


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
            "first_sightings": first_sightings(taken),
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
    parser.add_argument("--images", type=Path,
                        help="each target search saved here (search-NNN.npz: its images and inputs)")
    args = parser.parse_args()
    rng = np.random.default_rng(args.seed)
    with contextlib.ExitStack() as stack:
        state = args.state_dir or Path(stack.enter_context(tempfile.TemporaryDirectory(prefix="diag-looks-")))
        config = load_config(args.config).with_state_dir(state).with_api(port=0)
        daemon = stack.enter_context(serve(config))
        client = ApiClient(daemon.api_url)
        world = daemon.parts.devices.world
        lens = daemon.parts.devices.cameras["left"].unit_lens
        recorder = stack.enter_context(StepRecorder(world, lens, args.images).installed())
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
