"""Maps learned from exact samples (`learn`), scored on the targets the online experiments use.

`headctl experiment learn` scores its map on targets anywhere within the joint limits; the
online experiments score theirs on the room's targets (points of the room's surfaces, seen from
poses fixating the room). To compare the two on the same targets, this learns `learn`'s map
(exact samples, poses uniform over the joint limits, with the pose) on the simulated head the
online experiments build, for each seed, and scores it at given numbers of fixations on the
very targets `headctl experiment online` draws for that seed (`headctl.experiments.online.run_online`:
300 targets, seed + 7919). With `--sweep FOLDER` (an `online` sweep), each online run's final
room landing error is divided by the `learn` map's at the same number of fixations, seed by seed.

    .venv/bin/python -m benchmarks.diag.learn_on_room_targets [--seeds 0-4] [--fixations 1000]
        [--sweep runs/sweep-exploration]
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from pathlib import Path

import numpy as np

from benchmarks.diag.summarise_sweeps import finished_runs, fmt
from calib_free.map.gaze_map import GazeMap
from calib_free.sim.experiments import EXPERIMENTS, landing_errors_px, landing_targets, map_predictor, run_experiment
from headctl.experiments.online import SimulatedHeadRig
from headctl.experiments.sweep import parse_seeds


def learn_on_room(seed: int, fixations: int, width: int = 320, height: int = 240) -> tuple[float, float]:
    """(room's targets, joint range's targets): median landing px of `learn`'s map after `fixations`."""
    rig = SimulatedHeadRig(width, height, seed)  # built, not opened: its head model and room
    gm = GazeMap.for_image(width, height, seed=seed)
    drange = gm.params.disparity_range
    result = run_experiment(dataclasses.replace(EXPERIMENTS["learn"], fixations=fixations), gm, rig.model,
                            seed=seed, landing_every=fixations, landing_count=300)
    room = landing_targets(rig.model, 300, drange, seed + 7919, rig.surroundings)
    room_px = float(np.median(landing_errors_px(rig.model, room, map_predictor(gm))))
    return room_px, result.landing[-1][1]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seeds", default="0-4")
    parser.add_argument("--fixations", type=int, default=1000)
    parser.add_argument("--sweep", type=Path, default=None, help="an online sweep to compare, seed by seed")
    args = parser.parse_args()
    seeds = parse_seeds(args.seeds)
    learned = {seed: learn_on_room(seed, args.fixations) for seed in seeds}
    for seed, (room_px, joint_px) in learned.items():
        print(f"seed {seed}: learn at {args.fixations}: room's targets {room_px:.3f} px, joint range's {joint_px:.3f} px")
    print(f"learn, room's targets: {fmt([r for r, _ in learned.values()], unit=' px')}; "
          f"joint range's: {fmt([j for _, j in learned.values()], unit=' px')}")
    if args.sweep:
        ratios: dict[str, list[float]] = {}
        for record, path in finished_runs(args.sweep):
            summary = json.loads(path.read_text())
            seed = int(record["seed"])
            if seed in learned and summary["online"]["landing_at_fixations"][-1] == args.fixations:
                name = ", ".join(f"{k}={v}" for k, v in record["settings"].items())
                ratios.setdefault(name, []).append(summary["landing_error_px"] / learned[seed][0])
        for name, values in sorted(ratios.items()):
            print(f"{name}: online over learn, both on the room's targets: {fmt(values)} ({len(values)} seeds)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
