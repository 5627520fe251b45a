"""Diagnostic: which fixations of an online run were refused, why, and whether their matches were right.

Runs `--fixations` exploratory fixations on the simulated head from a random map, as
`headctl experiment online` does, and judges every fixation that reached the correspondence
against the truth, eye by eye: where the point on that eye's fovea after the fixation (the
first surface on the ray through its image centre at the true final joints, through the
unit's own lens) was in that eye's pre-fixation image.
Per eye, not through the left eye's point alone: at a depth edge the left fovea's centre can
lie on the far surface while the patch around it, and the right fovea, hold the near one's
edge; the fixation then teaches the edge's (x, y, d), rightly.

A match is *right* when the left (x, y) and the right x are each within 1 px of the truth,
*wrong* when either is off by more than 3 px. Prints the outcomes by the left fovea's texture
and by right and wrong, the confidence's factors of the right matches refused for confidence,
and, for each `--compare` setting (CorrespondenceParams fields, and `floor` for the
fixation's confidence floor), what the same recorded pairs would have taught: the
correspondence, the stereo check and the floor again on every matched fixation (those refused
as outside the map left out: the map of the moment is not kept).

`--config` names the simulated head (default: the packaged one, the realistic world);
`--room config` keeps that config's room.

    .venv/bin/python -m benchmarks.diag.online_refusals [--config configs/sim.yaml] [--fixations 1000]
        [--seed 2] [--room generated|photos|config] [--exploration teaching|random]
        [--compare context_min_correlation=0.0] [--compare floor=0.2,stereo_tolerance_px=3] [--json FILE]
"""
from __future__ import annotations

import argparse
import collections
import dataclasses
import json
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from calib_free.map.gaze_map import GazeMap
from calib_free.map.adapter import MapAdapter
from calib_free.correspondence.search import CorrespondenceParams, match_fixation
from calib_free.correspondence.stereo import stereo_inconsistency
from calib_free.correspondence.disparity import as_grey_float
from calib_free.gaze.fixation import FixationController, FixationOutcome, FixationParams
from drivers.servo.joints import JOINTS
from calib_free.sim.head_model import HeadModel
from drivers.sim.camera import SimulatedCamera
from drivers.sim.scene import Lens, Scene
from drivers.sim.truth import centre_point, hidden_from, texture_at
from headctl.config.head import HeadConfig, load_config
from headctl.experiments.online import SimulatedHeadRig, exploration_for

RIGHT_PX, WRONG_PX = 1.0, 3.0


@dataclasses.dataclass
class Judged:
    """One fixation that reached the correspondence, with each eye's truth."""

    outcome: str
    factors: dict[str, float]
    position: np.ndarray  # (x, y, d) matched
    truth_left: np.ndarray  # (x, y) of the left fovea's point in the left pre-fixation image
    truth_right_x: float  # x of the right fovea's point in the right pre-fixation image
    seen: bool  # both points in view and unoccluded before the fixation
    texture: str  # of the left fovea's surface
    pairs: tuple[np.ndarray, ...] | None = None  # pre left, pre right, post left, post right (grey)

    def errors(self, position: np.ndarray) -> tuple[float, float]:
        left = float(np.hypot(*(position[:2] - self.truth_left)))
        return left, abs(float(position[0] + position[2]) - self.truth_right_x)

    def verdict(self, position: np.ndarray | None = None) -> str:
        if not self.seen:
            return "no answer"
        worst = max(self.errors(self.position if position is None else position))
        return "right" if worst <= RIGHT_PX else "wrong" if worst > WRONG_PX else "within 3 px"


