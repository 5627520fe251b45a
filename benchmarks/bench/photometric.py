"""Benchmark: correspondence and confidence when the target's brightness and contrast differ
between the pre- and post-fixation images (an auto exposure or gain that followed the view).

Rendered saccades (`headctl.experiments.saccades`: random saccades of up to +-15 deg, sensor
noise of 2 grey levels) in the photo room; each post-fixation image is changed by a gain
about black and an offset, post' = clip(gain * post + offset, 0, 255), as a sensor's gain or
exposure and a shift of its black level change it, saturation included. Per condition
(gains 1/1.4, 1/1.2, 1, 1.2, 1.4 and offsets -10, 0, +10 grey levels) and variant, on the
textured foveal patches: the share matched within 1 px; of the matches accepted (per-eye
confidence >= 0.3), the share wrong by more than 3 px; of the right ones (within 1 px), the
share accepted. Variants: the default profile (which compensates the change,
`calib_free.correspondence.photometric`), the paper's eqs. 1-7, and the default profile on
plain NCC (`use_factors: false`); `--baseline REV` adds the default profile as at git
revision REV. Each figure is the median [interquartile range] over `--seeds` scene seeds, the
same cases for every variant and condition.

    .venv/bin/python -m benchmarks.bench.photometric [--saccades 60] [--seeds 5] [--width 640]
        [--room photos] [--baseline REV]
"""
from __future__ import annotations

import argparse
import os
import types
from collections.abc import Callable
from typing import Any

import numpy as np

from benchmarks.bench.fixation import load_baseline, scored
from calib_free.correspondence import search as correspondence
from calib_free.correspondence.photometric import brightness_change
from calib_free.sim.head_model import HeadModel, JointLimits
from drivers.sim.scene import shared_scene
from headctl.experiments.saccades import SaccadeCase, accuracy, saccade_cases

GAINS = (1 / 1.4, 1 / 1.2, 1.0, 1.2, 1.4)
OFFSETS = (-10.0, 0.0, 10.0)
TARGETS = "targets (default): >= 95 % within 1 px, <= 1 % of the accepted wrong by > 3 px, >= 85 % of the right accepted"


def changed(image: np.ndarray, gain: float, offset: float) -> np.ndarray:
    """`image` (uint8) as a sensor with `gain` times the signal and `offset` more black level gives it."""
    return np.clip(np.rint(image.astype(np.float32) * gain + offset), 0, 255).astype(np.uint8)


def with_change(cases: list[SaccadeCase], gain: float, offset: float) -> list[SaccadeCase]:
    return [SaccadeCase(c.pre, changed(c.post, gain, offset), c.truth, c.eye, c.texture, c.patch_std) for c in cases]


def variants(baseline: types.ModuleType | None, rev: str) -> dict[str, tuple[Callable[..., Any], Any]]:
    params = correspondence.CorrespondenceParams
    out: dict[str, tuple[Callable[..., Any], Any]] = {
        "default": (correspondence.match_eye, params()),
        "paper": (correspondence.match_eye, params.profile_values("paper")),
        "plain NCC": (correspondence.match_eye, params(use_factors=False)),
    }
    if baseline is not None:
        out[f"default@{rev}"] = (baseline.match_eye, baseline.CorrespondenceParams())
    return out


def quartiles(values: list[float]) -> str:
    q1, q2, q3 = np.percentile(values, [25, 50, 75])
    return f"{100 * q2:5.1f} [{100 * q1:5.1f}-{100 * q3:5.1f}]"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--saccades", type=int, default=60, help="saccades per seed (two eyes each)")
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--width", type=int, default=640, choices=(320, 640))
    parser.add_argument("--room", default="photos", choices=("photos", "generated"))
    parser.add_argument("--baseline", metavar="REV", default=None,
                        help="also the default profile as at this git revision")
    args = parser.parse_args()
    baseline = load_baseline(args.baseline) if args.baseline else None
    timed = variants(baseline, args.baseline or "")
    width, height = args.width, args.width * 3 // 4
    model = HeadModel.default(width, height, limits=JointLimits(vergence=(1.0, 20.0)))
    conditions = [(g, o) for g in GAINS for o in OFFSETS]
    # figures[condition][variant] -> per seed (within 1 px, accepted wrong, right accepted)
    figures: dict[tuple[float, float], dict[str, list[tuple[float, float, float]]]] = {
        c: {name: [] for name in timed} for c in conditions}
    gain_error: dict[tuple[float, float], list[float]] = {c: [] for c in conditions}
    counts = []
    print(f"load average at start: {' '.join(f'{x:.2f}' for x in os.getloadavg())}")
    for seed in range(args.seeds):
        cases = saccade_cases_of(model, args.room, args.saccades, seed)
        counts.append(sum(c.textured for c in cases))
        for gain, offset in conditions:
            trial = with_change(cases, gain, offset)
            for name, (match_eye, params) in timed.items():
                a = accuracy(list(scored(trial, match_eye, params)))
                figures[(gain, offset)][name].append((a.within_1px, a.wrong_accepted, a.right_accepted))
            p = correspondence.CorrespondenceParams()
            gain_error[(gain, offset)] += [brightness_change(c.pre, c.post, p.max_gain, p.max_offset).gain / gain - 1
                                           for c in trial if c.textured]
    print(f"{args.room} room, {width}x{height}, {args.saccades} saccades x {args.seeds} seeds "
          f"({min(counts)}-{max(counts)} textured foveal patches a seed); median [IQR] over the seeds, %")
    name_width = max(len(n) for n in timed)
    print(f"{'gain':>6} {'offset':>6}  {'variant':<{name_width}}  {'within 1 px':>19}  {'accepted, wrong > 3 px':>22}"
          f"  {'right, accepted':>19}")
    for (gain, offset), by_variant in figures.items():
        for name, rows in by_variant.items():
            within, wrong, right = zip(*rows)
            print(f"{gain:6.3f} {offset:+6.0f}  {name:<{name_width}}  {quartiles(list(within)):>19}  "
                  f"{quartiles(list(wrong)):>22}  {quartiles(list(right)):>19}")
    print("the default profile's estimated gain / true gain - 1, textured cases, p10 / p50 / p90 (%):")
    for (gain, offset), errors in gain_error.items():
        p10, p50, p90 = np.percentile(errors, [10, 50, 90])
        print(f"  gain {gain:.3f} offset {offset:+.0f}: {100 * p10:+.1f} / {100 * p50:+.1f} / {100 * p90:+.1f}")
    print(TARGETS)
    print(f"load average at end: {' '.join(f'{x:.2f}' for x in os.getloadavg())}")


def saccade_cases_of(model: HeadModel, room: str, saccades: int, seed: int) -> list[SaccadeCase]:
    """One seed's cases: the room of scene seed `seed`, its own saccades."""
    return saccade_cases(shared_scene(seed, False, room), model, saccades, seed=100 + seed)


if __name__ == "__main__":
    main()
