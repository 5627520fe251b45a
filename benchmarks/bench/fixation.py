"""Benchmark: correspondence + confidence per stereo pair, its accuracy, and the whole
simulated fixation cycle.

1. `match_fixation` (both eyes) on rendered fish-eye pairs of the photo room at 320 x 240
   and 640 x 480: the default profile (context search, distinctiveness, backward check),
   the paper's eqs. 1-7, and eqs. 1-7 with the exhaustive full-resolution search, measured
   in the same run, in `--rounds` interleaved rounds: the median and lower quartile of the
   wall time a pair, and the median CPU time of one eye's `match_eye` on its thread (which
   other work on the machine barely changes).
2. Accuracy (`--accuracy N`: N random saccades of up to +-15 deg per room and size, sensor
   noise of 2 grey levels; a scene seed and saccades other than the tests'): of the textured
   foveal patches, the share matched within 1 px; of the matches accepted (per-eye confidence
   >= 0.3), the share wrong by more than 3 px; of the right ones, the share accepted. For
   both profiles on the same pairs, in the photo room and the generated room.
3. The match's bias (`--bias N`: N saccades per room as in item 2, at 320 x 240): its error
   along the radius from the image centre, by the truth's eccentricity, with the affine and
   the quadratic alignment (`alignment_warp`); a bias the same way every time is learned by
   the map as if it were the head's.
4. Fixations per second of the simulated head of `--config` (default: the packaged
   sim.yaml; servo motion model on a manual clock, rendering through its cameras' sensor,
   fine vergence, correspondence, the adapter thread), from a random map: with the eyes
   rendered in turn on the caller's thread, then with the right eye on a thread of its own
   (`SimulatedHeadRig(parallel_eyes=True)`), the same fixations; first, the wall time of one
   pair of those cameras rendered both ways.

`--baseline REV` also loads the correspondence (with the rest of `calib_free`) as it is at
the git revision REV and measures it beside the working tree's in items 1 and 2, on the same
pairs in the same run (so that a change is judged on one machine state). 0 for `--pairs`, `--fixations`,
`--accuracy` or `--bias` skips that item.

    .venv/bin/python -m benchmarks.bench.fixation [--pairs 30] [--rounds 3] [--fixations 200]
        [--accuracy 0] [--bias 0] [--baseline HEAD] [--config configs/sim-ideal.yaml]
"""
from __future__ import annotations

import argparse
import importlib
import os
import sys
import time
import types
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.support.baseline import baseline_package
from benchmarks.support.image_error import radial_tangential_error
from calib_free.map.gaze_map import GazeMap
from calib_free.correspondence import search as correspondence
from calib_free.map.adapter import MapAdapter, Sample
from calib_free.gaze.fixation import FixationController
from headctl.service.head import joints_of
from calib_free.sim.head_model import HeadModel, JointLimits
from drivers.sim.scene import StereoRenderer, shared_scene
from headctl.config.head import DEFAULT_CONFIG, load_config
from headctl.experiments.online import SimulatedHeadRig
from headctl.experiments.saccades import SaccadeCase, Scored, saccade_cases
from headctl.experiments.saccades import accuracy as accuracy_of

def load_baseline(rev: str) -> types.ModuleType:
    """`calib_free.correspondence.search` as it is at git revision `rev`
    (`benchmarks.support.baseline`): the baseline runs with its own alignment, kernels and
    helpers beside the working tree's."""
    package = baseline_package(rev)
    # a revision with the package `calib_free/correspondence/` has the search in its `search.py`; others in
    # the module `calib_free/correspondence.py`
    nested = (package / "correspondence" / "search.py").exists()
    return importlib.import_module("calib_free_baseline.correspondence" + (".search" if nested else ""))


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


def variants(baseline: types.ModuleType | None, rev: str) -> dict[str, tuple[types.ModuleType, Any]]:
    """name -> (the correspondence module, its parameters) of every variant timed."""
    params = correspondence.CorrespondenceParams
    out: dict[str, tuple[types.ModuleType, Any]] = {
        "default": (correspondence, params()),
        "paper": (correspondence, params.profile_values("paper")),
        "paper, exhaustive": (correspondence, params.profile_values("paper", pyramid_levels=0)),
    }
    if baseline is not None:
        out[f"default@{rev}"] = (baseline, baseline.CorrespondenceParams())
        out[f"paper@{rev}"] = (baseline, baseline.CorrespondenceParams.profile_values("paper"))
    return out


