"""Diagnostic: the places a look's target patch matched when its first search was ambiguous, against the truth.

A look fails as "ambiguous" after its saccade where its target's patch matches two places of
the new image within `ambiguity_ncc_margin` of each other and nothing (a measured landing, the
view before the saccade) tells which is the target. This reads the looks that
`benchmarks.diag.look_steps` recorded with `--images`, takes those whose first search failed
so and whose first fixation's truth is known (where the target truly was, as an offset from
the fovea), and scores, with the patch as the best candidate warp shows it: the places
matching within `--margin` of the best, and the true place. Each is then scored again with the
warp fitted there (ECC, affine), as the search scores the place it takes, so that a place is
not ranked below another only because the candidate warp suits it less.

Printed per look: where the target truly was, how its true place scores (plain and fitted),
the nearest place to the truth, and the best fitted score of the places 3 px or more from it:
where those repeats score as high as the truth once fitted, nothing in the image after the
saccade tells the target from them; only where the saccade left it can.

Then what a prior about the fovea would do where no landing was measured: every recorded first
search without one searched again (`calib_free.gaze.refind.search_target`) as if the saccade
were known to leave the target within each `--fovea-reach` of the fovea, and the target it
finds, or its failure, set against the search as recorded and the truth (right within 1.5 px
of the true place, wrong beyond 3 px; in a recording without offsets, by the distance from the
fovea alone, which counts only some of the wrong ones).

    .venv/bin/python -m benchmarks.diag.ambiguous_places --steps runs/steps.json --images DIR
        [--steps ... --images ...] [--margin 0.15] [--fovea-reach 6,9,12]
"""
from __future__ import annotations

import argparse
import collections
import dataclasses
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from benchmarks.diag.look_steps import recording_arguments, recordings, saved_first_searches
from calib_free.correspondence.disparity import as_grey_float
from calib_free.gaze.fixation import LookParams
from calib_free.gaze.refind import (PRIOR_SIGMAS, _refine, candidate_warps, distinct_places, fovea, search_target,
                                    warped_patch)

REPEAT_PX = 3.0  # a place this far from the truth or farther is a repeat, not the target


def fitted_ncc(template: np.ndarray, image: np.ndarray, xy: tuple[float, float]) -> float | None:
    """NCC of `template` centred at `xy` in `image` with its warp fitted there (ECC); None
    where the fit did not converge or wandered more than 2 px."""
    h, w = template.shape
    fitted = _refine(template, image, xy[0] - (w - 1) / 2.0, xy[1] - (h - 1) / 2.0)
    if fitted is None or np.hypot(fitted[0][0] - xy[0], fitted[0][1] - xy[1]) > 2.0:
        return None
    return fitted[2]


def places_against_truth(source: np.ndarray, source_xy: tuple[float, float], image: np.ndarray,
                         size: tuple[int, int], truth_xy: tuple[float, float], margin: float,
                         max_places: int = 12) -> dict[str, Any] | None:
    """The places the patch of `size` about `source_xy` in `source` matches in `image` within
    `margin` of its best (with the best of `candidate_warps`), and the true place `truth_xy`:
    each plain and fitted (`fitted_ncc`). None where no candidate warp shows the patch."""
    source, image = as_grey_float(source), as_grey_float(image)
    w, h = size
    best: tuple[float, np.ndarray, np.ndarray] | None = None
    for warp in candidate_warps(source_xy, fovea(source), LookParams().max_target_scale):
        template = warped_patch(source, source_xy, warp, size)
        if template is None or float(template.std()) < 1.0:
            continue
        scores = np.nan_to_num(cv2.matchTemplate(image, template, cv2.TM_CCOEFF_NORMED))
        if best is None or float(scores.max()) > best[0]:
            best = (float(scores.max()), template, scores)
    if best is None:
        return None
    peak, template, scores = best
    c = np.array([(w - 1) / 2.0, (h - 1) / 2.0])
    places = []
    for u, v in distinct_places(scores, peak - margin, max(w, h) / 2.0)[:max_places]:
        xy = (float(u + c[0]), float(v + c[1]))
        places.append({"from_truth_px": float(np.hypot(xy[0] - truth_xy[0], xy[1] - truth_xy[1])),
                       "ncc": float(scores[v, u]), "fitted": fitted_ncc(template, image, xy)})
    u, v = (int(round(truth_xy[0] - c[0])), int(round(truth_xy[1] - c[1])))
    near = scores[max(0, v - 1):v + 2, max(0, u - 1):u + 2]
    repeats = [p["fitted"] for p in places if p["from_truth_px"] >= REPEAT_PX and p["fitted"] is not None]
    return {"peak": peak, "truth_ncc": float(near.max()) if near.size else None,
            "truth_fitted": fitted_ncc(template, image, truth_xy),
            "nearest_place_px": min((p["from_truth_px"] for p in places), default=None),
            "best_repeat_fitted": max(repeats, default=None), "places": places}


def recorded_cases(steps_json: Path, images: Path, margin: float) -> list[dict[str, Any]]:
    """One row a recorded look whose first search failed as ambiguous and whose first
    fixation's true offset from the fovea is known."""
    rows = []
    for look, fixation, search, saved in saved_first_searches(steps_json, images):
        truth = true_place(fixation, saved)
        if search["search"] is not None or "ambiguous" not in (search.get("why") or "") or truth is None:
            continue
        found = places_against_truth(saved["source"], tuple(float(v) for v in saved["source_xy"]), saved["image"],
                                     tuple(int(v) for v in saved["patch"]), truth, margin)
        if found is not None:
            rows.append({"xy": look["xy"], "true_offset_px": fixation["true_offset_px"], **found})
    return rows


