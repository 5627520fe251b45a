"""Diagnostic: the structure of the target patches of recorded looks, against how their first search went.

A patch with structure in one direction only (a straight edge, stripes) matches itself almost as
well slid along that direction, and where the view changes between the two images (the lens's
magnification, parallax across a depth edge) the search's best place can slide along it. This
reads the looks that `benchmarks.diag.look_steps` recorded with `--images`, and prints for each
look's first target search: the structure tensor of the target's 21 px patch in its own view
(the sums of the products of its grey-level gradients), as the ratio of its eigenvalues (1 for
structure alike in every direction, large for an edge) and the localisation error the camera's
noise alone would leave (`--noise` grey levels over the square root of the smaller eigenvalue,
px); the first fixation's true error and the search's distance of the target from the fovea
(px); and whether the look ended on target. Sorted by the ratio: the searches the truth refutes
(they differ by more than `--disagree-px`) are marked.

With `--rendered N` instead: how the ratio is spread over the targets a client may pick, N
random pixels a pose of the generated room at 40 random poses (the UVC webcam's frames once its
auto exposure settled) that the look's own-view checks accept (`target_patch_problem`): the
share above a few ratios, what refusing above each would cost.

    .venv/bin/python -m benchmarks.diag.patch_structure --steps runs/steps.json --images DIR
        [--noise 2.3] [--disagree-px 1.0]
    .venv/bin/python -m benchmarks.diag.patch_structure --rendered 40 [--seed 0]
"""
from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from benchmarks.diag import own_view_margin
from benchmarks.diag.look_steps import saved_first_searches
from calib_free.gaze import target_patch
from calib_free.gaze.fixation import LookParams

HALF_PATCH = 10  # the look's 21 px patch


def structure(source: np.ndarray, xy: tuple[float, float], half: int = HALF_PATCH) -> tuple[float, float] | None:
    """The eigenvalues (smaller, larger) of the structure tensor of the patch around `xy`; None
    where the patch reaches beyond the image."""
    x, y = int(round(xy[0])), int(round(xy[1]))
    if not (half + 1 <= x < source.shape[1] - half - 1 and half + 1 <= y < source.shape[0] - half - 1):
        return None
    image = source.astype(np.float32)
    gx = cv2.Sobel(image, cv2.CV_32F, 1, 0, ksize=3)[y - half:y + half + 1, x - half:x + half + 1] / 8.0
    gy = cv2.Sobel(image, cv2.CV_32F, 0, 1, ksize=3)[y - half:y + half + 1, x - half:x + half + 1] / 8.0
    tensor = np.array([[np.sum(gx * gx), np.sum(gx * gy)], [np.sum(gx * gy), np.sum(gy * gy)]], dtype=float)
    smaller, larger = np.linalg.eigvalsh(tensor)
    return float(smaller), float(larger)


def first_searches(steps_json: Path, images: Path, noise: float) -> list[dict[str, Any]]:
    """One row a look taken on whose first search was saved."""
    rows = []
    for look, fixation, search, saved in saved_first_searches(steps_json, images):
        eigen = structure(saved["source"], tuple(saved["source_xy"]))
        if eigen is None:
            continue
        smaller, larger = eigen
        rows.append({"xy": [round(v, 1) for v in look["xy"]], "ratio": larger / max(smaller, 1e-9),
                     "noise_bound_px": noise / np.sqrt(max(smaller, 1e-9)),
                     "truth_px": fixation["true_error_px"], "search_px": search["search"],
                     "on_target": look["on_target"]})
    return sorted(rows, key=lambda r: r["ratio"])


def rendered_ratios(pixels: int, poses: int = 40, seed: int = 0) -> np.ndarray:
    """The eigenvalue ratio of every accepted target among `pixels` random ones a pose (see the
    module doc)."""
    rng = np.random.default_rng(seed)
    ratios = []
    for _ in range(poses):
        frame = own_view_margin.settled_frame("uvc_webcam", rng, seed)
        for _ in range(pixels):
            xy = (float(rng.uniform(0, frame.shape[1] - 1)), float(rng.uniform(0, frame.shape[0] - 1)))
            eigen = structure(frame, xy)
            if eigen is None or target_patch.target_patch_problem(frame, xy, LookParams()):
                continue
            ratios.append(eigen[1] / max(eigen[0], 1e-9))
    return np.asarray(ratios)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--steps", type=Path, help="look_steps' --json")
    parser.add_argument("--images", type=Path, help="look_steps' --images")
    parser.add_argument("--rendered", type=int, help="random pixels a pose of the rendered room, instead")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--noise", type=float, default=2.3, help="the camera's noise, grey levels (default 2.3)")
    parser.add_argument("--disagree-px", type=float, default=1.0)
    args = parser.parse_args()
    if args.rendered:
        ratios = rendered_ratios(args.rendered, seed=args.seed)
        print(f"{ratios.size} accepted targets; eigenvalue ratio p50 {np.median(ratios):.1f}, p90 "
              f"{np.percentile(ratios, 90):.1f}; above " + ", ".join(
                  f"{limit}: {np.mean(ratios > limit):.1%}" for limit in (15, 20, 30, 50)))
        return
    if args.steps is None or args.images is None:
        parser.error("--steps and --images (a look_steps recording), or --rendered N")
    rows = first_searches(args.steps, args.images, args.noise)
    print(f"{'pixel':>14} {'ratio':>7} {'noise px':>8} {'truth':>7} {'search':>7}  on target")
    for r in rows:
        truth, search = r["truth_px"], r["search_px"]
        refuted = truth is not None and search is not None and abs(search - truth) > args.disagree_px
        print(f"{str(r['xy']):>14} {r['ratio']:7.1f} {r['noise_bound_px']:8.3f} {truth if truth is not None else '-':>7} "
              f"{search if search is not None else '-':>7}  {r['on_target']}{'  <- the truth refutes the search' if refuted else ''}")


if __name__ == "__main__":
    main()
