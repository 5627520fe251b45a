"""Benchmark: closed-loop looks on the simulated head after exploration (issue 13, part 2's goal).

1. Explores `--explore` fixations (default 2,000) from a random map on the simulated head, as
   `headctl experiment online` does (`SimulatedHeadRig`: a manual clock, rendered pairs with
   sensor noise, the adapter thread learning).
2. Then `--looks` looks of each kind, each from wherever an exploratory fixation left the head
   (one runs between looks), through `calib_free.gaze.look.LookController`, which teaches the
   map as the service's looks do:
   - textured targets: random pixels of the left image whose patch identifies them in their own
     view (`patch_problem`: textured, not repetitive), with their disparity measured;
   - random pixels sent without d: d as the daemon finds it
     (`headctl.service.control.target_disparity` on the pair at rest): measured, else 0 (the
     fixation's depth) where the look can find the target by its patch; a pixel it refuses (the
     API answers 422: no patch to find the target by) counts as a look that did not succeed.
     Where d is not measured, the truth says why (`unmeasured_cause`: counted in `draws`).
   Pixels whose map command (with that d, or 0 for a refused pixel) would take pan or tilt
   beyond the joint limits are drawn again (counted): no head reaches them.
3. The truth: the world point the target pixel showed before the look (the first surface along
   its ray, `drivers.sim.truth`), projected into the left image at the servos' true
   final position; its distance from the fovea beside the look's own `final_error_px`.

    .venv/bin/python -m benchmarks.bench.looks [--explore 2000] [--looks 100] [--seed 0]
        [--map FILE] [--save-map FILE] [--json FILE] [--band-px N] [--survey VIEWS]

`--map` starts from a saved map instead of exploring (`--save-map` keeps the explored one).
`--survey VIEWS` measures d instead of looking: 20 random pixels (reachable or not) in each of
VIEWS views, and why d is not measured where it is not (`survey_disparity`).
"""
from __future__ import annotations

import argparse
import collections
import json
import sys
import time
from pathlib import Path
from typing import Any, Callable

import numpy as np

from calib_free.map.file import read_map, write_map
from calib_free.map.gaze_map import GazeMap
from calib_free.map.adapter import MapAdapter
from calib_free.gaze.look import LookController, LookRecord
from calib_free.gaze.target_patch import patch_problem
from calib_free.correspondence.disparity import as_grey_float
from calib_free.gaze.fixation import FixationController, LookParams
from drivers.sim.truth import first_surface, hidden_from
from headctl.errors import ControlError
from headctl.experiments.online import SimulatedHeadRig
from headctl.service.control import DISPARITY_BAND_PX, disparity_at, target_disparity

JOINT_ORDER = ("pan", "tilt", "left_eye", "right_eye")


def true_error_px(rig: SimulatedHeadRig, before: dict[str, float], after: dict[str, float],
                  xy: tuple[float, float]) -> tuple[float, bool]:
    """Distance from the left fovea, at the joints `after`, of the point pixel `xy` showed at
    the joints `before`, through the left camera's own lens (a realistic unit's differs from the
    model's) in the room it renders; and whether that point is hidden from the left eye there."""
    return world_error_px(rig.model, rig.scene, rig.devices.cameras["left"].unit_lens, before, after, xy)


def world_error_px(model, scene, lens, before: dict[str, float], after: dict[str, float],
                   xy: tuple[float, float]) -> tuple[float, bool]:
    """`true_error_px` in `scene` seen through `lens`, the left camera's own (a simulated unit's
    lens differs from the model's); the fovea is the model's, the image centre the method uses."""
    (dx, dy), hidden = world_offset_px(model, scene, lens, before, after, xy)
    return float(np.hypot(dx, dy)), hidden


def world_offset_px(model, scene, lens, before: dict[str, float], after: dict[str, float],
                    xy: tuple[float, float]) -> tuple[tuple[float, float], bool]:
    """Where the world point pixel `xy` showed at the joints `before` is seen at the joints
    `after`, from the fovea (x, y), and whether it is hidden there (`world_error_px`)."""
    (rotation, centre), _ = model.eye_frames_from_joints(*(before[j] for j in JOINT_ORDER))
    ray = lens.unproject(np.array([xy]))[0]
    point = first_surface(scene, centre, rotation.T @ ray)
    (rotation, centre), _ = model.eye_frames_from_joints(*(after[j] for j in JOINT_ORDER))
    uv, _ = lens.project(((point - centre) @ rotation.T)[None])
    hidden = hidden_from(scene, centre, point, 1e-3)
    cx, cy = model.lens_left.principal_point
    return (float(uv[0, 0] - cx), float(uv[0, 1] - cy)), hidden


