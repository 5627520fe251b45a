"""Diagnostic: what separates the map learned from images from one learned from exact samples.

Runs `--fixations` exploratory fixations on the simulated head from a random map, as
`headctl experiment online` does, recording for every taught fixation the servos' true joint
angles before and after it. Then:

1. The samples against the truth: what ended on the left fovea (the first surface along the
   left optical axis at the true final joints, `drivers.sim.truth`), projected into the
   pre-fixation pair at the true joints before: the true (x, y, d), beside the correspondence's;
   and the pose read against the true one, the executed command against the true motion; the
   (x, y) error's mean and spread, radial and tangential, by eccentricity (a bias the map learns).
2. Fresh maps taught, in the run's order, (a) the run's samples again, (b) the true positions
   with the true commands, (b') the run's samples with only their (x, y), or only their d, made
   true, (c) exact geometric samples on the run's own poses (the fixation
   point of the pose after, seen from the pose before), (d) as many exact samples from
   `FixationSampler` (poses uniform over the joint limits, the geometric experiments'); each with
   and without the pose, each scored (median landing px) on the geometric experiments' targets
   (anywhere in the joint limits) and on targets in the room seen from poses fixating it.

    .venv/bin/python -m benchmarks.diag.online_samples [--fixations 2000] [--exploration random|teaching]
        [--seed 0] [--json FILE]
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.support.image_error import radial_tangential_error
from calib_free.map.gaze_map import GazeMap
from calib_free.map.adapter import MapAdapter
from calib_free.correspondence.search import CorrespondenceParams
from calib_free.sim.experiments import landing_errors_px, landing_targets, map_predictor
from calib_free.gaze.fixation import FixationController, FixationParams
from drivers.servo.joints import JOINTS
from headctl.service.head import pose_of
from calib_free.sim.head_model import FixationSampler, HeadModel
from drivers.sim.truth import axis_point, hidden_from
from headctl.experiments.online import SimulatedHeadRig, exploration_for

DRANGE = (-60.0, 60.0)


def explore(fixations: int, exploration: str, seed: int) -> tuple[list[dict[str, Any]], SimulatedHeadRig, GazeMap]:
    """The run: every taught fixation's sample and the true joints around it."""
    params = FixationParams(exploration=exploration, correspondence=CorrespondenceParams.profile_values("default"))
    gm = GazeMap.for_image(320, 240, seed=seed)
    taught = []
    with SimulatedHeadRig(seed=seed, fixation=params) as rig, MapAdapter(gm) as adapter:
        world = rig.devices.world
        assert world is not None
        controller = FixationController(rig.head, adapter, params, seed=seed, clock=rig.clock.monotonic,
                                        learner=adapter)
        before = world.true_joints()
        for n in range(fixations):
            record = controller.fixate()
            after = world.true_joints()
            if record.taught:
                taught.append({"position": record.position, "executed": record.executed,
                               "pose_before": record.pose_before, "true_before": before, "true_after": after})
            before = after
            if (n + 1) % 500 == 0:
                print(f"{n + 1} fixations, {len(taught)} taught", file=sys.stderr)
        adapter.wait_idle()
    return taught, rig, gm


def truth(model: HeadModel, scene: Any, sample: dict[str, Any]) -> tuple[np.ndarray, bool]:
    """The true (x, y, d) of what the fixation put on the left fovea, and whether it was in view."""
    (rotation, centre), _ = model.eye_frames_from_joints(*(sample["true_after"][j] for j in JOINTS))
    point = axis_point(scene, rotation, centre)
    frames = model.eye_frames_from_joints(*(sample["true_before"][j] for j in JOINTS))
    (uv_l, seen_l), (uv_r, seen_r) = (lens.project(((point - c) @ r.T)[None])
                                      for (r, c), lens in zip(frames, (model.lens_left, model.lens_right)))
    hidden = hidden_from(scene, frames[0][1], point, 1e-3)
    return np.array([uv_l[0, 0], uv_l[0, 1], uv_r[0, 0] - uv_l[0, 0]]), bool(seen_l[0] and seen_r[0] and not hidden)


def xy_bias_by_eccentricity(measured: np.ndarray, true_r: np.ndarray, model: HeadModel,
                            rings_px: tuple[float, ...] = (0, 30, 60, 90, 1e9)) -> list[dict[str, float]]:
    """The correspondence's (x, y) error, radial (outwards from the image centre, positive) and
    tangential, mean and standard deviation per ring of the true position's eccentricity."""
    centre = np.array([(model.width - 1) / 2.0, (model.height - 1) / 2.0])
    radius, radial, tangential = radial_tangential_error(measured[:, :2], true_r[:, :2], centre)
    out = []
    for lo, hi in zip(rings_px[:-1], rings_px[1:]):
        m = (radius >= lo) & (radius < hi)
        if m.any():
            out.append({"eccentricity_px": f"{lo:g}-{hi:g}", "n": int(m.sum()),
                        "radial_mean_px": round(float(radial[m].mean()), 3), "radial_sd_px": round(float(radial[m].std()), 3),
                        "tangential_mean_px": round(float(tangential[m].mean()), 3),
                        "tangential_sd_px": round(float(tangential[m].std()), 3)})
    return out


