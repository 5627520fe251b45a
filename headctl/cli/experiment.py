"""`headctl experiment NAME`: the paper's simulated experiments, with CSV, plot and summary.

NAME is one of `calib_free.sim.experiments.EXPERIMENTS` (learn, baseline, prism, pan-defect,
swap: (r, m) pairs straight from the geometric head model) or `headctl.experiments.online`'s (online,
online-prism, online-pan-defect: the whole fixation loop on rendered images). The run
learns with a progress bar, writes
`<out>/<name>-<profile>.csv` (per fixation: raw and averaged errors) and `.png` (like the
paper's figures), and prints the paper's figures beside the measured ones, the landing error
and the representation's floor.
"""
from __future__ import annotations

import argparse
import csv
import dataclasses
import json
import logging
import sys
import time
from typing import Any
from pathlib import Path

import numpy as np
from tqdm import tqdm

from calib_free.map.gaze_map import GazeMap
from calib_free.gaze.exploration import EXPLORATION_KINDS
from calib_free.sim.experiments import (EXPERIMENTS, ExperimentResult, ExperimentSpec, final_head, landing_targets,
                                    representation_floor, run_experiment)
from calib_free.map.params import PROFILES, GazeMapParams
from calib_free.lens import LENS_KINDS
from calib_free.sim.head_model import HeadModel
from drivers.sim.scene import ROOMS as ROOM_KINDS
from headctl.experiments import sweep
from headctl.experiments.online import ONLINE_EXPERIMENTS, OnlineResult, OnlineSpec, run_online

log = logging.getLogger(__name__)

# The paper's figures for each experiment: what `learn` is compared with (fig. 5), and the
# re-adaptation windows the issue sets (figs. 6, 8, 9).
PAPER_LEARN = {"pan_deg": 1.3, "tilt_deg": 1.07, "vergence_deg": 0.5, "retinal_error": 0.0368}
RECOVERY_GOAL = {"baseline": 500, "prism": 700, "pan-defect": 700, "swap": 700}
# The options of one run a sweep passes on to all its runs (`--set` varies them).
SWEEP_BASE_OPTIONS = ("fixations", "width", "height", "lens", "floor_samples", "landing_every", "exploration", "room")
STEADY_OVER = 200  # fixations in the steadier "mean of the last 200" figure


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "experiment", help="run one of the paper's simulated experiments (learning curves, plot, summary)",
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("name", choices=sorted(EXPERIMENTS) + sorted(ONLINE_EXPERIMENTS) + ["pursuit", "sweep"],
                   help="which experiment (online*: on rendered images through the fixation loop); "
                        "sweep NAME: NAME over seeds, profiles and settings on Dask (headctl.experiments.sweep)")
    p.add_argument("--profile", choices=PROFILES, default="default",
                   help="gaze map profile: 'paper' (the rule as written) or 'default' (improved)")
    p.add_argument("--fixations", type=int, default=None, help="fixations to run (default: the experiment's)")
    p.add_argument("--seed", type=int, default=0, help="random seed (map initialisation and fixations)")
    p.add_argument("--width", type=int, default=320, help="image width, px (default 320)")
    p.add_argument("--height", type=int, default=240, help="image height, px (default 240)")
    p.add_argument("--lens", choices=LENS_KINDS, default="foveated", help="fish-eye model of both cameras")
    p.add_argument("--out", type=Path, default=Path("runs"), help="where the CSV and PNG go (default ./runs)")
    p.add_argument("--floor-samples", type=int, default=50_000,
                   help="samples for the k-NN representation floor; 0 skips it (default 50000)")
    p.add_argument("--landing-every", type=int, default=100, help="fixations between landing-error checks")
    p.add_argument("--pose", action=argparse.BooleanOptionalAction, default=True,
                   help="samples and lookups carry the head's pose (default); --no-pose: (x, y, d) alone, "
                        "as the paper")
    p.add_argument("--exploration", choices=EXPLORATION_KINDS, default=None,
                   help="online*: where exploratory fixations go: 'random' (the paper's) or 'teaching' "
                        "(targets that teach); default: random with --profile paper, else teaching")
    p.add_argument("--room", choices=ROOM_KINDS, default=None,
                   help="online*: the room the simulated cameras see: 'generated' (default) or 'photos' "
                        "(walls papered with photographs, docs/sim-rooms.md)")
    sweep.add_arguments(p)
    p.add_argument("--map", type=Path, default=None, metavar="FILE",
                   help="pursuit: the gaze map to pursue with (default: one learned on the geometric head model)")
    p.add_argument("--speeds", default=None, metavar="S,S,...",
                   help="pursuit: target speeds, deg/s (default 5,10,20,30,40)")
    p.add_argument("--latency-ms", type=float, default=40.0,
                   help="pursuit: frame-to-command latency modelled on the manual clock (default 40, as measured "
                        "on the real-time daemon)")
    p.set_defaults(func=run)
    # What a sweep compares against to tell the options given from the defaults.
    p.set_defaults(defaults={dest: p.get_default(dest) for dest in SWEEP_BASE_OPTIONS + ("out",)})


