"""`headctl experiment NAME`: the paper's simulated experiments, with CSV, plot and summary.

NAME is one of `calib_free.sim.experiments.EXPERIMENTS` (learn, baseline, prism, pan-defect,
swap: (r, m) pairs straight from the geometric head model) or `headctl.experiments.online`'s (online,
online-prism, online-pan-defect: the whole fixation loop on rendered images). The run
learns with a progress bar, writes
`<out>/<name>-<profile>.csv` (per fixation: raw and averaged errors) and `.png` (like the
paper's figures), and prints the paper's figures beside the measured ones, the landing error
and the representation's floor.

`headctl experiment relearn BAG` learns a recorded session again (`headctl.experiments.relearn`):
a fresh map, the bag's fixations replayed in order; it prints the fixations taught, the
refusals by reason and the learning curve, recorded beside replayed (`--json`: as JSON).
"""
from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path

from tqdm import tqdm

from calib_free.gaze.exploration import EXPLORATION_KINDS
from calib_free.lens import LENS_KINDS
from calib_free.map.params import PROFILES
from drivers.sim.scene import ROOMS as ROOM_KINDS
from headctl.experiments import paper
from headctl.experiments.paper import ExperimentRequest
from headctl.experiments.report import write_outputs
from headctl.experiments.runs import RUNS_DIR
from headctl.experiments.sweep import SETTABLE, SweepError, build_runs, parse_seeds, parse_set, run_sweep

log = logging.getLogger(__name__)

