"""Benchmark: finding a look's target again (`calib_free.gaze.refind.find_target`).

A look searches for its target's patch after every fixation: after the first with every
candidate warp (the patch seen through another part of the lens), after each corrective one
with the warp found before. This times both searches on rendered 640 x 480 views of the photo
room: `--cases` targets, each a point of the room fixated from a random pose (the sampler of
the geometric experiments), seen in the left image before a saccade that brings it within
`--landing-deg` (pan and tilt, normal) of the fovea, and after it. With `--baseline REV` the
same searches run with `find_target` as it is at revision REV, interleaved in `--rounds`
rounds, so that both meet the machine alike; their answers are compared (found by both,
positions within 0.01 px).

    .venv/bin/python -m benchmarks.bench.refind [--cases 60] [--rounds 3] [--seed 0]
        [--landing-deg 0.15] [--baseline HEAD]
"""
from __future__ import annotations

import argparse
import os
import time
import types
from dataclasses import dataclass
from typing import Any

import numpy as np

from benchmarks.support.baseline import baseline_module
from calib_free.correspondence.disparity import as_grey_float
from calib_free.gaze import refind
from calib_free.gaze.fixation import LookParams
from calib_free.gaze.target_patch import patch_problem
from calib_free.sim.head_model import FixationSampler, HeadModel
from drivers.sim.scene import StereoRenderer, shared_scene
from headctl.experiments.online import RoomSurfaces
from headctl.service.head import joints_of


@dataclass(frozen=True)
class Case:
    before: np.ndarray  # the left image the target was chosen in
    xy: tuple[float, float]  # the target there
    after: np.ndarray  # the left image after the saccade


def cases(count: int, seed: int, landing_deg: float) -> list[Case]:
    model = HeadModel.default(640, 480)
    scene = shared_scene(0, False, "photos")
    sampler = FixationSampler(model, seed=seed, surroundings=RoomSurfaces(scene))
    rng = np.random.default_rng(seed + 1)
    out = []
    with StereoRenderer(model, scene, parallel=False) as renderer:
        while len(out) < count:
            sample = sampler.draw()
            landed = model.limits.clamp(sampler.pose + np.r_[rng.normal(0.0, landing_deg, 2), 0.0])
            before = as_grey_float(renderer.render(joints_of(sample.pose_before))[0])
            after = as_grey_float(renderer.render(joints_of(landed))[0])
            x, y = (float(v) for v in sample.position[:2])
            if patch_problem(before, (x, y), LookParams()):
                continue  # a look refuses such a target before the head moves
            out.append(Case(before, (x, y), after))
    return out


def run(module: types.ModuleType, case: Case, params: Any, warps: list[np.ndarray] | None) -> tuple[Any, float]:
    started = time.perf_counter()
    sighting, _ = module.find_target(case.before, case.xy, case.after, params, warps, 1.0)
    return sighting, time.perf_counter() - started


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--cases", type=int, default=60)
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--landing-deg", type=float, default=0.15,
                        help="the saccade's landing error, pan and tilt, normal (deg, default 0.15)")
    parser.add_argument("--baseline", help="also time find_target as it is at this git revision")
    args = parser.parse_args()
    print(f"load average at start: {' '.join(f'{x:.2f}' for x in os.getloadavg())}")
    views = cases(args.cases, args.seed, args.landing_deg)
    variants: dict[str, tuple[types.ModuleType, Any]] = {"working tree": (refind, LookParams())}
    if args.baseline:
        old = baseline_module(args.baseline, "gaze.refind")
        variants[args.baseline] = (old, baseline_module(args.baseline, "gaze.fixation").LookParams())
    first: dict[str, list[float]] = {name: [] for name in variants}
    later: dict[str, list[float]] = {name: [] for name in variants}
    found: dict[str, list[Any]] = {name: [None] * len(views) for name in variants}
    for module, params in variants.values():
        run(module, views[0], params, None)  # warm up
    for _ in range(args.rounds):
        for name, (module, params) in variants.items():
            for k, case in enumerate(views):
                sighting, seconds = run(module, case, params, None)
                first[name].append(seconds)
                found[name][k] = sighting
                if sighting is not None:
                    later[name].append(run(module, case, params, [sighting.warp])[1])
    print(f"{len(views)} targets, {args.rounds} rounds; load average at end: "
          f"{' '.join(f'{x:.2f}' for x in os.getloadavg())}")
    print("| find_target, ms | first search: median | p25 | p90 | corrective search: median | found |")
    print("| --- | --- | --- | --- | --- | --- |")
    for name in variants:
        f, c = 1e3 * np.asarray(first[name]), 1e3 * np.asarray(later[name])
        print(f"| {name} | {np.median(f):.1f} | {np.percentile(f, 25):.1f} | {np.percentile(f, 90):.1f} | "
              f"{np.median(c):.1f} | {sum(s is not None for s in found[name])} of {len(views)} |")
    if args.baseline:
        ours, theirs = found["working tree"], found[args.baseline]
        same = sum((a is None) == (b is None) and (a is None or np.hypot(a.x - b.x, a.y - b.y) <= 0.01)
                   for a, b in zip(ours, theirs))
        print(f"answers the same as {args.baseline}'s (both refused, or within 0.01 px): {same} of {len(views)}")


if __name__ == "__main__":
    main()