def run(args: argparse.Namespace) -> int:
    if args.name == "pursuit":
        return run_pursuit_command(args)
    if args.name == "sweep":
        # Every run of the sweep takes the experiment options given here; --set varies them.
        base = [str(v) for dest in SWEEP_BASE_OPTIONS if getattr(args, dest, None) != args.defaults[dest]
                for v in ("--" + dest.replace("_", "-"), getattr(args, dest))]
        if not args.pose:
            base.append("--no-pose")
        if args.out == args.defaults["out"]:
            args.out = args.out / f"sweep-{args.swept}"
        return sweep.run(args, base)
    if args.swept:
        print(f"{args.swept!r}: a second experiment name is taken by sweep only", file=sys.stderr)
        return 2
    online = args.name in ONLINE_EXPERIMENTS
    spec: ExperimentSpec = ONLINE_EXPERIMENTS[args.name] if online else EXPERIMENTS[args.name]
    if args.fixations is not None:
        if args.fixations < 1:
            print(f"--fixations must be at least 1, got {args.fixations}", file=sys.stderr)
            return 2
        spec = dataclasses.replace(spec, fixations=args.fixations,
                                   changes=tuple(c for c in spec.changes if c.at < args.fixations))
    args.out.mkdir(parents=True, exist_ok=True)
    stem = args.out / f"{spec.name}-{args.profile}{'' if args.pose else '-nopose'}"
    extra: dict[str, Any] = {}
    started = time.monotonic()
    with tqdm(total=spec.fixations, desc=f"{spec.name} ({args.profile})", unit="fix",
              disable=None, file=sys.stderr) as bar:
        if online:
            if args.lens != "foveated":
                print("--lens applies to the geometric experiments only", file=sys.stderr)
                return 2
            taught = 0

            def progress(record) -> None:
                nonlocal taught
                taught += record.taught
                bar.update(1)
                bar.set_postfix(taught=taught, refresh=False)

            assert isinstance(spec, OnlineSpec)
            online_result = run_online(spec, args.profile, seed=args.seed, width=args.width, height=args.height,
                                       landing_every=args.landing_every, progress=progress,
                                       exploration=args.exploration, room=args.room or "generated",
                                       use_pose=args.pose)
            result = online_result.as_experiment_result()
            assert online_result.model is not None
            head = online_result.model
            extra = online_summary(online_result)
            extra["online"]["room"] = args.room or "generated"
        else:
            if args.exploration is not None or args.room is not None:
                print("--exploration and --room apply to the online experiments only", file=sys.stderr)
                return 2
            head = HeadModel.default(args.width, args.height, lens=args.lens)
            gm = GazeMap.for_image(args.width, args.height, seed=args.seed, profile=args.profile)
            result = run_experiment(spec, gm, head, seed=args.seed, landing_every=args.landing_every,
                                    progress=lambda n: None if bar.update(n) else None, use_pose=args.pose)
    learn_s = time.monotonic() - started
    drange = GazeMapParams().disparity_range  # both kinds of run use the default range

    floor_px = None
    if args.floor_samples > 0:
        print(f"measuring the representation floor (k-NN on {args.floor_samples} samples)...", file=sys.stderr)
        end_head = final_head(spec, head)
        targets = landing_targets(end_head, 500, drange, seed=args.seed + 7919 + spec.fixations)
        floor_px, best_k = representation_floor(end_head, drange, args.floor_samples, targets, seed=args.seed + 1)
    write_csv(result, stem.with_suffix(".csv"))
    from headctl.experiments.plots import plot_learning_curves  # matplotlib only when plotting

    plot_learning_curves(result, stem.with_suffix(".png"), floor_px,
                         title=f"{spec.name} ({args.profile} profile): {spec.description}", online=online)
    summary = summarise(result, floor_px, args.profile, learn_s)
    summary.update(extra)
    summary["pose"] = args.pose
    stem.with_suffix(".json").write_text(json.dumps(summary, indent=2) + "\n")
    print(format_summary(summary))
    print(f"wrote {stem}.csv, {stem}.png, {stem}.json")
    return 0


