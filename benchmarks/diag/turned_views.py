"""Diagnostic: how far the view turns about the optical axis between a look's images, beside
the head's pan and tilt.

The offline looks of `benchmarks.bench.looks` recorded search by search
(`benchmarks.diag.offline_steps`, the images of each search kept in a temporary directory). For each search whose truth (where the world point the target pixel
showed before the look lies, after the fixation before the search) is within `--near-px` of the
left fovea: the turn of the view at the target, from ECC's affine fit of the patch
(`calib_free.gaze.refind.ecc_fit`) started at the truth from the candidate warp that matches
best there (the angle of the fitted linear part's rotation), beside -pan x sin(tilt) between
the look's first pose and the end of that fixation (pan its change, tilt its mean; degrees).
Searches whose fit is poor (ECC's correlation below `--min-fit`: a patch across a depth edge,
whose parts moved apart) are counted, not compared. Printed: for the searches that found the
target and for those that found nothing at `min_target_ncc`, how many, the turns' p50 and p90
and how far -pan x sin(tilt) was from them; and each search that found nothing.

    .venv/bin/python -m benchmarks.diag.turned_views --map runs/offl-map-0.npz [--seed 0]
        [--looks 200] [--near-px 1.5] [--min-fit 0.7] [--json FILE]
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.diag.offline_steps import offline_arguments, offline_rig, recorded_looks
from calib_free.gaze.fixation import LookParams
from calib_free.gaze.refind import candidate_warps, ecc_fit, fovea, warped_patch

PAN, TILT = 0, 1  # in a recorded pose


def turn_deg(linear: np.ndarray) -> float:
    """The rotation part of a 2 x 2 linear map (its polar decomposition), in degrees, positive
    turning x towards y."""
    u, _, vt = np.linalg.svd(linear)
    rotation = u @ vt
    return float(np.degrees(np.arctan2(rotation[1, 0], rotation[0, 0])))


def pan_turn_deg(first_pose: list[float], pose: list[float]) -> float:
    """-pan x sin(tilt) from `first_pose` to `pose` (pan's change, tilt's mean): how far a neck
    that pans about an axis the tilt leans away from the optical axis turns the view."""
    tilt = np.radians((first_pose[TILT] + pose[TILT]) / 2.0)
    return float(-(pose[PAN] - first_pose[PAN]) * np.sin(tilt))


def turn_at_truth(saved: Any, truth_offset: tuple[float, float], params: LookParams) -> tuple[float, float] | None:
    """(turn deg, ECC's correlation) of the view at the truth for a saved search
    (`StepRecorder`'s npz); None where the patch reaches beyond an image or ECC does not converge."""
    source, image = saved["source"].astype(np.float32), saved["image"].astype(np.float32)
    source_xy = (float(saved["source_xy"][0]), float(saved["source_xy"][1]))
    size = (int(saved["patch"][0]), int(saved["patch"][1]))
    centre = fovea(image)
    truth = (centre[0] + truth_offset[0], centre[1] + truth_offset[1])
    warps = [*list(saved["warps"]), *candidate_warps(source_xy, fovea(source), params.max_target_scale)]
    there = warped_patch(image, truth, np.eye(2), size)
    if there is None or there.std() == 0:
        return None
    best: tuple[float, np.ndarray, np.ndarray] | None = None
    for warp in warps:
        template = warped_patch(source, source_xy, warp, size)
        if template is None or template.std() == 0:
            continue
        ncc = float(np.corrcoef(template.ravel(), there.ravel())[0, 1])
        if best is None or ncc > best[0]:
            best = (ncc, warp, template)
    if best is None:
        return None
    _, warp, template = best
    fitted = ecc_fit(template, image, truth[0] - (size[0] - 1) / 2.0, truth[1] - (size[1] - 1) / 2.0)
    if fitted is None:
        return None
    return turn_deg(fitted[1] @ warp), fitted[2]


def turned_searches(looks: list[dict[str, Any]], images: Path, params: LookParams,
                    near_px: float) -> list[dict[str, Any]]:
    """One row a recorded search whose truth lies within `near_px` of the fovea (see the module
    doc); `found`: the search found the target (within `near_px` of the truth)."""
    rows = []
    for look in looks:
        fixations_seen: list[dict[str, Any]] = []
        for step in look.get("steps") or []:
            if "aim" in step:
                fixations_seen.append(step)
                continue
            if not fixations_seen or step.get("saved") is None:
                continue
            last, first = fixations_seen[-1], fixations_seen[0]
            truth = last.get("true_offset_px")
            if truth is None or np.hypot(*truth) > near_px or last.get("pose_after") is None \
                    or first.get("pose_before") is None:
                continue
            size = tuple(step["patch"])
            found = turn_at_truth(np.load(images / f"search-{step['saved']:03d}.npz"), (truth[0], truth[1]),
                                  dataclasses.replace(params, target_patch_size=(int(size[0]), int(size[1]))))
            seen = step.get("seen_at_px")
            rows.append({"kind": look["kind"], "why": step["why"],
                         "found": seen is not None and bool(np.hypot(seen[0] - truth[0], seen[1] - truth[1]) <= near_px),
                         "after_step": len(fixations_seen) > 1, "true_px": round(float(np.hypot(*truth)), 2),
                         "turn_deg": None if found is None else round(found[0], 2),
                         "fit": None if found is None else round(found[1], 3),
                         "pan_turn_deg": round(pan_turn_deg(first["pose_before"], last["pose_after"]), 2)})
    return rows


def summary(rows: list[dict[str, Any]], min_fit: float) -> dict[str, Any]:
    def of(group: list[dict[str, Any]]) -> dict[str, Any]:
        fitted = [r for r in group if r["fit"] is not None and r["fit"] >= min_fit]
        turns = np.abs([r["turn_deg"] for r in fitted])
        apart = np.abs([r["turn_deg"] - r["pan_turn_deg"] for r in fitted])
        return {"searches": len(group), "fitted": len(fitted),
                "turn_deg": {"p50": float(np.median(turns)), "p90": float(np.percentile(turns, 90))} if len(fitted)
                else None,
                "turn_minus_pan_turn_deg": {"p50": float(np.median(apart)), "p90": float(np.percentile(apart, 90))}
                if len(fitted) else None}
    return {"found": of([r for r in rows if r["found"]]),
            "not_found_below_min_ncc": of([r for r in rows if "scores NCC" in r["why"]])}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    offline_arguments(parser)
    parser.add_argument("--near-px", type=float, default=1.5, help="the truth this near the fovea (default 1.5)")
    parser.add_argument("--min-fit", type=float, default=0.7, help="ECC's correlation for a turn to count (default 0.7)")
    parser.add_argument("--json", type=Path, help="write the rows and the summary here")
    args = parser.parse_args(argv)
    if not args.map.is_file():
        parser.error(f"--map {args.map}: no such file")
    with tempfile.TemporaryDirectory(prefix="turned-views-") as images:
        with offline_rig(args.map, args.seed) as offline:
            looks = recorded_looks(offline, args.seed, args.looks, Path(images))
            params = offline.looker.params
        rows = turned_searches(looks, Path(images), params, args.near_px)
    out = {"seed": args.seed, "near_px": args.near_px, "min_fit": args.min_fit, **summary(rows, args.min_fit)}
    print(json.dumps(out, indent=2))
    for r in rows:
        if "scores NCC" in r["why"]:
            print(r)
    if args.json:
        args.json.write_text(json.dumps({**out, "rows": rows}, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