def right_eye_truth(rig, xy: tuple[float, float]) -> tuple[bool, bool, float, float]:
    """What the right eye sees of the point pixel `xy` of the left image shows, the head at rest,
    through the cameras' own lenses:
    (hidden from it, in its image, true disparity x_r - x_l, vertical disparity y_r - y_l)."""
    model, scene = rig.model, rig.scene
    lens_left, lens_right = (rig.devices.cameras[side].unit_lens for side in ("left", "right"))
    joints = rig.devices.world.true_joints()
    (rot_l, centre_l), (rot_r, centre_r) = model.eye_frames_from_joints(*(joints[j] for j in JOINT_ORDER))
    point = first_surface(scene, centre_l, rot_l.T @ lens_left.unproject(np.array([xy]))[0])
    uv, seen = lens_right.project(((point - centre_r) @ rot_r.T)[None])
    hidden = hidden_from(scene, centre_r, point, 1e-3)
    return hidden, bool(seen[0]), float(uv[0, 0] - xy[0]), float(uv[0, 1] - xy[1])


def unmeasured_cause(rig, left: np.ndarray, xy: tuple[float, float], patch_size: tuple[int, int],
                     disparity_range: tuple[float, float], band_px: int, row_offset_px: float = 0.0) -> str:
    """Why the truth says the disparity at pixel `xy` of the left image at rest could not be
    measured: the measuring patch beyond the image, flat, the point hidden from the right eye or
    outside its image, its disparity beyond the range searched, its vertical disparity a row
    beyond the rows searched, else a patch seen by both eyes that still does not match (a
    depth edge across it, foreshortening)."""
    (x, y), (pw, ph) = xy, patch_size
    x0, y0 = round(x - (pw - 1) / 2.0), round(y - (ph - 1) / 2.0)
    if x0 < 0 or y0 < 0 or x0 + pw > left.shape[1] or y0 + ph > left.shape[0]:
        return "its patch reaches beyond the image"
    if float(left[y0:y0 + ph, x0:x0 + pw].std()) < LookParams().min_patch_std:
        return "flat"
    hidden, seen, d, dy = right_eye_truth(rig, xy)
    if hidden:
        return "hidden from the right eye"
    if not seen:
        return "outside the right image"
    if not disparity_range[0] < d < disparity_range[1]:
        return "disparity beyond the map's range"
    if abs(dy - row_offset_px) > band_px + 1.0:  # a match survives about a row of vertical disparity
        return "vertical disparity beyond the rows searched"
    return "seen by both eyes, no match (depth edge, foreshortening)"


def survey_disparity(rig, adapter, controller, rng, views: int, per_view: int, band_px: int) -> dict[str, Any]:
    """`per_view` random pixels (reachable or not) in each of `views` views an exploratory
    fixation left: the share whose d `disparity_at` measures, how many of those lie within 2 px
    of the true d, the vertical disparities, and why the others were not measured (the truth)."""
    causes: collections.Counter = collections.Counter()
    measured = close = 0
    vertical: list[float] = []
    params, disparity_range = rig.fixation, adapter.map.params.disparity_range
    for _ in range(views):
        controller.fixate()
        left, right = (as_grey_float(im) for im in rig.head.wait_pair(rig.head.wait_settled(3.0), 2.0))
        for _ in range(per_view):
            xy = float(rng.uniform(0, left.shape[1] - 1)), float(rng.uniform(0, left.shape[0] - 1))
            hidden, seen, true_d, dy = right_eye_truth(rig, xy)
            if seen and not hidden:
                vertical.append(abs(dy))
            try:
                d, _ = disparity_at(left, right, *xy, params.vergence_patch_size, disparity_range, band_px,
                                    controller.row_offset_px)
            except ControlError:
                causes[unmeasured_cause(rig, left, xy, params.vergence_patch_size, disparity_range, band_px,
                                        controller.row_offset_px)] += 1
                continue
            measured += 1
            close += seen and not hidden and abs(d - true_d) <= 2.0
    total = views * per_view
    return {"pixels": total, "band_px": band_px, "measured_fraction": measured / total,
            "measured_within_2px_of_true_d": close / measured if measured else None,
            "vertical_disparity_px": dict(zip(("p50", "p90", "p99"), np.percentile(vertical, [50, 90, 99]).tolist())),
            "not_measured_fraction": {cause: n / total for cause, n in causes.most_common()}}