def online_summary(result: OnlineResult) -> dict:
    records = result.records
    confidences = [r.confidence for r in records if r.taught]
    return {
        # Beside the room's landing error: targets anywhere within the joint limits.
        "landing_joint_range_px": result.landing_joint_range[-1][1] if result.landing_joint_range else None,
        "online": {
            "fixations": len(records),
            "taught": sum(r.taught for r in records),
            "outcomes": result.outcomes(),
            "fixations_per_s": len(records) / result.seconds if result.seconds else None,
            "median_confidence_taught": float(np.median(confidences)) if confidences else None,
            "vergence": result.vergence_convergence(),
            "landing_at_fixations": result.landing_fixations,
            "landing_start_px": result.landing_start_px,
            "exploration": result.exploration,
            "exploration_stats": result.exploration_stats,
        }
    }


def write_csv(result: ExperimentResult, path: Path) -> None:
    avg_out = result.averaged(result.output_error)
    avg_ret = result.averaged(result.retinal_error)
    landing = dict(result.landing)
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["fixation", "retinal_error", "pan_error_deg", "tilt_error_deg", "vergence_error_deg",
                    "retinal_error_avg10", "pan_error_avg10_deg", "tilt_error_avg10_deg",
                    "vergence_error_avg10_deg", "landing_error_median_px"])
        for n in range(len(result.retinal_error)):
            w.writerow([n + 1, f"{result.retinal_error[n]:.6f}", *(f"{v:.5f}" for v in result.output_error[n]),
                        f"{avg_ret[n]:.6f}", *(f"{v:.5f}" for v in avg_out[n]),
                        f"{landing[n + 1]:.3f}" if n + 1 in landing else ""])


def summarise(result: ExperimentResult, floor_px: float | None, profile: str, learn_s: float) -> dict:
    spec = result.spec
    summary: dict = {"experiment": spec.name, "profile": profile, "fixations": spec.fixations,
                     "seconds": round(learn_s, 2), "final": result.final(),
                     "steady": result.final(over=STEADY_OVER),
                     "landing_error_px": result.landing[-1][1] if result.landing else None,
                     "floor_px": floor_px, "refused": result.refused}
    if floor_px:
        summary["landing_over_floor"] = summary["landing_error_px"] / floor_px
    changes = []
    for change in spec.changes:
        entry: dict[str, Any] = {"at": change.at, "recovery_fixations": result.recovery_fixations(change.at),
                 "goal_fixations": RECOVERY_GOAL.get(spec.name), "before": result.final(change.at)}
        before = [px for at, px in result.landing if at <= change.at]
        after = [px for at, px in result.landing if change.at < at <= change.at + 700]
        entry["landing_before_px"] = before[-1] if before else None
        entry["landing_worst_after_px"] = max(after) if after else None
        entry["landing_700_after_px"] = after[-1] if after else None
        changes.append(entry)
    summary["changes"] = changes
    summary["landing_curve_px"] = result.landing
    return summary


