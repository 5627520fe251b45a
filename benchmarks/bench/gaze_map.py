"""Benchmark: GazeMap.adapt calls per second on the full 100 x 75 x 21 grid.

A 2,000-fixation learning run from random initialisation (the samples are drawn before the
clock starts), for both profiles (the default one with and without the head's pose on each
sample), beside a naive baseline measured in the same run: the
paper's rule written the obvious numpy way, a Gaussian over the whole grid and a brute-force
nearest-node inverse lookup on every adaptation.

Each rate is given by the wall clock and by the process's CPU time: on a machine loaded by
other work the wall-clock rate depends on how much of a core the scheduler gives, the CPU-time
rate much less (it still pays for shared caches). The load average is printed with them.

    .venv/bin/python -m benchmarks.bench.gaze_map [--fixations 2000] [--baseline-fixations 200]
"""
from __future__ import annotations

import argparse
import os
import time

import numpy as np

from calib_free.map.gaze_map import GazeMap
from calib_free.sim.head_model import FixationSampler, HeadModel


class NaiveFullGridMap:
    """Eqs. 8-11 on every node each time: what the issue calls the naive full-grid update."""

    def __init__(self, reference: GazeMap) -> None:
        self.ref = reference
        self.grid = reference.node_values().copy()  # (nx, ny, nd, 3)
        shape = reference.params.grid_shape
        self.axes = [np.arange(n, dtype=float) for n in shape]
        self.errors: list[float] = []

    def adapt(self, position, command, confidence=1.0) -> float:
        ref = self.ref
        g = ref.to_grid(position)
        scale = ref._motor_scale
        dist = (((self.grid - command) * scale) ** 2).sum(axis=-1)
        node = np.array(np.unravel_index(np.argmin(dist), dist.shape))
        error = ref.retinal_error(position, ref.to_position(node))
        self.errors = (self.errors + [error])[-ref.params.error_window:]
        sigma = ref.sigma_cells(float(np.mean(self.errors)))
        gx, gy, gd = (np.exp(-0.5 * ((ax - c) / s) ** 2) for ax, c, s in zip(self.axes, g, sigma))
        gauss = gx[:, None, None] * gy[None, :, None] * gd[None, None, :]
        self.grid += ref.params.adaptation_rate * confidence * gauss[..., None] * (command - self.grid)
        return error


def timed(adapt, samples, pose: bool = False) -> tuple[float, float]:
    """Adaptations per second of wall-clock time and of the process's CPU time."""
    started, started_cpu = time.perf_counter(), time.process_time()
    if pose:
        for s in samples:
            adapt(s.position, s.command, 1.0, pose=s.pose_before)
    else:
        for s in samples:
            adapt(s.position, s.command, 1.0)
    wall_s, cpu_s = time.perf_counter() - started, time.process_time() - started_cpu
    return len(samples) / wall_s, len(samples) / max(cpu_s, 1e-9)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--fixations", type=int, default=2000)
    parser.add_argument("--baseline-fixations", type=int, default=200)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()

    sampler = FixationSampler(HeadModel.default(320, 240), (-60, 60), seed=args.seed)
    samples = [sampler.draw() for _ in range(args.fixations)]

    started = time.perf_counter()
    warm = GazeMap.for_image(320, 240, seed=99)
    warm.adapt(samples[0].position, samples[0].command)  # compiles the kernels (or loads the cache)
    compile_s = time.perf_counter() - started

    rates = {}
    for name, profile, pose in (("default", "default", False), ("default + pose", "default", True),
                                ("paper", "paper", False)):
        gm = GazeMap.for_image(320, 240, seed=args.seed, profile=profile)
        rates[name] = timed(gm.adapt, samples, pose)
    naive = NaiveFullGridMap(GazeMap.for_image(320, 240, seed=args.seed, profile="paper"))
    rates["naive full grid"] = timed(naive.adapt, samples[:args.baseline_fixations])

    print(f"GazeMap.adapt on the full 100 x 75 x 21 grid, {args.fixations}-fixation run "
          f"(first call, kernel compile or cache load: {compile_s:.2f} s); load average "
          + ", ".join(f"{v:.2f}" for v in os.getloadavg()))
    naive_wall, naive_cpu = rates["naive full grid"]
    print(f"{'variant':<18}{'adapt/s':>10}{'x naive':>10}{'CPU adapt/s':>14}{'x naive':>10}")
    for name, (wall, cpu) in rates.items():
        print(f"{name:<18}{wall:>10.0f}{wall / naive_wall:>10.1f}{cpu:>14.0f}{cpu / naive_cpu:>10.1f}")
    for clock, column in (("wall clock", 0), ("CPU time", 1)):
        print(f"goal: >= 2000 adapt/s ({clock}) -> " + ", ".join(
            f"{name} {'met' if rates[name][column] >= 2000 else 'NOT met'}"
            for name in ("default", "default + pose", "paper")))


if __name__ == "__main__":
    main()
