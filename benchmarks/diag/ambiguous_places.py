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

Then where a first saccade's motion beyond its plan (the recorded poses: after, less before,
less planned) moved the target: at `--px-per-deg` (the simulated head's map at the fovea),
pan and tilt move the view by that, and vergence by half of it against the pan (the left eye
turns by half its change). By how far the motion went, the target's true distance from the
fovea and from where the shift puts it; and the first searches without a measured landing
searched again with the prior centred there, within 1 px and each `--shift-spread` of the
shift, against the prior about the fovea as wide as the whole motion.

    .venv/bin/python -m benchmarks.diag.ambiguous_places --steps runs/steps.json --images DIR
        [--steps ... --images ...] [--margin 0.15] [--fovea-reach 6,9,12] [--px-per-deg 4.0]
        [--shift-spread 0.25,0.5]
"""
from __future__ import annotations

import argparse
import collections
import dataclasses
import json
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from benchmarks.diag.look_steps import recording_arguments, recordings, saved_first_searches
from calib_free.correspondence.disparity import as_grey_float
from calib_free.gaze.fixation import LookParams
from calib_free.gaze.look_geometry import FIRST_SACCADE_ERROR_PX, corrective_step_error_px
from calib_free.gaze.refind import (PRIOR_SIGMAS, candidate_warps, distinct_places, ecc_fit, fovea, search_target,
                                    warped_patch)

REPEAT_PX = 3.0  # a place this far from the truth or farther is a repeat, not the target


def fitted_ncc(template: np.ndarray, image: np.ndarray, xy: tuple[float, float]) -> float | None:
    """NCC of `template` centred at `xy` in `image` with its warp fitted there (ECC); None
    where the fit did not converge or wandered more than 2 px."""
    h, w = template.shape
    fitted = ecc_fit(template, image, xy[0] - (w - 1) / 2.0, xy[1] - (h - 1) / 2.0)
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
        if (truth is None and true_error is None) or landing_measured(saved):
            continue
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


def landing_measured(saved: Any) -> bool:
    """Whether a saved search had a measured landing for its prior (an offset in the source's
    pixels), not the encoders' shift in the image's or none."""
    in_image = "in_image" in saved.files and bool(saved["in_image"])
    return not in_image and not np.isnan(float(saved["offset"][0]))


def beyond_plan_shift_px(fixation: dict[str, Any], px_per_deg: float) -> tuple[np.ndarray, float] | None:
    """(where a recorded fixation's motion beyond its plan moved the view at the fovea, (dx, dy)
    px; that motion's whole extent, px: pan and tilt, and half the vergence, at `px_per_deg`);
    None for a recording without its plan."""
    if fixation.get("planned") is None or fixation.get("pose_after") is None:
        return None
    moved = np.asarray(fixation["pose_after"], dtype=float) - np.asarray(fixation["pose_before"], dtype=float)
    planned = np.asarray(fixation["planned"], dtype=float)
    beyond = moved - planned
    shift = px_per_deg * np.array([beyond[0] - beyond[2] / 2.0, beyond[1]])
    return shift, corrective_step_error_px(0.0, moved, planned, px_per_deg)


BEYOND_BANDS_PX = ((0.0, 1.0), (1.0, 4.0), (4.0, float("inf")))


def excess_shift_tally(steps_json: Path, images: Path, px_per_deg: float, spreads: list[float],
                       ) -> tuple[list[tuple[float, float, float, float]], dict[float, collections.Counter[str]]]:
    """Of a recording's first fixations whose plan and true offset are known: (motion beyond the
    plan, the target's true distance from the fovea, from where the shift puts it, the shift's
    length), all px; and for each spread, how the first searches without a measured landing
    change from the prior about the fovea as wide as the whole motion (`FIRST_SACCADE_ERROR_PX`
    + the motion) to the prior centred on the shift (+ spread x the shift): counts of
    'about the fovea -> centred' verdicts (`verdict`)."""
    rows: list[tuple[float, float, float, float]] = []
    tally: dict[float, collections.Counter[str]] = {spread: collections.Counter() for spread in spreads}
    for look in json.loads(steps_json.read_text())["looks"]:
        fixation = next((s for s in look.get("steps") or [] if "aim" in s), None)
        moved = None if fixation is None else beyond_plan_shift_px(fixation, px_per_deg)
        if moved is None or fixation.get("true_offset_px") is None:
            continue
        shift, whole = moved
        true = np.asarray(fixation["true_offset_px"], dtype=float)
        rows.append((whole, float(np.hypot(*true)), float(np.hypot(*(true - shift))), float(np.hypot(*shift))))
    for _, fixation, _, saved in saved_first_searches(steps_json, images):
        moved = beyond_plan_shift_px(fixation, px_per_deg)
        truth = true_place(fixation, saved)
        if moved is None or truth is None or landing_measured(saved):
            continue
        shift, whole = moved
        params = dataclasses.replace(LookParams(), target_patch_size=tuple(int(v) for v in saved["patch"]))
        inputs = (saved["source"], tuple(float(v) for v in saved["source_xy"]), saved["image"], params, None)

        def found(expected: float, offset: tuple[float, float] | None) -> tuple[float, float] | None:
            sighting = search_target(*inputs, expected, offset, prior_in_image=True).sighting
            return None if sighting is None else (sighting.x, sighting.y)

        about_fovea = verdict(found(FIRST_SACCADE_ERROR_PX + whole, None), truth)
        for spread in spreads:
            centred = found(FIRST_SACCADE_ERROR_PX + spread * float(np.hypot(*shift)), (float(shift[0]), float(shift[1])))
            tally[spread][f"{about_fovea} -> {verdict(centred, truth)}"] += 1
    return rows, tally


def _changes(tally: collections.Counter[str]) -> str:
    """A tally of 'before -> after' verdicts said: how many kept theirs, and each change."""
    changed = {k: n for k, n in sorted(tally.items()) if k.split(" -> ")[0] != k.split(" -> ")[1]}
    same = sum(n for k, n in tally.items() if k not in changed)
    return f"{same} unchanged; " + (", ".join(f"{k}: {n}" for k, n in changed.items()) or "none changed")


def _fmt(value: float | None, spec: str = ".2f") -> str:
    return "-" if value is None else format(value, spec)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    recording_arguments(parser)
    parser.add_argument("--margin", type=float, default=0.15, help="places within this NCC of the best are listed")
    parser.add_argument("--fovea-reach", default="6,9,12", help="reaches (px) of a prior about the fovea to try")
    parser.add_argument("--px-per-deg", type=float, default=4.0,
                        help="the view's pixels a degree at the fovea, for the motion beyond the plan")
    parser.add_argument("--shift-spread", default="0.25,0.5",
                        help="fractions of the shift to try as the centred prior's spread")
    args = parser.parse_args(argv)

    def numbers(option: str, text: str) -> list[float]:
        try:
            return [float(v) for v in text.split(",")]
        except ValueError:
            parser.error(f"{option}: expected numbers separated by commas, got {text!r}")

    reaches, spreads = numbers("--fovea-reach", args.fovea_reach), numbers("--shift-spread", args.shift_spread)
    if args.px_per_deg <= 0:
        parser.error(f"--px-per-deg: expected a positive number, got {args.px_per_deg}")
    rows: list[dict[str, Any]] = []
    tally: dict[float, collections.Counter[str]] = {reach: collections.Counter() for reach in reaches}
    shifts: list[tuple[float, float, float, float]] = []
    centred: dict[float, collections.Counter[str]] = {spread: collections.Counter() for spread in spreads}
    for steps_json, images in recordings(parser, args):
        rows += recorded_cases(steps_json, images, args.margin)
        for reach, counts in fovea_prior_tally(steps_json, images, reaches).items():
            tally[reach].update(counts)
        more, counts_by_spread = excess_shift_tally(steps_json, images, args.px_per_deg, spreads)
        shifts += more
        for spread, counts in counts_by_spread.items():
            centred[spread].update(counts)
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
        print(f"  reach {reach:g} px: {_changes(tally[reach])}")
    print(f"\nfirst fixations with their plan and truth ({len(shifts)}), by their motion beyond the plan "
          f"(px at {args.px_per_deg:g} px a degree): the target's true distance from the fovea, and from where "
          "the shift puts it, p50 / p90 (and as a fraction of the shift)")
    table = np.array(shifts).reshape(-1, 4)
    for low, high in BEYOND_BANDS_PX:
        band = table[(table[:, 0] >= low) & (table[:, 0] < high)]
        if len(band):
            shifted = band[band[:, 3] >= 1.0]  # a fraction of a shift under a pixel says nothing
            ratio = shifted[:, 2] / shifted[:, 3]
            fraction = (f" ({np.median(ratio):.2f} / {np.percentile(ratio, 90):.2f} of the {len(shifted)} shifts of "
                        "1 px or more)" if len(shifted) else "")
            print(f"  {low:g}-{high:g} px: {len(band)}; from the fovea {np.median(band[:, 1]):.1f} / "
                  f"{np.percentile(band[:, 1], 90):.1f} px; from the shifted place {np.median(band[:, 2]):.1f} / "
                  f"{np.percentile(band[:, 2], 90):.1f} px{fraction}")
    print("first searches without a measured landing, about the fovea as wide as the whole motion -> centred on "
          "the shift:")
    for spread in spreads:
        print(f"  spread {spread:g}: {_changes(centred[spread])}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