def eye_truths(model: HeadModel, scene: Scene, lenses: tuple[Lens, Lens], before: dict[str, float],
               after: dict[str, float]) -> tuple[list[np.ndarray], bool, str]:
    """Per eye, where its fovea's point after the fixation was before it, through that eye's
    own lens (`lenses`, left and right: a unit's lens differs from the model's, its centre
    off the image centre by up to 10 px in the realistic world); whether both were seen; the
    left point's texture."""
    frames_after = model.eye_frames_from_joints(*(after[j] for j in JOINTS))
    frames_before = model.eye_frames_from_joints(*(before[j] for j in JOINTS))
    truths, seen = [], True
    points = [centre_point(scene, lens, rotation, centre) for (rotation, centre), lens in zip(frames_after, lenses)]
    for point, (rotation, centre), lens in zip(points, frames_before, lenses):
        uv, visible = lens.project(((point - centre) @ rotation.T)[None])
        seen = seen and bool(visible[0]) and not hidden_from(scene, centre, point, 1e-3)
        truths.append(uv[0])
    return truths, seen, texture_at(scene, points[0])


class RecordingHead:
    """The rig's head, keeping the stereo pairs of the fixation in progress."""

    def __init__(self, head: Any) -> None:
        self._head = head
        self.pairs: list[tuple[np.ndarray, np.ndarray]] = []

    def __getattr__(self, name: str) -> Any:
        return getattr(self._head, name)

    def wait_pair(self, after_s: float, timeout_s: float) -> tuple[np.ndarray, np.ndarray]:
        pair = self._head.wait_pair(after_s, timeout_s)
        self.pairs.append(pair)
        return pair


def run(fixations: int, seed: int, room: str | None, exploration: str, keep_pairs: bool,
        config: HeadConfig | None = None) -> tuple[list[Judged], collections.Counter[str]]:
    params = FixationParams(exploration=exploration, correspondence=CorrespondenceParams.profile_values("default"))
    judged: list[Judged] = []
    unmatched: collections.Counter[str] = collections.Counter()
    with SimulatedHeadRig(seed=seed, fixation=params, room=room, config=config) as rig, \
            MapAdapter(GazeMap.for_image(320, 240, seed=seed)) as adapter:
        world = rig.devices.world
        assert world is not None
        cameras = [rig.devices.cameras[side] for side in ("left", "right")]
        assert all(isinstance(camera, SimulatedCamera) for camera in cameras)  # the rig checked it
        lenses = (cameras[0].unit_lens, cameras[1].unit_lens)  # type: ignore[attr-defined]
        head = RecordingHead(rig.head)
        controller = FixationController(head, adapter, params, seed=seed, clock=rig.clock.monotonic, learner=adapter)
        before = world.true_joints()
        for n in range(fixations):
            head.pairs = []
            record = controller.fixate()
            after = world.true_joints()
            if record.match is None:
                unmatched[str(record.outcome)] += 1
            else:
                truths, seen, texture = eye_truths(rig.model, rig.scene, lenses, before, after)
                pairs = None
                if keep_pairs:
                    pairs = tuple(as_grey_float(im).astype(np.uint8) for im in (*head.pairs[0], *head.pairs[-1]))
                judged.append(Judged(str(record.outcome), record.match.factors(), record.match.position,
                                     truths[0], float(truths[1][0]), seen, texture, pairs))
            before = after
            if (n + 1) % 250 == 0:
                print(f"{n + 1} fixations", file=sys.stderr)
        adapter.wait_idle()
    return judged, unmatched


def parse_setting(text: str) -> tuple[dict[str, Any], float]:
    """'key=value,...' into CorrespondenceParams overrides and the floor."""
    overrides: dict[str, Any] = {}
    floor = FixationParams().confidence_floor
    fields = {f.name: f for f in dataclasses.fields(CorrespondenceParams)}
    for item in filter(None, text.split(",")):
        key, _, value = item.partition("=")
        if key == "floor":
            floor = float(value)
        elif key not in fields:
            raise SystemExit(f"--compare: {key!r} is not a CorrespondenceParams field (nor 'floor')")
        else:
            kind = type(getattr(CorrespondenceParams(), key))
            overrides[key] = value if kind is str else int(value) if kind is int else float(value)
    return overrides, floor


