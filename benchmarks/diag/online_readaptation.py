"""Diagnostic: where in the image an online re-adaptation's retinal error stays up.

Runs an online experiment with a change (`online-prism` by default) for each seed, logging
every adaptation (`GazeMap.adapt` wrapped: the run is the one `headctl experiment` makes), and
prints, by the sample's distance from the fovea's row, before the change (the 200 adaptations
before it) and over the last 200: how many samples, the median retinal error (eq. 8: through
the map's inverse, where the map sends the command), how many are above 5 %, and the median
output error (the map's command for the sample's position against the command that fixated
it, per axis): a high retinal error with a low output error is the inverse lookup, not the map.

    .venv/bin/python -m benchmarks.diag.online_readaptation [--experiment online-prism] [--seeds 1,3]
"""
from __future__ import annotations

import argparse
import sys
from typing import Any

import numpy as np

from calib_free.map.gaze_map import GazeMap
from headctl.experiments.online import ONLINE_EXPERIMENTS, run_online

BANDS_PX = ((0, 30), (30, 50), (50, 70), (70, 1000))
IMAGE_HEIGHT = 240  # run_online's default image size is 320 x 240


def logged_run(name: str, seed: int) -> tuple[list[tuple[np.ndarray, float, np.ndarray]], int]:
    """Every accepted adaptation's (position, retinal error, output error), and how many came
    before the change."""
    log: list[tuple[np.ndarray, float, np.ndarray]] = []
    adapt = GazeMap.adapt

    def logging_adapt(self: GazeMap, *args: Any, **kwargs: Any) -> Any:
        result = adapt(self, *args, **kwargs)
        if result.accepted:
            log.append((np.asarray(args[0], dtype=float), result.retinal_error, np.asarray(result.output_error)))
        return result

    GazeMap.adapt = logging_adapt  # type: ignore[method-assign]
    try:
        result = run_online(ONLINE_EXPERIMENTS[name], seed=seed)
    finally:
        GazeMap.adapt = adapt  # type: ignore[method-assign]
    return log, int(result.as_experiment_result().spec.changes[0].at)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--experiment", default="online-prism", choices=[n for n, s in ONLINE_EXPERIMENTS.items()
                                                                         if s.changes])
    parser.add_argument("--seeds", default="1,3")
    args = parser.parse_args()
    for seed in (int(s) for s in args.seeds.split(",")):
        log, at = logged_run(args.experiment, seed)
        rows = np.array([p[1] for p, _, _ in log])
        retinal = np.array([e for _, e, _ in log])
        output = np.array([o for _, _, o in log])
        print(f"{args.experiment} seed {seed}: {len(log)} adaptations, the change at {at}")
        for part, window in (("before", slice(max(0, at - 200), at)), ("last 200", slice(len(log) - 200, len(log)))):
            off_row = np.abs(rows[window] - (IMAGE_HEIGHT - 1) / 2.0)
            for low, high in BANDS_PX:
                band = (off_row >= low) & (off_row < high)
                if not band.any():
                    continue
                e, o = retinal[window][band], output[window][band]
                print(f"  {part:<8} {low:>2}-{high if high < 1000 else '':<3} px from the fovea's row: n={band.sum():>3}, "
                      f"retinal median {100 * np.median(e):.2f} %, above 5 %: {int(np.sum(e > 0.05)):>2}, "
                      f"output error median {np.round(np.median(o, axis=0), 2)} deg")
    return 0


if __name__ == "__main__":
    sys.exit(main())
