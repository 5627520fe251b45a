"""Benchmark: correspondence + confidence per stereo pair, its accuracy, and the whole
simulated fixation cycle.

1. `match_fixation` (both eyes) on rendered fish-eye pairs of the photo room at 320 x 240
   and 640 x 480: the default profile (context search, distinctiveness, backward check),
   the paper's eqs. 1-7, and eqs. 1-7 with the exhaustive full-resolution search, measured
   in the same run.
2. Accuracy (`--accuracy N`: N random saccades of up to +-15 deg per room and size, sensor
   noise of 2 grey levels; a scene seed and saccades other than the tests'): of the textured
   foveal patches, the share matched within 1 px; of the matches accepted (per-eye confidence
   >= 0.3), the share wrong by more than 3 px; of the right ones, the share accepted. For
   both profiles on the same pairs, in the photo room and the generated room.
3. Fixations per second of the simulated head (servo motion model on a manual clock,
   rendering, fine vergence, correspondence, the adapter thread), from a random map.

    .venv/bin/python benchmarks/bench_fixation.py [--pairs 30] [--fixations 200] [--accuracy 0]
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # tests.support, from a checkout

from calib_free import GazeMap  # noqa: E402
from calib_free.adapter import MapAdapter, Sample  # noqa: E402
from calib_free.correspondence import CorrespondenceParams, match_fixation  # noqa: E402
from calib_free.fixation import FixationController  # noqa: E402
from calib_free.kinematics import joints_of  # noqa: E402
from calib_free.sim import HeadModel, JointLimits  # noqa: E402
from drivers.sim_scene import StereoRenderer, shared_scene  # noqa: E402
from headctl.online import SimulatedHeadRig  # noqa: E402
from tests.support.saccade_pairs import accuracy as accuracy_of, saccade_cases, scored  # noqa: E402

PAPER = CorrespondenceParams.profile_values("paper")


def rendered_pairs(width: int, height: int, count: int, seed: int = 0,
                   room: str = "photos") -> list[tuple[np.ndarray, ...]]:
    model = HeadModel.default(width, height)
    rng = np.random.default_rng(seed)
    pairs = []
    with StereoRenderer(model, shared_scene(0, False, room), parallel=False) as renderer:
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


def accuracy(saccades: int) -> None:
    """The figures of item 2 of the module doc, one line per room, size and profile."""
    print(f"correspondence accuracy, {saccades} saccades per room and size (textured foveal patches)")
    for room in ("photos", "generated"):
        for width, height in ((320, 240), (640, 480)):
            model = HeadModel.default(width, height, limits=JointLimits(vergence=(1.0, 20.0)))
            cases = saccade_cases(shared_scene(5, False, room), model, saccades, seed=71)
            for name, params in (("default", CorrespondenceParams()), ("paper", PAPER)):
                print(f"  {room:<9} {width}x{height} {name:<8} {accuracy_of(list(scored(cases, params))).line()}")
    print("goal (photo room, default): >= 97 % within 1 px, <= 1 % of the accepted wrong by > 3 px, "
          ">= 85 % of the right ones accepted")


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
    parser.add_argument("--accuracy", type=int, default=0, help="saccades per room and size (0: skip)")
    args = parser.parse_args()

    print("correspondence + confidence, one stereo pair (both eyes) of the photo room, median ms")
    print(f"{'size':<10}{'default':>10}{'paper':>10}{'paper, exhaustive':>19}")
    for width, height in ((320, 240), (640, 480)):
        pairs = rendered_pairs(width, height, args.pairs)
        default = ms_per_pair(pairs, CorrespondenceParams())
        paper = ms_per_pair(pairs, PAPER)
        exhaustive = ms_per_pair(pairs, CorrespondenceParams.profile_values("paper", pyramid_levels=0))
        print(f"{width}x{height:<6}{default:>10.2f}{paper:>10.2f}{exhaustive:>19.2f}")
    print("goal at 640x480: <= 3 ms (default)")
    if args.accuracy:
        accuracy(args.accuracy)
    rate, taught_rate = fixations_per_s(args.fixations)
    print(f"simulated fixation cycle, 320x240: {rate:.1f} fixations/s ({taught_rate:.1f} taught/s); "
          f"goal >= 20 -> {'met' if rate >= 20 else 'NOT met'}")


if __name__ == "__main__":
    main()