def reevaluate(judged: list[Judged], overrides: dict[str, Any], floor: float) -> collections.Counter[str]:
    params = CorrespondenceParams.profile_values("default", **overrides)
    counts: collections.Counter[str] = collections.Counter()
    for case in judged:
        if case.outcome == FixationOutcome.POSITION_OUTSIDE or case.pairs is None:
            continue
        pre_left, pre_right, post_left, post_right = (im.astype(np.float32) for im in case.pairs)
        match = match_fixation(pre_left, pre_right, post_left, post_right, params)
        taught = not stereo_inconsistency(match, pre_left, pre_right, params) and match.confidence >= floor
        counts[f"{'taught' if taught else 'refused'} {case.verdict(match.position)}"] += 1
    return counts


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--fixations", type=int, default=1000)
    parser.add_argument("--seed", type=int, default=2)
    parser.add_argument("--config", type=Path, help="the simulated head's config (default: the packaged one)")
    parser.add_argument("--room", default="generated", help="generated, photos, or config: the config's own")
    parser.add_argument("--exploration", default=exploration_for("default"))
    parser.add_argument("--compare", action="append", default=[], metavar="KEY=VALUE,...")
    parser.add_argument("--json", type=Path)
    args = parser.parse_args()
    settings = [parse_setting(text) for text in args.compare]
    started = time.monotonic()
    config = load_config(args.config) if args.config else None
    room = None if args.room == "config" else args.room
    judged, unmatched = run(args.fixations, args.seed, room, args.exploration, bool(settings), config)
    table = collections.Counter((case.outcome, case.texture, case.verdict()) for case in judged)
    print(f"{args.fixations} fixations, seed {args.seed}, {args.room} room, {args.exploration} exploration; "
          f"{len(judged)} matched ({time.monotonic() - started:.0f} s)")
    print("\noutcome, the left fovea's texture, the match against each eye's truth:")
    for (outcome, texture, verdict), count in sorted(table.items()):
        print(f"  {count:5d}  {outcome:36s} {texture:9s} {verdict}")
    for outcome, count in sorted(unmatched.items()):
        print(f"  {count:5d}  {outcome:36s} (no correspondence)")
    refused_right = [c for c in judged if c.outcome == FixationOutcome.LOW_CONFIDENCE and c.verdict() == "right"]
    if refused_right:
        print(f"\nthe {len(refused_right)} right matches refused for confidence, per eye (median [IQR]):")
        for name in ("context_c_max", "second_peak", "backward_px", "confidence"):
            values = np.array([c.factors[f"{name}_{side}"] for c in refused_right for side in ("left", "right")])
            q1, q2, q3 = np.percentile(values, [25, 50, 75])
            print(f"  {name:14s} {q2:.2f} [{q1:.2f}, {q3:.2f}]")
    compared: dict[str, dict[str, int]] = {}
    if settings:
        runs = [("as run", ({}, FixationParams().confidence_floor)), *zip(args.compare, settings)]
        for label, (overrides, floor) in runs:
            counts = reevaluate(judged, overrides, floor)
            compared[label] = dict(counts)
            print(f"\n{label}: taught {counts['taught right']} right, {counts['taught within 3 px']} within 3 px, "
                  f"{counts['taught wrong']} wrong; refused {counts['refused right']} right, "
                  f"{counts['refused within 3 px']} within 3 px, {counts['refused wrong']} wrong "
                  f"({counts['taught no answer'] + counts['refused no answer']} without an answer)")
    if args.json:
        args.json.write_text(json.dumps({
            "fixations": args.fixations, "seed": args.seed, "room": args.room, "exploration": args.exploration,
            "outcomes": [{"outcome": o, "texture": t, "verdict": v, "count": n} for (o, t, v), n in table.items()],
            "unmatched": dict(unmatched), "compared": compared}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