# The options of one run a sweep passes on to all its runs (`--set` varies them).
SWEEP_BASE_OPTIONS = ("fixations", "width", "height", "lens", "floor_samples", "landing_every", "exploration", "room",
                      "config")


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser(
        "experiment", help="run one of the paper's simulated experiments (learning curves, plot, summary)",
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("name", choices=paper.experiment_names() + ["pursuit", "relearn", "sweep"],
                   help="which experiment (online*: on rendered images through the fixation loop); "
                        "sweep NAME: NAME over seeds, profiles and settings on Dask (headctl.experiments.sweep); "
                        "relearn BAG: a recording's fixations replayed on a fresh map")
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
    p.add_argument("--config", default=None, metavar="FILE",
                   help="online* and pursuit: the simulated head whose world (cameras, servos, room) the run "
                        "happens in (default configs/sim.yaml, the realistic world; configs/sim-ideal.yaml is the "
                        "kind one); relearn: the config whose gaze_map and fixation sections to learn with "
                        "(default: the bag's recorded config, else configs/sim.yaml)")
    add_sweep_arguments(p)
    relearn = p.add_argument_group("relearn (headctl experiment relearn BAG ...)")
    relearn.add_argument("--every", type=int, default=100, metavar="N",
                         help="fixations per point of the learning curve (default 100)")
    relearn.add_argument("--json", action="store_true", help="print the report as JSON")
    p.add_argument("--map", type=Path, default=None, metavar="FILE",
                   help="pursuit: the gaze map to pursue with (default: one learned on the geometric head model)")
    p.add_argument("--speeds", default=None, metavar="S,S,...",
                   help="pursuit: target speeds, deg/s (default 5,10,20,30,40)")
    p.add_argument("--latency-ms", type=float, default=40.0,
                   help="pursuit: frame-to-command latency modelled on the manual clock (default 40, as measured "
                        "on the real-time daemon)")
    p.add_argument("--timing", choices=("ideal", "free_running"), default=None,
                   help="pursuit: both cameras' frame timing preset (docs/sim-world.md; default: the config's)")
    p.add_argument("--skew-ms", type=float, default=None,
                   help="pursuit, with --timing free_running: the right camera's phase this long after the "
                        "left's (negative: before); default: each drawn from the seed")
    p.add_argument("--skew-correction", action=argparse.BooleanOptionalAction, default=True,
                   help="pursuit: bring each disparity to the left image's time (tracking.correct_skew; default on)")
    p.set_defaults(func=run)
    # What a sweep compares against to tell the options given from the defaults.
    p.set_defaults(defaults={dest: p.get_default(dest) for dest in SWEEP_BASE_OPTIONS + ("out",)})


def add_sweep_arguments(p: argparse.ArgumentParser) -> None:
    """The sweep's options on `headctl experiment`'s parser."""
    group = p.add_argument_group("sweep (headctl experiment sweep NAME ...)")
    group.add_argument("swept", nargs="?", metavar="NAME|BAG",
                       help="with sweep: the experiment to run over the grid; with relearn: the bag")
    group.add_argument("--seeds", default="0-4", help="seeds, such as 0-4 or 0,1,5 (default 0-4)")
    group.add_argument("--profiles", default="default", help="gaze map profiles, comma-separated (default: default)")
    group.add_argument("--set", action="append", default=[], metavar="KEY=V1,V2",
                       help=f"one more axis of the grid; KEY one of {', '.join(SETTABLE)} (repeatable)")
    group.add_argument("--scheduler", default=None, metavar="tcp://HOST:8786",
                       help="an existing Dask scheduler (the project installed on its workers); "
                            "default: a local cluster")
    group.add_argument("--workers", type=int, default=2,
                       help="processes of the local cluster, one thread each (default 2)")


def request_of(args: argparse.Namespace) -> ExperimentRequest:
    """The experiment `args` ask for."""
    return ExperimentRequest(args.name, args.profile, fixations=args.fixations, seed=args.seed, width=args.width,
                             height=args.height, lens=args.lens, floor_samples=args.floor_samples,
                             landing_every=args.landing_every, pose=args.pose, exploration=args.exploration,
                             room=args.room, config=args.config)


def run(args: argparse.Namespace) -> int:
    if args.name == "pursuit":
        return run_pursuit_command(args)
    if args.name == "relearn":
        return run_relearn_command(args)
    if args.name == "sweep":
        # Every run of the sweep takes the experiment options given here; --set varies them.
        base = [str(v) for dest in SWEEP_BASE_OPTIONS if getattr(args, dest, None) != args.defaults[dest]
                for v in ("--" + dest.replace("_", "-"), getattr(args, dest))]
        if not args.pose:
            base.append("--no-pose")
        if args.out == args.defaults["out"]:
            args.out = args.out / f"sweep-{args.swept}"
        return run_sweep_command(args, base)
    if args.swept:
        print(f"{args.swept!r}: a second experiment name is taken by sweep only", file=sys.stderr)
        return 2
    request = request_of(args)
    problem = request.problem()
    if problem:
        print(problem, file=sys.stderr)
        return 2
    spec = request.spec()
    args.out.mkdir(parents=True, exist_ok=True)
    with tqdm(total=spec.fixations, desc=f"{spec.name} ({args.profile})", unit="fix",
              disable=None, file=sys.stderr) as bar:

        def progress(fixations: int, taught: int | None) -> None:
            bar.update(fixations)
            if taught is not None:
                bar.set_postfix(taught=taught, refresh=False)

        report = paper.learn(request, progress)
    report = paper.measure_floor(report, say=lambda text: print(text, file=sys.stderr))
    print(write_outputs(report, args.out))
    return 0


def run_sweep_command(args: argparse.Namespace, base: list[str]) -> int:
    """`headctl experiment sweep`: `base` holds the experiment options every run shares."""
    from headctl.experiments.summary import summarise_sweep

    if not args.swept:
        print("sweep: name the experiment to sweep (headctl experiment sweep online ...)", file=sys.stderr)
        return 2
    if args.workers < 1:
        print(f"--workers must be at least 1, got {args.workers}", file=sys.stderr)
        return 2
    try:
        runs = build_runs(args.swept, parse_seeds(args.seeds),
                          [p.strip() for p in args.profiles.split(",") if p.strip()], parse_set(args.set), base)
    except SweepError as err:
        print(err, file=sys.stderr)
        return 2
    out: Path = args.out
    print(f"sweep: {len(runs)} runs of {args.swept} into {out / RUNS_DIR}", file=sys.stderr)
    done, failed = run_sweep(runs, out, args.scheduler, args.workers)
    if done:
        print(f"sweep: {len(done)} runs were already finished and are kept", file=sys.stderr)
    summary = summarise_sweep([r for r in runs if r not in failed], out)
    print(summary.table())
    print(f"wrote {out / 'summary.csv'}, {out / 'summary.json'}, {out / 'summary.png'}")
    if failed:
        print(f"sweep: {len(failed)} runs failed: " + ", ".join(r.run_id for r in failed), file=sys.stderr)
        return 1
    return 0


def run_relearn_command(args: argparse.Namespace) -> int:
    """`headctl experiment relearn BAG`: a recording learned again (headctl.experiments.relearn)."""
    import json

    from headctl.experiments.relearn import RelearnError, RelearnRequest, format_report, relearn
    from headctl.errors import ConfigError
    from headctl.ros2.bag_reader import BagReadError

    if not args.swept:
        print("relearn: name the bag (headctl experiment relearn BAG)", file=sys.stderr)
        return 2
    with tqdm(desc="relearn", unit="fix", disable=None, file=sys.stderr) as bar:

        def progress(fixations: int, taught: int, rate_per_s: float) -> None:
            bar.update(fixations - bar.n)
            bar.set_postfix(taught=taught, refresh=False)

        try:
            report = relearn(RelearnRequest(Path(args.swept), None if args.config is None else Path(args.config), args.every, progress_every=10), progress)
        except (RelearnError, BagReadError, ConfigError) as err:
            bar.close()
            print(f"relearn: {err}", file=sys.stderr)
            return 1
    print(json.dumps(report.as_dict(), indent=2) if args.json else format_report(report))
    return 0


def run_pursuit_command(args: argparse.Namespace) -> int:
    """`headctl experiment pursuit`: tracking error against target speed (headctl.experiments.pursuit)."""
    from headctl.experiments.pursuit import SPEEDS_DEG_S, PursuitSpec, format_result, run_pursuit, write_pursuit

    try:
        speeds = tuple(float(v) for v in args.speeds.split(",")) if args.speeds else SPEEDS_DEG_S
    except ValueError:
        print(f"--speeds {args.speeds!r}: expected numbers separated by commas (deg/s)", file=sys.stderr)
        return 2
    spec = PursuitSpec(speeds, latency_s=args.latency_ms / 1e3, map_path=args.map, seed=args.seed,
                       profile=args.profile, config=None if args.config is None else Path(args.config),
                       timing=args.timing, correct_skew=args.skew_correction,
                       skew_s=None if args.skew_ms is None else args.skew_ms / 1e3)
    summary = write_pursuit(run_pursuit(spec), args.out)
    print(format_result(summary))
    print(f"wrote {args.out}/{spec.stem}.csv, .png, .json")
    return 0


__all__ = ["register", "run"]