def timings(pairs: list[tuple[np.ndarray, ...]], timed: dict[str, tuple[types.ModuleType, Any]],
            rounds: int) -> dict[str, tuple[float, float, float]]:
    """Per variant: the median and lower quartile of `match_fixation`'s wall time a pair, and
    the median CPU time of one eye's `match_eye` (its thread's: what the eye costs, whatever
    else runs on the machine), ms. The variants are interleaved round by round, so that the
    machine's load changes touch them alike."""
    wall: dict[str, list[float]] = {name: [] for name in timed}
    cpu: dict[str, list[float]] = {name: [] for name in timed}
    for module, params in timed.values():
        module.match_fixation(*pairs[0], params=params)  # warm up OpenCV and the thread pool
    for _ in range(rounds):
        for name, (module, params) in timed.items():
            for pre_l, pre_r, post_l, post_r in pairs:
                started = time.perf_counter()
                module.match_fixation(pre_l, pre_r, post_l, post_r, params)
                wall[name].append(time.perf_counter() - started)
            for pre_l, pre_r, post_l, post_r in pairs:
                for pre, post in ((pre_l, post_l), (pre_r, post_r)):
                    started = time.thread_time()
                    module.match_eye(pre, post, params)
                    cpu[name].append(time.thread_time() - started)
    return {name: (1e3 * float(np.median(wall[name])), 1e3 * float(np.percentile(wall[name], 25)),
                   1e3 * float(np.median(cpu[name]))) for name in timed}


def scored(cases: list[SaccadeCase], match_eye: Callable[..., Any], params: Any) -> Iterator[Scored]:
    for case in cases:
        m = match_eye(case.pre, case.post, params)
        yield Scored(case, m, float(np.hypot(m.x - case.truth[0], m.y - case.truth[1])))


def accuracy(saccades: int, baseline: types.ModuleType | None, rev: str) -> None:
    """The figures of item 2 of the module doc, one line per room, size and profile."""
    print(f"correspondence accuracy, {saccades} saccades per room and size (textured foveal patches)")
    profiles: list[tuple[str, Callable[..., Any], Any]] = [
        ("default", correspondence.match_eye, correspondence.CorrespondenceParams()),
        ("paper", correspondence.match_eye, correspondence.CorrespondenceParams.profile_values("paper"))]
    if baseline is not None:
        profiles += [(f"default@{rev}", baseline.match_eye, baseline.CorrespondenceParams()),
                     (f"paper@{rev}", baseline.match_eye, baseline.CorrespondenceParams.profile_values("paper"))]
    width_of_name = max(len(name) for name, _, _ in profiles)
    for room in ("photos", "generated"):
        for width, height in ((320, 240), (640, 480)):
            model = HeadModel.default(width, height, limits=JointLimits(vergence=(1.0, 20.0)))
            cases = saccade_cases(shared_scene(5, False, room), model, saccades, seed=71)
            for name, match_eye, params in profiles:
                line = accuracy_of(list(scored(cases, match_eye, params))).line()
                print(f"  {room:<9} {width}x{height} {name:<{width_of_name}} {line}")
    print("goal (photo room, default): >= 97 % within 1 px, <= 1 % of the accepted wrong by > 3 px, "
          ">= 85 % of the right ones accepted")


ECCENTRICITY_BANDS_PX = ((0, 30), (30, 60), (60, 90), (90, 1000))


def radial_bias(saccades: int) -> None:
    """Item 3 of the module doc: the match's error along the radius from the image centre, by
    eccentricity, for each alignment warp, at 320 x 240 (the online experiments' size)."""
    print(f"match error along the radius (positive: outwards) by the truth's eccentricity, {saccades} saccades "
          "per room, 320x240, textured foveal patches matched within 1.5 px: mean +- standard error [median |error|]")
    model = HeadModel.default(320, 240, limits=JointLimits(vergence=(1.0, 20.0)))
    centre = np.array([(320 - 1) / 2.0, (240 - 1) / 2.0])
    for room in ("photos", "generated"):
        cases = [c for c in saccade_cases(shared_scene(5, False, room), model, saccades, seed=71) if c.textured]
        for warp in ("affine", "quadratic"):
            params = correspondence.CorrespondenceParams(alignment_warp=warp)
            results = list(scored(cases, correspondence.match_eye, params))
            eccentricity, radial, _ = radial_tangential_error(np.array([(r.match.x, r.match.y) for r in results]),
                                                              np.array([r.case.truth for r in results]), centre)
            table = np.column_stack([eccentricity, radial, [r.error_px for r in results]])
            near = table[:, 2] <= 1.5
            cells = []
            for low, high in ECCENTRICITY_BANDS_PX:
                band = table[near & (table[:, 0] >= low) & (table[:, 0] < high)]
                if len(band):
                    cells.append(f"{low}-{high if high < 1000 else ''} px: {band[:, 1].mean():+.3f} +- "
                                 f"{band[:, 1].std() / np.sqrt(len(band)):.3f} [{np.median(band[:, 2]):.3f}] (n={len(band)})")
            print(f"  {room:<9} {warp:<9} within 1 px {np.mean(table[:, 2] <= 1.0):.1%}, median error "
                  f"{np.median(table[:, 2]):.3f} px; " + "; ".join(cells))


