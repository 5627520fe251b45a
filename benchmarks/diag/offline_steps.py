"""The offline looks of `benchmarks.bench.looks`, recorded fixation by fixation and search by
search, for the diagnostics that read them (`benchmarks.diag.turned_views`,
`benchmarks.diag.depth_edges`).

A saved map on the manual-clock rig (`SimulatedHeadRig`), `--looks` looks of each kind (textured
targets, then random pixels), the same targets as `benchmarks.bench.looks --map` draws for the
same `--seed`, each fixation and target search recorded by `benchmarks.diag.look_steps.StepRecorder`
with its images saved.
"""
from __future__ import annotations

import argparse
import contextlib
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterator

import numpy as np

from benchmarks.bench.looks import run_looks
from benchmarks.diag.look_steps import StepRecorder
from calib_free.gaze.fixation import FixationController
from calib_free.gaze.look import LookController
from calib_free.map.adapter import MapAdapter
from calib_free.map.file import read_map
from headctl.experiments.online import SimulatedHeadRig

KINDS = (("textured", True), ("random_without_d", False))


def offline_arguments(parser: argparse.ArgumentParser) -> None:
    """`--map FILE [--seed N] [--looks N]`."""
    parser.add_argument("--map", type=Path, required=True, help="a saved map (benchmarks.bench.looks --save-map)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--looks", type=int, default=200, help="looks of each kind (default 200)")


@dataclass(frozen=True)
class OfflineRig:
    """The rig of `benchmarks.bench.looks --map`, its map's adapter, and the controllers on it."""

    rig: SimulatedHeadRig
    adapter: MapAdapter
    controller: FixationController
    looker: LookController


@contextlib.contextmanager
def offline_rig(map_path: Path, seed: int) -> Iterator[OfflineRig]:
    """The rig of `benchmarks.bench.looks --map` for `seed`."""
    with SimulatedHeadRig(seed=seed) as rig, MapAdapter(read_map(map_path)) as adapter:
        controller = FixationController(rig.head, adapter, rig.fixation, seed=seed, clock=rig.clock.monotonic,
                                        learner=adapter)
        yield OfflineRig(rig, adapter, controller, LookController(controller))


def recorded_looks(offline: OfflineRig, seed: int, count: int, images: Path | None) -> list[dict[str, Any]]:
    """`count` looks of each kind (`KINDS`), each its row of `benchmarks.bench.looks` with its
    `kind`, the servos' true joints as it began (`joints_before`) and its recorded `steps`
    (fixations and searches; the searches' inputs saved in `images` as search-NNN.npz, unless
    None); refused targets have no row."""
    rng = np.random.default_rng(seed + 101)  # as benchmarks.bench.looks draws its targets
    rig = offline.rig
    recorder = StepRecorder(rig.devices.world, rig.devices.cameras["left"].unit_lens, images)
    looks: list[dict[str, Any]] = []
    with recorder.installed():
        for kind, textured in KINDS:
            def kept(row: dict[str, Any], kind: str = kind) -> dict[str, Any]:
                looks.append({**row, "kind": kind, "joints_before": recorder.joints_before, "steps": recorder.take()})
                print(f"{kind} look {sum(lk['kind'] == kind for lk in looks)}", file=sys.stderr, flush=True)
                return row
            run_looks(rig, offline.adapter, offline.controller, offline.looker, rng, count, textured,
                      before_look=recorder.look_posted, after_look=kept)
    return looks
