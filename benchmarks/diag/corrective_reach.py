"""Diagnostic: the searches after recorded corrective steps, replayed unbounded and bounded by the step's reach.

After a corrective step a look searches its target no farther from the fovea than the step
can have left it (`calib_free.gaze.refind.step_reach_px`). This reads the looks that
`benchmarks.diag.look_steps` recorded with `--images`, and replays each search that followed a
corrective step twice on the saved images: without a bound, and bounded by the step's expected
error. That error is the one recorded where the recording holds it; else, in older
recordings, the landing error the search was told to expect where no landing was measured (it
is then the step's own), and otherwise the distance from the fovea the step aimed at, which is
the least it can be. Each answer's distance from the fovea is set against the truth, the
distance the fixation truly left the target at: within `--agree-px` it is right. Prints the
searches that differ, and the counts found right, found wrong and not found, both ways.

    .venv/bin/python -m benchmarks.diag.corrective_reach --steps runs/steps.json --images DIR
        [--steps ... --images ...] [--agree-px 3]
"""
from __future__ import annotations

import argparse
import dataclasses
import json
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.diag.look_steps import recording_arguments, recordings
from calib_free.gaze.fixation import LookParams
from calib_free.gaze.refind import find_target, fovea


def step_error_px(search: dict[str, Any], fixation: dict[str, Any], image_size: tuple[int, int]) -> float:
    """The expected error of the corrective step `fixation` that `search` followed (see the module doc)."""
    if search.get("step_error_px") is not None:
        return float(search["step_error_px"])
    if search.get("expected_offset_px") is None and search.get("expected_error_px") is not None:
        return float(search["expected_error_px"])
    width, height = image_size
    return float(np.hypot(fixation["aim"][0] - (width - 1) / 2.0, fixation["aim"][1] - (height - 1) / 2.0))


def corrective_searches(steps_json: Path, images: Path) -> list[dict[str, Any]]:
    """One row a search after a corrective step whose images were saved and whose truth is known:
    the truth and the distances found unbounded and bounded (None: not found)."""
    rows = []
    for k, look in enumerate(json.loads(steps_json.read_text())["looks"]):
        fixation: dict[str, Any] | None = None
        fixations = 0
        for step in look.get("steps") or []:
            if "aim" in step:
                fixation, fixations = step, fixations + 1
                continue
            if fixations < 2 or fixation is None or step.get("saved") is None or fixation.get("true_error_px") is None:
                continue
            saved = np.load(images / f"search-{step['saved']:03d}.npz")
            image = saved["image"]
            params = dataclasses.replace(LookParams(), target_patch_size=(int(saved["patch"][0]), int(saved["patch"][1])))
            warps = list(saved["warps"]) if len(saved["warps"]) else None
            expected = float(saved["expected"])
            offset = None if np.isnan(saved["offset"][0]) else (float(saved["offset"][0]), float(saved["offset"][1]))
            bound = step_error_px(step, fixation, (image.shape[1], image.shape[0]))
            centre = fovea(image)
            found = []
            for step_error in (None, bound):
                sighting, _ = find_target(saved["source"], tuple(saved["source_xy"]), image, params, warps,
                                          None if np.isnan(expected) else expected, offset, step_error)
                found.append(None if sighting is None else round(sighting.distance_px(centre), 2))
            rows.append({"look": k, "step": fixations - 1, "truth": fixation["true_error_px"],
                         "step_error_px": round(bound, 2), "unbounded": found[0], "bounded": found[1]})
    return rows


def counts(rows: list[dict[str, Any]], key: str, agree_px: float) -> dict[str, int]:
    """How many of `rows` the `key` search found right (within `agree_px` of the truth), wrong, or not at all."""
    right = sum(1 for r in rows if r[key] is not None and abs(r[key] - r["truth"]) <= agree_px)
    missed = sum(1 for r in rows if r[key] is None)
    return {"right": right, "wrong": len(rows) - right - missed, "not found": missed}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    recording_arguments(parser)
    parser.add_argument("--agree-px", type=float, default=3.0, help="a search this near the truth is right")
    args = parser.parse_args(argv)
    rows: list[dict[str, Any]] = []
    for steps_json, images in recordings(parser, args):
        rows += [{"recording": steps_json.name, **row} for row in corrective_searches(steps_json, images)]
    print(f"{len(rows)} searches after corrective steps")
    print(f"{'recording':<22}{'look':>5}{'step':>5}{'truth':>8}{'σ':>7}{'unbounded':>11}{'bounded':>9}")
    for r in rows:
        if r["unbounded"] != r["bounded"]:
            print(f"{r['recording']:<22}{r['look']:>5}{r['step']:>5}{r['truth']:>8.2f}{r['step_error_px']:>7.2f}"
                  f"{str(r['unbounded']):>11}{str(r['bounded']):>9}")
    for key in ("unbounded", "bounded"):
        print(f"{key:>9}: " + ", ".join(f"{v} {k}" for k, v in counts(rows, key, args.agree_px).items()))
    ratios = [r["truth"] / max(1.0, r["step_error_px"]) for r in rows]
    if ratios:
        print(f"truth / max(1 px, σ): p90 {np.percentile(ratios, 90):.2f}, max {max(ratios):.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