def fixations_per_s(count: int, config_path: Path | None = None, parallel_eyes: bool = False) -> tuple[float, float]:
    gm = GazeMap.for_image(320, 240, seed=0)
    taught = 0
    with (SimulatedHeadRig(seed=0, config=load_config(config_path), parallel_eyes=parallel_eyes) as rig,
          MapAdapter(gm) as adapter):
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


def pair_ms(count: int, config_path: Path | None = None, parallel_eyes: bool = False) -> float:
    """Median wall time (ms) of one pair rendered by the config's simulated cameras (sensor,
    compression, timing and room included), the head still, a frame period apart."""
    with SimulatedHeadRig(seed=0, config=load_config(config_path), parallel_eyes=parallel_eyes) as rig:
        world = rig.devices.world
        assert world is not None  # the rig builds only simulated heads
        joints = world.true_joints()
        rig.pairs.render(joints)  # warm up
        times = []
        for _ in range(count):
            rig.clock.sleep(1.0 / 30.0)
            started = time.perf_counter()
            rig.pairs.render(joints)
            times.append(time.perf_counter() - started)
    return 1e3 * float(np.median(times))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--pairs", type=int, default=30, help="stereo pairs timed per size (0: skip)")
    parser.add_argument("--rounds", type=int, default=3, help="interleaved rounds over the pairs")
    parser.add_argument("--fixations", type=int, default=200, help="simulated fixations (0: skip)")
    parser.add_argument("--accuracy", type=int, default=0, help="saccades per room and size (0: skip)")
    parser.add_argument("--bias", type=int, default=0, help="saccades per room for the radial bias (0: skip)")
    parser.add_argument("--baseline", metavar="REV", default=None,
                        help="also measure calib_free/correspondence/search.py as at this git revision")
    parser.add_argument("--config", type=Path, default=DEFAULT_CONFIG,
                        help="the simulated head of item 4 (default: the packaged sim.yaml, the realistic world)")
    args = parser.parse_args()
    baseline = load_baseline(args.baseline) if args.baseline else None
    rev = args.baseline or ""

    print(f"load average at start: {' '.join(f'{x:.2f}' for x in os.getloadavg())}")
    if args.pairs > 0:
        timed = variants(baseline, rev)
        header = f"{'size':<10}" + "".join(f"{name:>{max(10, len(name) + 2)}}" for name in timed)
        tables: list[list[str]] = [[], [], []]
        for width, height in ((320, 240), (640, 480)):
            ms = timings(rendered_pairs(width, height, args.pairs), timed, max(1, args.rounds))
            for k, table in enumerate(tables):
                table.append(f"{width}x{height:<6}" + "".join(f"{ms[name][k]:>{max(10, len(name) + 2)}.2f}"
                                                            for name in timed))
        titles = ["correspondence + confidence, one stereo pair (both eyes, `match_fixation`) of the photo room, "
                  f"median ms ({args.pairs} pairs x {args.rounds} rounds)",
                  "the same, lower quartile (less touched by other work on the machine)",
                  "one eye (`match_eye`), median CPU time of its thread, ms"]
        for title, table in zip(titles, tables):
            print("\n".join([title, header, *table]))
        print("goal at 640x480: <= 3 ms a pair (default, median)")
    if args.accuracy > 0:
        accuracy(args.accuracy, baseline, rev)
    if args.bias > 0:
        radial_bias(args.bias)
    if args.fixations > 0:
        # The eyes rendered one after the other (the baseline), then on two threads, in this run.
        in_turn, on_two = (pair_ms(60, args.config, parallel) for parallel in (False, True))
        print(f"one pair of {args.config.name}'s cameras, median of 60: {in_turn:.1f} ms in turn, "
              f"{on_two:.1f} ms on 2 threads")
        for parallel_eyes in (False, True):
            rate, taught_rate = fixations_per_s(args.fixations, args.config, parallel_eyes)
            how = "eyes rendered on 2 threads" if parallel_eyes else "eyes rendered in turn"
            print(f"simulated fixation cycle, 320x240, {args.config.name}, {how}: {rate:.1f} fixations/s "
                  f"({taught_rate:.1f} taught/s); goal >= 20 -> {'met' if rate >= 20 else 'NOT met'}")
    print(f"load average at end: {' '.join(f'{x:.2f}' for x in os.getloadavg())}")


if __name__ == "__main__":
    main()