def draw_target(rig, adapter, rng, textured: bool, counts: collections.Counter, band_px: int = DISPARITY_BAND_PX,
                row_offset_px: float = 0.0) -> tuple[tuple[float, float, float], bool] | None:
    """A target in the pair at rest, (x, y, d), and whether d was measured; None when the daemon
    would refuse it (random pixels only). Unreachable pixels, and for `textured` unidentifiable
    ones, are drawn again. d is measured about the rows `row_offset_px` below (the pair's
    misalignment as fine vergence found it, as the daemon measures d)."""
    head = rig.head
    left, right = (as_grey_float(im) for im in head.wait_pair(head.wait_settled(3.0), 2.0))
    height, width = left.shape
    pose = head.read_pose()
    params = rig.fixation
    disparity_range = adapter.map.params.disparity_range
    for _ in range(1000):
        x, y = float(rng.uniform(0, width - 1)), float(rng.uniform(0, height - 1))
        refused, measured = "", True
        if textured:
            try:
                d, _ = disparity_at(left, right, x, y, params.vergence_patch_size, disparity_range, band_px,
                                    row_offset_px)
            except ControlError:
                continue
            if patch_problem(left, (x, y), params.look):
                continue
        else:
            try:
                found = target_disparity(left, right, x, y, params.vergence_patch_size, disparity_range, params.look,
                                         band_px, row_offset_px)
                d, measured = found.d, found.measured
            except ControlError as err:
                d, refused = 0.0, str(err)
        goal = pose + adapter.command((x, y, d))
        if np.any(goal[:2] < head.pose_low[:2] + 1.0) or np.any(goal[:2] > head.pose_high[:2] - 1.0):
            counts["drawn again: beyond the joint limits"] += 1
            continue
        if not measured or "could not be measured" in refused:
            cause = unmeasured_cause(rig, left, (x, y), params.vergence_patch_size, disparity_range, band_px,
                                     row_offset_px)
            counts[f"d not measured because: {cause}"] += 1
        if refused:
            why = next((w for w in ("beyond the image", "no texture", "ambiguous") if w in refused), "other")
            counts[f"refused (422): {why}"] += 1
            return None
        if not measured:
            counts["d not measured: looked at with d = 0"] += 1
        return (x, y, d), measured
    raise RuntimeError("no usable target in 1000 draws")


def second_attempts(looks: list[dict[str, Any]]) -> dict[str, int]:
    """How many looks tried a second time at the depth their first attempt found, and how many
    of those ended on target (`calib_free.gaze.second_attempt`)."""
    again = [r for r in looks if (r.get("attempts") or 1) > 1]
    return {"looks": len(again), "on_target": sum(bool(r["on_target"]) for r in again)}


def finishing_steps(looks: list[dict[str, Any]], max_corrective_steps: int) -> dict[str, int]:
    """How many looks took finishing steps (corrective steps past `max_corrective_steps`, the
    target then within `finishing_reach_px` of the fovea), and how many of those ended on target."""
    finished = [r for r in looks if (r.get("corrective_steps") or 0) > max_corrective_steps]
    return {"looks": len(finished), "on_target": sum(bool(r["on_target"]) for r in finished)}


def summary(rows: list[dict[str, Any]], counts: collections.Counter, params: LookParams) -> dict[str, Any]:
    tolerance_px = params.tolerance_px
    looks = [r for r in rows if r["outcome"] is not None]
    on = [r for r in looks if r["on_target"]]
    unmeasured = [r for r in looks if not r["d_measured"]]
    final = np.array([r["final_error_px"] for r in on])
    truth_on = np.array([r["true_error_px"] for r in on])
    steps = np.array([r["corrective_steps"] for r in on])
    landing = np.array([r["landing_error_px"] for r in looks if r["landing_error_px"] is not None])

    def q(values: np.ndarray, p: float) -> float | None:
        return float(np.percentile(values, p)) if len(values) else None

    return {
        "looks": len(rows), "refused_at_the_api": len(rows) - len(looks),
        "on_target": len(on), "on_target_fraction": len(on) / len(rows) if rows else None,
        "on_target_fraction_of_looks_run": len(on) / len(looks) if looks else None,
        "truly_within_tolerance_fraction": sum(r["true_error_px"] <= tolerance_px for r in on) / len(rows)
        if rows else None,
        "d_not_measured": {"looks": len(unmeasured), "on_target": sum(r["on_target"] for r in unmeasured)},
        "final_error_px": {"median": q(final, 50), "p90": q(final, 90), "max": q(final, 100)},
        "true_error_px_on_target": {"median": q(truth_on, 50), "p90": q(truth_on, 90), "max": q(truth_on, 100),
                                    "within_tolerance": float(np.mean(truth_on <= tolerance_px)) if len(on) else None},
        "corrective_steps": {"median": q(steps, 50), "max": q(steps, 100),
                             "histogram": dict(collections.Counter(int(s) for s in steps))},
        "landing_error_px_accepted": {"count": len(landing), "median": q(landing, 50), "p90": q(landing, 90)},
        "second_attempts": second_attempts(looks),
        "finishing_steps": finishing_steps(looks, params.max_corrective_steps),
        "outcomes": dict(collections.Counter(r["outcome"] or "refused at the API (422)" for r in rows)),
        "draws": dict(counts),
        "seconds_per_look_simulated": float(np.mean([r["duration_s"] for r in looks])) if looks else None,
    }


