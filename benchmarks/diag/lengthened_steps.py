"""Diagnostic: the corrective steps a look lengthened, and whether the step before them had moved the target.

A look's corrective step goes twice as far beyond the fovea as the target was seen where the
step before it is judged not made (`calib_free.gaze.fixation.next_boost`: moved what it corrects
by less than `STUCK_PX`). This reads recordings of `benchmarks.diag.look_steps` and finds the
lengthened steps from what each step aimed at against where the search before it saw the target
(its offset from the fovea, `seen_at_px`; in recordings that kept only the distance, made while
a step was judged by the change of the target's distance from the fovea, by that rule), then
says, of each, how far the step before it had moved the target in the image, and whether the
lengthened step left the target truly farther from the fovea than it was.

    .venv/bin/python -m benchmarks.diag.lengthened_steps runs/steps.json [runs/other-steps.json ...]
"""
from __future__ import annotations

import collections
import json
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.diag.look_steps import recording_files
from calib_free.gaze.fixation import STUCK_PX, next_boost

FOVEA = np.array([159.5, 119.5])  # the simulated cameras' 320 x 240 images


def lengthened_steps(look: dict[str, Any]) -> list[dict[str, Any]]:
    """The corrective steps of one recorded look that went farther than the target was seen:
    each with how far the step before had moved the target in the image (px), the boost, and the
    truth before and after it (the target's distance from the fovea; None where not known)."""
    fixations = [s for s in look.get("steps") or [] if "aim" in s]
    searches = [s for s in look.get("steps") or [] if "search" in s]
    seen: list[np.ndarray] = []  # where each search saw the target, from the fovea
    boost, last_distance = 1.0, None
    found: list[dict[str, Any]] = []
    for k, search in enumerate(searches[:len(fixations) - 1]):
        if search["search"] is None:
            break
        aim = np.asarray(fixations[k + 1]["aim"][:2], dtype=float) - FOVEA
        if search.get("seen_at_px") is not None:
            seen.append(np.asarray(search["seen_at_px"], dtype=float))
            boost = float(np.hypot(*aim) / max(np.hypot(*seen[-1]), 1e-9))
        else:  # a recording from before the offset was kept: the distance rule it ran under
            boost = next_boost(boost, None if last_distance is None else search["search"] - last_distance)
            seen.append(aim / boost)
        last_distance = search["search"]
        if boost > 1.0 + 1e-6 and k >= 1:
            found.append({"moved_px": float(np.hypot(*(seen[k] - seen[k - 1]))), "boost": round(boost, 2),
                          "true_before_px": fixations[k].get("true_error_px"),
                          "true_after_px": fixations[k + 1].get("true_error_px")})
    return found


def tally(recordings: list[Path]) -> tuple[int, collections.Counter[str], list[dict[str, Any]]]:
    """(corrective steps, lengthened ones counted by 'moved' / 'not moved' and 'farther' /
    'nearer' / 'truth unknown', each lengthened one) over the recordings' looks."""
    steps, counts, rows = 0, collections.Counter[str](), []
    for path in recordings:
        for look in json.loads(path.read_text())["looks"]:
            steps += max(0, sum("aim" in s for s in look.get("steps") or []) - 1)
            for row in lengthened_steps(look):
                before, after = row["true_before_px"], row["true_after_px"]
                verdict = "truth unknown" if before is None or after is None else "farther" if after > before else "nearer"
                counts[f"{'moved' if row['moved_px'] >= STUCK_PX else 'not moved'}, {verdict}"] += 1
                rows.append({"recording": path.name, **row})
    return steps, counts, rows


def main(argv: list[str] | None = None) -> int:
    recordings = recording_files(__doc__.split("\n")[0], argv)
    steps, counts, rows = tally(recordings)
    print(f"{steps} corrective steps, {len(rows)} lengthened; by whether the step before had moved the target "
          f"{STUCK_PX} px or more, and whether the lengthened one left it farther from the fovea:")
    for key, n in sorted(counts.items()):
        print(f"  {key}: {n}")
    for r in rows:
        print(f"  {r['recording']}: the step before moved it {r['moved_px']:.2f} px; x{r['boost']:g}; "
              f"truth {r['true_before_px']} -> {r['true_after_px']} px")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