def format_summary(s: dict) -> str:
    f, st = s["final"], s["steady"]
    counted = "adaptations (taught fixations)" if "online" in s else "fixations"
    lines = [f"{s['experiment']} ({s['profile']} profile), {s['fixations']} {counted} in {s['seconds']:.1f} s",
             "                   last 10 (paper)  last 200    paper fig. 5 (2,000 fixations)",
             f"  pan error        {f['pan_deg']:7.2f} deg   {st['pan_deg']:7.2f} deg   {PAPER_LEARN['pan_deg']:.2f} deg",
             f"  tilt error       {f['tilt_deg']:7.2f} deg   {st['tilt_deg']:7.2f} deg   {PAPER_LEARN['tilt_deg']:.2f} deg",
             f"  vergence error   {f['vergence_deg']:7.2f} deg   {st['vergence_deg']:7.2f} deg   "
             f"{PAPER_LEARN['vergence_deg']:.2f} deg",
             f"  retinal error    {100 * f['retinal_error']:7.2f} %     {100 * st['retinal_error']:7.2f} %     "
             f"{100 * PAPER_LEARN['retinal_error']:.2f} %"]
    if s["landing_error_px"] is not None:
        line = f"  landing error    {s['landing_error_px']:7.2f} px   (median over visible targets, one saccade)"
        lines.append(line)
    if s["floor_px"]:
        lines.append(f"  floor (k-NN)     {s['floor_px']:7.2f} px   landing / floor = {s['landing_over_floor']:.2f}"
                     " (goal <= 1.5)")
    for c in s["changes"]:
        rec = c["recovery_fixations"]
        goal = c["goal_fixations"]
        rec_text = "not within the run" if rec is None else f"{rec} fixations"
        lines.append(f"  change at {c['at']}: retinal error back to its pre-change level after {rec_text}"
                     + (f" (goal <= {goal})" if goal else ""))
        if c["landing_worst_after_px"] is not None:
            lines.append(f"    landing error {c['landing_before_px']:.1f} px before, {c['landing_worst_after_px']:.1f} px "
                         f"at worst after, {c['landing_700_after_px']:.1f} px 700 fixations after")
    if s["refused"]:
        lines.append(f"  refused samples: {s['refused']}")
    if "online" in s:
        o = s["online"]
        lines.append(f"  fixations {o['fixations']}, taught {o['taught']} ({o['fixations_per_s']:.1f} fixations/s); "
                     "the curves above are per taught fixation")
        for outcome, count in sorted(o["outcomes"].items(), key=lambda kv: -kv[1]):
            lines.append(f"    {outcome:<34} {count:6d}")
        v = o["vergence"]
        lines.append(f"  fine vergence: {v['converged']} of {v['matched']} converged "
                     f"({100 * v['converged_fraction']:.1f} %), median {v['median_steps']:.0f} steps; "
                     f"median confidence of taught fixations {o['median_confidence_taught']:.2f}")
    return "\n".join(lines)


def run_pursuit_command(args: argparse.Namespace) -> int:
    """`headctl experiment pursuit`: tracking error against target speed (headctl.experiments.pursuit)."""
    from headctl.experiments.pursuit import SPEEDS_DEG_S, format_result, run_pursuit

    try:
        speeds = tuple(float(v) for v in args.speeds.split(",")) if args.speeds else SPEEDS_DEG_S
    except ValueError:
        print(f"--speeds {args.speeds!r}: expected numbers separated by commas (deg/s)", file=sys.stderr)
        return 2
    result = run_pursuit(args.out, speeds, latency_s=args.latency_ms / 1e3, map_path=args.map, seed=args.seed,
                         profile=args.profile)
    print(format_result(result))
    print(f"wrote {args.out}/pursuit-{args.profile}.csv, .png, .json")
    return 0


__all__ = ["register", "run"]