def true_place(fixation: dict[str, Any], saved: Any) -> tuple[float, float] | None:
    """Where the target truly was in a recorded search's image after `fixation`: the fovea
    plus the recorded true offset; None where the truth is unknown (hidden, or a recording
    without offsets)."""
    offset = fixation.get("true_offset_px")
    if offset is None:
        return None
    centre = fovea(saved["image"])
    return centre[0] + offset[0], centre[1] + offset[1]


def verdict(found_xy: tuple[float, float] | None, truth_xy: tuple[float, float]) -> str:
    """A search's answer against the true place: 'none', 'right' (within 1.5 px), 'wrong'
    (beyond 3 px) or 'near'."""
    if found_xy is None:
        return "none"
    return _verdict_of_offset(float(np.hypot(found_xy[0] - truth_xy[0], found_xy[1] - truth_xy[1])))


def _verdict_of_offset(off_px: float) -> str:
    """'right' within 1.5 px of the truth, 'wrong' beyond `REPEAT_PX`, else 'near'."""
    return "right" if off_px <= 1.5 else "wrong" if off_px > REPEAT_PX else "near"


def verdict_by_distance(found_xy: tuple[float, float] | None, fovea_xy: tuple[float, float],
                        true_error_px: float) -> str:
    """`verdict` where only the target's true distance from the fovea is known (recordings
    without offsets): the found place's distance against it. A wrong place at the true
    distance passes, so 'wrong' counts at least the wrong ones."""
    if found_xy is None:
        return "none"
    return _verdict_of_offset(abs(float(np.hypot(found_xy[0] - fovea_xy[0], found_xy[1] - fovea_xy[1]))
                                  - true_error_px))


def fovea_prior_tally(steps_json: Path, images: Path, reaches: list[float]) -> dict[float, collections.Counter[str]]:
    """For each reach, how the recorded first searches without a measured landing would change
    with a prior about the fovea of that reach: counts of 'as recorded -> with the prior'
    verdicts (`verdict`), of those whose truth is known; by the distance alone
    (`verdict_by_distance`) where the recording kept no offset."""
    tally: dict[float, collections.Counter[str]] = {reach: collections.Counter() for reach in reaches}
    for _, fixation, _, saved in saved_first_searches(steps_json, images):
        truth = true_place(fixation, saved)
        true_error = fixation.get("true_error_px")
        if (truth is None and true_error is None) or not np.isnan(float(saved["offset"][0])):
            continue  # truth unknown, or a landing was measured
        params = dataclasses.replace(LookParams(), target_patch_size=tuple(int(v) for v in saved["patch"]))
        inputs = (saved["source"], tuple(float(v) for v in saved["source_xy"]), saved["image"], params)

        def found(expected: float | None) -> tuple[float, float] | None:
            sighting = search_target(*inputs, None, expected, None).sighting
            return None if sighting is None else (sighting.x, sighting.y)

        def judged(xy: tuple[float, float] | None) -> str:
            return verdict(xy, truth) if truth is not None else verdict_by_distance(xy, fovea(saved["image"]),
                                                                                      float(true_error))

        recorded = judged(found(None))
        for reach in reaches:
            tally[reach][f"{recorded} -> {judged(found(reach / PRIOR_SIGMAS))}"] += 1
    return tally


def _fmt(value: float | None, spec: str = ".2f") -> str:
    return "-" if value is None else format(value, spec)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    recording_arguments(parser)
    parser.add_argument("--margin", type=float, default=0.15, help="places within this NCC of the best are listed")
    parser.add_argument("--fovea-reach", default="6,9,12", help="reaches (px) of a prior about the fovea to try")
    args = parser.parse_args(argv)
    try:
        reaches = [float(v) for v in args.fovea_reach.split(",")]
    except ValueError:
        parser.error(f"--fovea-reach: expected numbers separated by commas, got {args.fovea_reach!r}")
    rows: list[dict[str, Any]] = []
    tally: dict[float, collections.Counter[str]] = {reach: collections.Counter() for reach in reaches}
    for steps_json, images in recordings(parser, args):
        rows += recorded_cases(steps_json, images, args.margin)
        for reach, counts in fovea_prior_tally(steps_json, images, reaches).items():
            tally[reach].update(counts)
    print(f"{len(rows)} looks whose first search was ambiguous, with the truth known")
    print(f"{'true offset':>16}  {'best':>5}  {'truth':>5}  {'fitted':>6}  {'nearest place':>13}  "
          f"{'best repeat, fitted':>19}")
    for r in rows:
        dx, dy = r["true_offset_px"]
        print(f"({dx:6.2f}, {dy:6.2f})  {r['peak']:5.2f}  {_fmt(r['truth_ncc']):>5}  {_fmt(r['truth_fitted'], '.3f'):>6}  "
              f"{_fmt(r['nearest_place_px'], '.1f'):>10} px  {_fmt(r['best_repeat_fitted'], '.3f'):>19}")
    tied = sum(r["truth_fitted"] is not None and r["best_repeat_fitted"] is not None
               and r["best_repeat_fitted"] >= r["truth_fitted"] for r in rows)
    print(f"a repeat 3 px or more from the truth scores at least as high as the truth once fitted: {tied} of {len(rows)}")
    print("\nfirst searches without a measured landing, searched again with a prior about the fovea "
          "(as recorded -> with it; right within 1.5 px of the truth, wrong beyond 3 px):")
    for reach in reaches:
        changed = {k: n for k, n in sorted(tally[reach].items()) if k.split(" -> ")[0] != k.split(" -> ")[1]}
        same = sum(n for k, n in tally[reach].items() if k not in changed)
        print(f"  reach {reach:g} px: {same} unchanged; " + (", ".join(f"{k}: {n}" for k, n in changed.items())
                                                               or "none changed"))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
