"""Diagnostic: the own-view ambiguity margin of recorded looks' target patches, plain and tried at nearby scales.

A target on a finely repeated texture can pass the own-view check (its patch's best other
place within the search radius at least `ambiguity_ncc_margin` below its own) and fail after
the saccade as ambiguous: at the fovea the lens shows the repeats about alike, where in the
periphery it magnified them unequally. This reads the looks that `benchmarks.diag.look_steps`
recorded with `--images`, and for each look taken on prints the margin of its 21 px patch in
its own view two ways: plain (the patch as it is), and scaled (the best other place over the
patch also resampled at `--scales`, isotropic and along the radius from the image centre, each
against its own place at scale 1). Then, for a few thresholds, how many looks each margin
would refuse: of those that ended on target, and of those that failed as ambiguous.

    .venv/bin/python -m benchmarks.diag.scaled_own_view --steps runs/steps.json --images DIR
        [--steps ... --images ...] [--scales 0.9,0.95,1.05,1.1]
"""
from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from benchmarks.diag.look_steps import recording_arguments, recordings, saved_first_searches
from calib_free.gaze.fixation import LookParams
from calib_free.gaze.refind import fovea, second_peak, warped_patch
from calib_free.gaze.target_patch import own_view_window

THRESHOLDS = (0.05, 0.075, 0.1, 0.125, 0.15)


def own_view_margins(source: np.ndarray, xy: tuple[float, float], scales: tuple[float, ...],
                     size: int = 21, radius_px: int | None = None) -> tuple[float, float] | None:
    """(plain, scaled) own-view margins of the `size` px patch about `xy` in `source` (see the
    module doc), searched within `radius_px` of it (default a third of the width, as the look
    does); None where the patch reaches beyond the image or is flat."""
    image = source.astype(np.float32)
    window = own_view_window(image, xy, LookParams(target_patch_size=(size, size), search_radius_px=radius_px))
    plain = warped_patch(image, xy, np.eye(2), (size, size))
    if plain is None or float(plain.std()) < 1.0:
        return None
    scores = np.nan_to_num(cv2.matchTemplate(window, plain, cv2.TM_CCOEFF_NORMED))
    _, peak, _, (ix, iy) = cv2.minMaxLoc(scores)
    other = second_peak(scores, ix, iy, size / 2)
    best_other = other
    offset = np.asarray(xy, dtype=float) - np.asarray(fovea(image))
    norm = float(np.hypot(*offset))
    radial = offset / norm if norm > 1.0 else np.array([1.0, 0.0])
    rotation = np.column_stack([radial, [-radial[1], radial[0]]])
    for scale in scales:
        for warp in (np.diag([scale, scale]), rotation @ np.diag([scale, 1.0]) @ rotation.T):
            template = warped_patch(image, xy, warp, (size, size))
            if template is None:
                continue
            scaled = np.nan_to_num(cv2.matchTemplate(window, template, cv2.TM_CCOEFF_NORMED))
            best_other = max(best_other, second_peak(scaled, ix, iy, size / 2))
    return float(peak - other), float(peak - best_other)


def recorded_margins(steps_json: Path, images: Path, scales: tuple[float, ...]) -> list[dict[str, Any]]:
    """One row a look taken on whose first search was saved: whether it ended on target, whether
    it failed as ambiguous, and its two margins."""
    rows = []
    for look, _, _, saved in saved_first_searches(steps_json, images):
        margins = own_view_margins(saved["source"], tuple(saved["source_xy"]), scales,
                                   LookParams().target_patch_size[0])
        if margins is None:
            continue
        rows.append({"on_target": bool(look["on_target"]),
                     "ambiguous": not look["on_target"] and "ambiguous" in (look.get("detail") or ""),
                     "plain": margins[0], "scaled": margins[1]})
    return rows


def refusals(rows: list[dict[str, Any]], key: str, threshold: float) -> tuple[int, int]:
    """How many looks a margin `key` below `threshold` would refuse: (on target, failed as ambiguous)."""
    below = [r for r in rows if r[key] < threshold]
    return sum(r["on_target"] for r in below), sum(r["ambiguous"] for r in below)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    recording_arguments(parser)
    parser.add_argument("--scales", default="0.9,0.95,1.05,1.1", help="the scales tried beside 1 (comma-separated)")
    args = parser.parse_args(argv)
    pairs = recordings(parser, args)
    try:
        scales = tuple(float(v) for v in args.scales.split(","))
    except ValueError:
        parser.error(f"--scales: expected numbers separated by commas, got {args.scales!r}")
    rows: list[dict[str, Any]] = []
    for steps_json, images in pairs:
        rows += recorded_margins(steps_json, images, scales)
    on, ambiguous = sum(r["on_target"] for r in rows), sum(r["ambiguous"] for r in rows)
    print(f"{len(rows)} looks taken on: {on} on target, {ambiguous} failed as ambiguous")
    print("margins of those that failed as ambiguous (plain, scaled): "
          + ", ".join(f"({r['plain']:.3f}, {r['scaled']:.3f})" for r in rows if r["ambiguous"]))
    print(f"{'margin below':>12}  {'plain: on target, ambiguous':>28}  {'scaled: on target, ambiguous':>29}")
    for threshold in THRESHOLDS:
        plain, scaled = refusals(rows, "plain", threshold), refusals(rows, "scaled", threshold)
        print(f"{threshold:>12}  {plain[0]:>18}, {plain[1]:>8}  {scaled[0]:>19}, {scaled[1]:>8}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
