"""Diagnostic: the disparity corrective steps planned with near the fovea, and what fine vergence did with it.

A look's corrective step goes to where the target was seen, with a disparity d: the map's
command for (x, y, d) turns the head and sets the vergence, then fine vergence verges the eyes
on what the fovea shows, turning the left eye by half its change. Where the eyes had converged
and the target lies a few pixels from the fovea, the fine vergence patch about it mostly covers
the fovea's (`calib_free.gaze.look_geometry.shares_the_fovea`), so its depth is the fovea's. This
reads recordings of `benchmarks.diag.look_steps` and, for the corrective steps whose target so
shared the fovea after eyes that converged, tallies by the |d| the step planned with: how many
planned a vergence change that fine vergence then undid (turned back by at least half of it),
and how many left the target truly within 1 px of the fovea.

    .venv/bin/python -m benchmarks.diag.step_disparity runs/steps.json [runs/other-steps.json ...]
"""
from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.diag.lengthened_steps import FOVEA
from benchmarks.diag.look_steps import recording_files
from calib_free.gaze.fixation import FixationParams
from calib_free.gaze.look_geometry import shares_the_fovea

D_BANDS = ((0.0, 1.0), (1.0, 2.0), (2.0, float("inf")))  # |d| the step planned with, px
ON_FOVEA_PX = 1.0  # the looks' tolerance
MIN_PLANNED_DEG = 0.25  # a planned vergence change smaller than the eyes' play is not told undone


def near_fovea_steps(look: dict[str, Any], patch_size: tuple[int, int]) -> list[dict[str, Any]]:
    """The corrective steps of one recorded look whose target shared the fovea the eyes had
    converged on: each with the d it planned with, its planned vergence change, what fine
    vergence changed beyond it (deg), and the truth after it (px from the fovea)."""
    steps = look.get("steps") or []
    fixations = [s for s in steps if "aim" in s]
    searches = [s for s in steps if "search" in s]
    rows = []
    for k in range(1, len(fixations)):
        before, step = fixations[k - 1], fixations[k]
        if not before.get("converged") or step.get("planned") is None or step.get("pose_after") is None \
                or step.get("pose_before") is None or step.get("true_error_px") is None:
            continue
        seen = searches[k - 1].get("seen_at_px") if k - 1 < len(searches) else None
        offset = seen if seen is not None else list(np.asarray(step["aim"][:2], dtype=float) - FOVEA)
        if not shares_the_fovea((float(offset[0]), float(offset[1])), patch_size):
            continue
        planned = float(step["planned"][2])
        fine = float(step["pose_after"][2] - step["pose_before"][2]) - planned
        rows.append({"d": float(step["aim"][2]), "planned_vergence_deg": planned, "fine_vergence_deg": fine,
                     "undone": abs(planned) >= MIN_PLANNED_DEG and planned * fine < 0 and abs(fine) >= abs(planned) / 2,
                     "true_after_px": float(step["true_error_px"])})
    return rows


def tally(recordings: list[Path], patch_size: tuple[int, int]) -> list[dict[str, Any]]:
    """One row a band of |d| (`D_BANDS`): steps, vergence undone, target within 1 px after."""
    rows = [r for path in recordings for look in json.loads(path.read_text())["looks"]
            for r in near_fovea_steps(look, patch_size)]
    out = []
    for low, high in D_BANDS:
        band = [r for r in rows if low <= abs(r["d"]) < high]
        out.append({"d_px": (low, high), "steps": len(band), "undone": sum(r["undone"] for r in band),
                    "on_fovea_after": sum(r["true_after_px"] <= ON_FOVEA_PX for r in band)})
    return out


def main(argv: list[str] | None = None) -> int:
    recordings = recording_files(__doc__.split("\n")[0], argv)
    patch = FixationParams().vergence_patch_size
    print(f"corrective steps whose target shared the fovea the eyes had converged on (the {patch[0]} x {patch[1]} "
          "fine vergence patch), by the |d| they planned with:")
    print(f"{'|d| px':>10}  {'steps':>5}  {'fine vergence undid the plan':>28}  {'within 1 px after':>17}")
    for row in tally(recordings, patch):
        low, high = row["d_px"]
        label = f"{low:g}-{high:g}" if np.isfinite(high) else f">= {low:g}"
        print(f"{label:>10}  {row['steps']:>5}  {row['undone']:>28}  {row['on_fovea_after']:>17}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