def taught_map(seed: int, positions: np.ndarray, commands: np.ndarray, poses: np.ndarray, use_pose: bool) -> GazeMap:
    gm = GazeMap.for_image(320, 240, seed=seed)
    for r, m, q in zip(positions, commands, poses):
        gm.adapt(r, m, confidence=1.0, pose=q if use_pose else None)
    return gm


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--fixations", type=int, default=2000)
    parser.add_argument("--exploration", default=exploration_for("default"))
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--json", type=Path)
    args = parser.parse_args()
    started = time.monotonic()
    taught, rig, online_map = explore(args.fixations, args.exploration, args.seed)
    model, scene = rig.model, rig.scene
    true_r, in_view = zip(*(truth(model, scene, s) for s in taught))
    true_r, in_view = np.array(true_r), np.array(in_view)
    position = np.array([s["position"] for s in taught])
    executed = np.array([s["executed"] for s in taught])
    read_before = np.array([s["pose_before"] for s in taught])
    before = np.array([pose_of(s["true_before"]) for s in taught])
    after = np.array([pose_of(s["true_after"]) for s in taught])
    off = position - true_r
    off_xy = np.hypot(off[:, 0], off[:, 1])
    out: dict[str, Any] = {
        "exploration": args.exploration, "fixations": args.fixations, "taught": len(taught),
        "correspondence_vs_truth": {
            "xy_px_median": float(np.median(off_xy)), "xy_px_p90": float(np.percentile(off_xy, 90)),
            "xy_over_1px": float(np.mean(off_xy > 1)), "xy_over_3px": float(np.mean(off_xy > 3)),
            "d_px_median": float(np.median(np.abs(off[:, 2]))), "d_over_1px": float(np.mean(np.abs(off[:, 2]) > 1)),
            "d_over_3px": float(np.mean(np.abs(off[:, 2]) > 3)), "not_in_view_before": int(np.sum(~in_view))},
        "xy_bias_by_eccentricity": xy_bias_by_eccentricity(position[in_view], true_r[in_view], model),
        "pose_read_minus_true_max_deg": np.abs(read_before - before).max(axis=0).tolist(),
        "executed_minus_true_motion_max_deg": np.abs(executed - (after - before)).max(axis=0).tolist(),
        "poses_before_5_50_95": np.percentile(before, [5, 50, 95], axis=0).round(1).tolist(),
    }
    targets = {"joint_range": landing_targets(model, 300, DRANGE, seed=args.seed + 7919),
               "room": landing_targets(model, 300, DRANGE, seed=args.seed + 7919, surroundings=rig.surroundings)}
    out["targets_poses_before_5_50_95"] = {
        name: np.percentile([t.pose_before for t in ts], [5, 50, 95], axis=0).round(1).tolist()
        for name, ts in targets.items()}
    exact = [model.image_position(model.fixation_point(a)[None], b) for b, a in zip(before, after)]
    exact_r = np.array([r[0] for r, _ in exact])
    inside = online_map.check_position
    exact_ok = np.array([bool(seen[0]) and inside(r[0]) == "" for r, seen in exact])
    sampler = FixationSampler(model, DRANGE, seed=args.seed)
    drawn = [sampler.draw() for _ in range(len(taught))]
    teachings = {
        "the run's samples": (position, executed, read_before),
        "true positions, true motion": (true_r[in_view], (after - before)[in_view], before[in_view]),
        # Which part of the correspondence's error costs what: its (x, y) or its d replaced by the truth.
        "true (x, y), measured d, the run's commands": (
            np.where(in_view[:, None], np.c_[true_r[:, :2], position[:, 2]], position), executed, read_before),
        "measured (x, y), true d, the run's commands": (
            np.where(in_view[:, None], np.c_[position[:, :2], true_r[:, 2]], position), executed, read_before),
        "exact samples on the run's poses": (exact_r[exact_ok], (after - before)[exact_ok], before[exact_ok]),
        "exact samples, FixationSampler poses": tuple(np.array([getattr(s, f) for s in drawn])
                                                      for f in ("position", "command", "pose_before")),
    }

    def score(gm: GazeMap, use_pose: bool) -> dict[str, float]:
        return {name: round(float(np.median(landing_errors_px(model, ts, map_predictor(gm, use_pose)))), 2)
                for name, ts in targets.items()}

    out["landing_px"] = {"the online map": score(online_map, True)}
    for use_pose in (True, False):
        for name, (r, m, q) in teachings.items():
            key = f"{name}, {'with' if use_pose else 'without'} the pose"
            out["landing_px"][key] = score(taught_map(args.seed, r, m, q, use_pose), use_pose)
    out["seconds"] = round(time.monotonic() - started, 1)
    text = json.dumps(out, indent=2)
    print(text)
    if args.json:
        args.json.write_text(text + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