def run_looks(rig, adapter, controller, looker, rng, count: int, textured: bool,
              band_px: int = DISPARITY_BAND_PX,
              before_look: Callable[[dict[str, float], tuple[float, float]], None] | None = None,
              after_look: Callable[[dict[str, Any]], dict[str, Any]] | None = None) -> dict[str, Any]:
    """`count` looks of a kind and their summary; `before_look` is told the true joints and the
    target pixel as each look starts, `after_look` may add to each look's row."""
    rows: list[dict[str, Any]] = []
    counts: collections.Counter = collections.Counter()
    world = rig.devices.world
    for _ in range(count):
        controller.fixate()  # an exploratory fixation: the look starts from wherever it left the head
        drawn = draw_target(rig, adapter, rng, textured, counts, band_px, controller.row_offset_px)
        if drawn is None:
            rows.append({"outcome": None, "on_target": False})
            continue
        target, measured = drawn
        before = world.true_joints()
        if before_look is not None:
            before_look(before, (float(target[0]), float(target[1])))
        record: LookRecord = looker.look(target, rig.head.read_pose(), depth_known=measured)
        truth, hidden = true_error_px(rig, before, world.true_joints(), target[:2])
        row = {"target": target, "d_measured": measured, "outcome": str(record.outcome),
               "on_target": record.on_target,
               "final_error_px": record.final_error_px, "true_error_px": truth, "hidden": hidden,
               "corrective_steps": record.corrective_steps, "attempts": record.attempts,
               "landing_error_px": record.landing_error_px,
               "duration_s": record.duration_s, "detail": record.detail}
        rows.append(after_look(row) if after_look is not None else row)
    return {"summary": summary(rows, counts, looker.params), "looks": rows}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--explore", type=int, default=2000, help="exploratory fixations first (default 2000)")
    parser.add_argument("--looks", type=int, default=100, help="looks of each kind (default 100)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--map", type=Path, help="start from this map file instead of exploring")
    parser.add_argument("--save-map", type=Path, help="save the explored map here")
    parser.add_argument("--json", type=Path, help="write every look and the summaries here")
    parser.add_argument("--survey", type=int, metavar="VIEWS",
                        help="instead of looks: why d cannot be measured, 20 random pixels in each of VIEWS views")
    parser.add_argument("--band-px", type=int, default=DISPARITY_BAND_PX,
                        help=f"rows either side searched to measure d (default {DISPARITY_BAND_PX}; 0: the same rows)")
    args = parser.parse_args()
    gm = read_map(args.map) if args.map else GazeMap.for_image(320, 240, seed=args.seed)
    rng = np.random.default_rng(args.seed + 101)
    started = time.monotonic()
    with SimulatedHeadRig(seed=args.seed) as rig, MapAdapter(gm) as adapter:
        controller = FixationController(rig.head, adapter, rig.fixation, seed=args.seed,
                                        clock=rig.clock.monotonic, learner=adapter)
        taught = sum(controller.fixate().taught for _ in range(0 if args.map else args.explore))
        adapter.wait_idle()
        if args.save_map:
            adapter.with_map(lambda m: write_map(m, args.save_map))
        explored_s = time.monotonic() - started
        print(f"explored {0 if args.map else args.explore} fixations ({taught} taught) in {explored_s:.0f} s",
              file=sys.stderr)
        if args.survey:
            print(json.dumps(survey_disparity(rig, adapter, controller, rng, args.survey, 20, args.band_px), indent=2))
            return 0
        looker = LookController(controller)
        results = {"textured": run_looks(rig, adapter, controller, looker, rng, args.looks, textured=True),
                   "random_without_d": run_looks(rig, adapter, controller, looker, rng, args.looks, textured=False,
                                                 band_px=args.band_px)}
    out = {"explore": 0 if args.map else args.explore, "map": str(args.map) if args.map else None,
           "seed": args.seed, "band_px": args.band_px, "seconds": time.monotonic() - started,
           **{kind: r["summary"] for kind, r in results.items()}}
    print(json.dumps(out, indent=2))
    if args.json:
        args.json.write_text(json.dumps({**out, "looks": {k: r["looks"] for k, r in results.items()}}, indent=1,
                                        default=float) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
