"""Diagnostic: how the offline looks end by whether their target's patch straddles a depth edge.

A patch across a depth edge holds two surfaces that the saccade's parallax moves against each
other (a near box's rim in front of the far wall): after the saccade no warp of the patch
matches both, and the search finds the target less well, or a look-alike. The offline looks of
`benchmarks.bench.looks` (recorded by `benchmarks.diag.offline_steps`); for each, the truth in
the view the target was chosen in: the first surface along the ray of every second pixel of the
target's 21 x 21 patch, at the servos' true joints, through the left camera's own lens, and the
largest ratio of the distances of two neighbouring samples. Above `--jump` (1.15) the patch
straddles a depth edge. Tallied by that: looks truly on target (counted on target and truly
within 3 px), look-alikes (counted on target, truly farther), and failures by their outcome.

    .venv/bin/python -m benchmarks.diag.depth_edges --map runs/offl-map-0.npz [--seed 0] [--looks 200]
        [--jump 1.15] [--json FILE]
"""
from __future__ import annotations

import argparse
import collections
import json
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.diag.offline_steps import offline_arguments, offline_rig, recorded_looks
from drivers.sim.truth import first_surface

JOINTS = ("pan", "tilt", "left_eye", "right_eye")
HALF_PX = 10  # the target's 21 x 21 patch
SAMPLE_PX = 2
LOOK_ALIKE_PX = 3.0  # counted on target, truly this far off or farther


def depth_jump(model: Any, scene: Any, lens: Any, joints: dict[str, float], xy: tuple[float, float]) -> float:
    """The largest ratio of the distances to the first surface along the rays of two
    neighbouring samples (every `SAMPLE_PX`) of the patch about `xy`, seen at `joints` through
    `lens`: 1 on one smooth surface, the ratio of the two depths across an edge."""
    (rotation, centre), _ = model.eye_frames_from_joints(*(joints[j] for j in JOINTS))
    offsets = np.arange(-HALF_PX, HALF_PX + 1, SAMPLE_PX)
    pixels = np.array([(xy[0] + dx, xy[1] + dy) for dy in offsets for dx in offsets])
    rays = lens.unproject(pixels)
    distance = np.array([np.linalg.norm(first_surface(scene, centre, rotation.T @ ray) - centre)
                         for ray in rays]).reshape(len(offsets), len(offsets))
    across = np.maximum(distance[:, 1:], distance[:, :-1]) / np.minimum(distance[:, 1:], distance[:, :-1])
    down = np.maximum(distance[1:], distance[:-1]) / np.minimum(distance[1:], distance[:-1])
    return float(max(across.max(), down.max()))


def ending(look: dict[str, Any]) -> str:
    """How a look ended: 'on target' (truly within `LOOK_ALIKE_PX`), 'look-alike', or its outcome."""
    if look["on_target"]:
        return "on target" if look["true_error_px"] < LOOK_ALIKE_PX else "look-alike"
    return str(look["outcome"])


def tally(looks: list[dict[str, Any]], jump: float) -> dict[str, Any]:
    """Looks and their endings, by whether the patch straddles a depth edge (`depth_jump` > `jump`)."""
    out: dict[str, Any] = {}
    for name, group in (("depth edge", [lk for lk in looks if lk["depth_jump"] > jump]),
                        ("one surface", [lk for lk in looks if lk["depth_jump"] <= jump])):
        endings = collections.Counter(ending(lk) for lk in group)
        missed = len(group) - endings["on target"]
        out[name] = {"looks": len(group), "not_truly_on_target": missed,
                     "not_truly_on_target_fraction": missed / len(group) if group else None,
                     "endings": dict(endings.most_common())}
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    offline_arguments(parser)
    parser.add_argument("--jump", type=float, default=1.15,
                        help="a depth ratio of two neighbouring samples above this is an edge (default 1.15)")
    parser.add_argument("--json", type=Path, help="write each look's jump and ending, and the tally, here")
    args = parser.parse_args(argv)
    if not args.map.is_file():
        parser.error(f"--map {args.map}: no such file")
    if args.jump <= 1.0:
        parser.error(f"--jump must be above 1, got {args.jump}")
    with offline_rig(args.map, args.seed) as offline:
        looks = recorded_looks(offline, args.seed, args.looks, None)
        rig = offline.rig
        lens = rig.devices.cameras["left"].unit_lens
        rows = [{"kind": lk["kind"], "target": lk["target"], "on_target": lk["on_target"],
                 "true_error_px": lk["true_error_px"], "outcome": lk["outcome"],
                 "depth_jump": depth_jump(rig.model, rig.scene, lens, lk["joints_before"],
                                          (float(lk["target"][0]), float(lk["target"][1])))} for lk in looks]
    out = {"seed": args.seed, "jump": args.jump, **tally(rows, args.jump)}
    print(json.dumps(out, indent=2))
    if args.json:
        args.json.write_text(json.dumps({**out, "rows": rows}, indent=1, default=float) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
