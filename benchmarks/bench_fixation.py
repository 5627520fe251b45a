"""Benchmark: correspondence + confidence per stereo pair, and the whole simulated fixation cycle.

1. `match_fixation` (both eyes: eq. 1 over the whole image, eqs. 4-7) on rendered fish-eye
   pairs at 320 x 240 and 640 x 480, beside the exhaustive full-resolution search measured
   in the same run (the default searches coarse-to-fine above 400 px width).
2. Fixations per second of the simulated head (servo motion model on a manual clock,
   rendering, fine vergence, correspondence, the adapter thread), from a random map.

    .venv/bin/python benchmarks/bench_fixation.py [--pairs 30] [--fixations 200]
"""
from __future__ import annotations

import argparse
import time

import numpy as np

from calib_free import GazeMap
from calib_free.adapter import MapAdapter, Sample
from calib_free.correspondence import CorrespondenceParams, match_fixation
from calib_free.fixation import FixationController
from calib_free.kinematics import joints_of
from calib_free.sim import HeadModel
from drivers.sim_scene import StereoRenderer, shared_scene
from headctl.online import SimulatedHeadRig


def rendered_pairs(width: int, height: int, count: int, seed: int = 0) -> list[tuple[np.ndarray, ...]]:
    model = HeadModel.default(width, height)
    rng = np.random.default_rng(seed)
    pairs = []
    with StereoRenderer(model, shared_scene(0, False), parallel=False) as renderer:
        for _ in range(count):
            pre = rng.uniform(model.limits.low, model.limits.high)
            post = model.limits.clamp(pre + np.r_[rng.uniform(-15, 15, 2), 0.0])
            pairs.append(renderer.render(joints_of(pre)) + renderer.render(joints_of(post)))
    return pairs


def ms_per_pair(pairs, params: CorrespondenceParams) -> float:
    match_fixation(*pairs[0], params=params)  # warm up OpenCV
    times = []
    for pre_l, pre_r, post_l, post_r in pairs:
        started = time.perf_counter()
        match_fixation(pre_l, pre_r, post_l, post_r, params)
        times.append(time.perf_counter() - started)
    return 1e3 * float(np.median(times))


def fixations_per_s(count: int) -> tuple[float, float]:
    gm = GazeMap.for_image(320, 240, seed=0)
    taught = 0
    with SimulatedHeadRig(seed=0) as rig, MapAdapter(gm) as adapter:
        controller = FixationController(rig.head, adapter, rig.fixation, seed=1, clock=rig.clock.monotonic)
        controller.fixate()  # warm up
        started = time.perf_counter()
        for n in range(count):
            record = controller.fixate()
            if record.taught:
                taught += 1
                adapter.submit(Sample(record.position, record.executed, record.confidence, n))
        elapsed = time.perf_counter() - started
        adapter.wait_idle()
    return count / elapsed, taught / elapsed


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--pairs", type=int, default=30)
    parser.add_argument("--fixations", type=int, default=200)
    args = parser.parse_args()

    print("correspondence + confidence, one stereo pair (both eyes), median ms")
    print(f"{'size':<10}{'default':>10}{'exhaustive':>12}{'speed-up':>10}")
    for width, height in ((320, 240), (640, 480)):
        pairs = rendered_pairs(width, height, args.pairs)
        default = ms_per_pair(pairs, CorrespondenceParams())
        exhaustive = ms_per_pair(pairs, CorrespondenceParams(pyramid_levels=0))
        print(f"{width}x{height:<6}{default:>10.2f}{exhaustive:>12.2f}{exhaustive / default:>10.1f}")
    print("goal at 640x480: <= 5 ms")
    rate, taught_rate = fixations_per_s(args.fixations)
    print(f"simulated fixation cycle, 320x240: {rate:.1f} fixations/s ({taught_rate:.1f} taught/s); "
          f"goal >= 20 -> {'met' if rate >= 20 else 'NOT met'}")


if __name__ == "__main__":
    main()
