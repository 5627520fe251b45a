"""The geometric experiments' sweeps summed up: the figures the docs/results/ pages state, and plots.

Reads the runs that `headctl experiment sweep NAME --profiles default,paper` kept under
`<sweeps>/sweep-NAME/runs/` (each run's JSON and per-fixation CSV) for `learn` (also
`learn-nopose`, the same sweep with `--no-pose`), `baseline`, `prism`, `pan-defect` and `swap`,
and prints per experiment and profile, as median [interquartile range] across the seeds:

- learn: pan, tilt, vergence and retinal error over the last 10 fixations (the paper's
  figure) and the mean of the last 200; the landing error and the representation's floor;
  the landing error at a few checks along the run;
- re-adaptation: per change, the fixations until the retinal error is back (how many seeds
  came back within the run and within the goal) and the landing error before, at worst within
  700 fixations after (and at which check), and 700 fixations after; the fixations until a
  landing check is back within 1.25 times the last one before the change.

The online sweeps, the same way: `online-prism` and `online-pan-defect` as the re-adaptation
experiments (in fixations: their curves and changes count adaptations, each seed its own, and
the retinal error's recovery is scaled by the run's fixations per adaptation after the change;
goal 700 fixations), and the exploration sweep (`--exploration FOLDER`: `online` over
`--set exploration=random,teaching --set room=generated,photos`, with `landing_every` 50),
per setting: the share of fixations that taught, the landing error on the room's targets and
on the joint range's, each over `learn`'s at the same number of fixations seed by seed
(`--learn FOLDER`, a `learn` sweep of as many fixations), the fixations until 90 % of the
improvement, and what the refused fixations were.

Plots (`--figures DIR`): per experiment and profile, the median across seeds of the paper's
curves (pan, tilt, vergence and retinal error, each averaged over the last 10 fixations) and
of the landing error, each with its interquartile band.

    .venv/bin/python -m benchmarks.diag.summarise_sweeps [--sweeps runs] [--figures DIR]
        [--plots learn-default,prism-default,...] [--json FILE]
        [--exploration runs/sweep-exploration --learn runs/sweep-learn-exploration]
"""
from __future__ import annotations

import argparse
import csv
import json
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterator, Sequence

import numpy as np

from headctl.experiments.paper_figures import GEOMETRIC
from headctl.experiments.sweep import RUN_FILE, result_json
from headctl.experiments.summary import run_figures, spread

EXPERIMENTS = ("learn", "learn-nopose", "baseline", "prism", "pan-defect", "swap", "online-prism", "online-pan-defect")
LEARN_FIGURES = ("pan_deg", "tilt_deg", "vergence_deg", "retinal_error")
CURVE_COLUMNS = ("pan_error_avg10_deg", "tilt_error_avg10_deg", "vergence_error_avg10_deg", "retinal_error_avg10")
RECOVERY_TOLERANCE = 1.25  # "back": within this factor of the level before the change (as the retinal error's)
LANDING_CHECKS = (100, 300, 500, 1000, 2000)  # fixations at which the learn table gives the landing error


@dataclass
class Run:
    profile: str
    seed: int
    summary: dict[str, Any]
    figures: dict[str, float | None]
    curves: np.ndarray  # (fixations, 4): CURVE_COLUMNS


def finished_runs(folder: Path) -> Iterator[tuple[dict[str, Any], Path]]:
    """(what the run was, its result JSON) for every run of a sweep folder that finished well."""
    for run_folder in sorted((folder / "runs").iterdir()):
        if run_folder.name.startswith(".") or not (run_folder / RUN_FILE).is_file():
            continue
        record = json.loads((run_folder / RUN_FILE).read_text())
        if record.get("code") == 0:
            yield record, result_json(run_folder)


def load_runs(folder: Path) -> list[Run]:
    """Every finished run of a sweep folder, in (profile, seed) order."""
    runs = []
    for record, path in finished_runs(folder):
        summary = json.loads(path.read_text())
        with open(path.with_suffix(".csv"), newline="") as f:
            rows = list(csv.DictReader(f))
        curves = np.array([[float(row[c]) for c in CURVE_COLUMNS] for row in rows])
        figures, _ = run_figures(summary)
        runs.append(Run(record["profile"], int(record["seed"]), summary, figures, curves))
    return sorted(runs, key=lambda r: (r.profile, r.seed))


def by_profile(runs: Sequence[Run]) -> dict[str, list[Run]]:
    profiles: dict[str, list[Run]] = {}
    for run in runs:
        profiles.setdefault(run.profile, []).append(run)
    return profiles


def fmt(values: Sequence[float | None], scale: float = 1.0, digits: int = 2, unit: str = "") -> str:
    """'median [q25, q75]' of the values (None and NaN left out; their count said)."""
    s = spread([None if v is None else scale * v for v in values])
    if s["median"] is None:
        return "–"
    text = f"{s['median']:.{digits}f}{unit} [{s['q25']:.{digits}f}, {s['q75']:.{digits}f}]"
    missing = len(values) - int(s["n"] or 0)
    return text + (f" ({missing} of {len(values)} without)" if missing else "")


def landing_at(run: Run, fixation: int) -> float | None:
    return next((float(px) for at, px in run.summary["landing_curve_px"] if at == fixation), None)


def learn_rows(runs: Sequence[Run]) -> dict[str, dict[str, str]]:
    rows: dict[str, dict[str, str]] = {}
    for profile, group in by_profile(runs).items():
        row: dict[str, str] = {"seeds": ", ".join(str(r.seed) for r in group)}
        for window in ("last10", "last200"):
            for name in LEARN_FIGURES:
                percent = name == "retinal_error"
                row[f"{name}_{window}"] = fmt([r.figures[f"{name}_{window}"] for r in group],
                                              scale=100.0 if percent else 1.0, unit=" %" if percent else "°")
        row["landing_px"] = fmt([r.figures["landing_error_px"] for r in group], unit=" px")
        row["floor_px"] = fmt([r.figures["floor_px"] for r in group], unit=" px")
        row["landing_over_floor"] = fmt([r.figures["landing_over_floor"] for r in group])
        for at in LANDING_CHECKS:
            row[f"landing_at_{at}_px"] = fmt([landing_at(r, at) for r in group], unit=" px")
        rows[profile] = row
    return rows


ONLINE_GOAL_FIXATIONS = 700  # the online re-adaptation goal (their runs carry none of their own)


def in_fixations(run: Run, at: int) -> tuple[list[tuple[int, float]], int, float]:
    """The run's landing checks as (fixation, px), the change's fixation, and fixations per
    adaptation after it. The geometric experiments count both in fixations; the online ones
    count their curves and the change in adaptations (taught fixations), and say at which
    fixation each landing check was."""
    curve = [(int(x), float(px)) for x, px in run.summary["landing_curve_px"]]
    online = run.summary.get("online")
    if not online:
        return curve, at, 1.0
    fixations = [int(f) for f in online["landing_at_fixations"]]
    nearest = min(range(len(curve)), key=lambda k: abs(curve[k][0] - at))
    change = fixations[nearest]
    per_adaptation = (online["fixations"] - change) / max(1, run.summary["fixations"] - at)
    return [(f, px) for f, (_, px) in zip(fixations, curve)], change, per_adaptation


def landing_back(run: Run, at: int, tolerance: float = RECOVERY_TOLERANCE) -> int | None:
    """Fixations after the change at `at` until a landing check is within `tolerance` times the
    last check before it (None if none is); the checks' spacing is the resolution."""
    curve, change, _ = in_fixations(run, at)
    before = [px for x, px in curve if x <= change]
    after = [(x, px) for x, px in curve if x > change]
    if not before:
        return None
    return next((x - change for x, px in after if px <= tolerance * before[-1]), None)


def worst_check(run: Run, at: int) -> int | None:
    """Fixations after the change at `at` of the worst landing check within 700 after it."""
    curve, change, _ = in_fixations(run, at)
    after = [(px, x) for x, px in curve if change < x <= change + 700]
    return max(after)[1] - change if after else None


def recovery(run: Run, at: int) -> float | None:
    """Fixations until the retinal error is back after the change at `at` (None: not back)."""
    adaptations = run.figures[f"recovery_at_{at}"]
    return None if adaptations is None else adaptations * in_fixations(run, at)[2]


def readaptation_rows(runs: Sequence[Run]) -> dict[str, list[dict[str, str]]]:
    rows: dict[str, list[dict[str, str]]] = {}
    for profile, group in by_profile(runs).items():
        changes = []
        for k, change in enumerate(group[0].summary["changes"]):
            # Each run's own change: the online experiments count in adaptations, which differ by seed.
            ats = [r.summary["changes"][k]["at"] for r in group]
            recovered = [recovery(r, at) for r, at in zip(group, ats)]
            back = sum(v is not None for v in recovered)
            goal = change.get("goal_fixations") or ONLINE_GOAL_FIXATIONS

            def each(name: str) -> list[Any]:
                return [r.figures[name.format(at=at)] for r, at in zip(group, ats)]

            changes.append({
                "at": ", ".join(sorted({str(at) for at in ats})),
                "recovery_fixations": fmt(recovered, digits=0),
                "recovery_each_seed": ", ".join("not back" if v is None else f"{v:.0f}" for v in recovered),
                "back": f"{back} of {len(group)}",
                "goal": str(goal),
                "within_goal": f"{sum(v is not None and v <= goal for v in recovered)} of {len(group)}",
                "landing_before_px": fmt(each("landing_before_{at}_px"), digits=1),
                "landing_worst_after_px": fmt(each("landing_worst_after_{at}_px"), digits=1),
                "landing_700_after_px": fmt(each("landing_700_after_{at}_px"), digits=1),
                "landing_worst_at": ", ".join(str(worst_check(r, at)) for r, at in zip(group, ats)),
                "landing_back_fixations": fmt([landing_back(r, at) for r, at in zip(group, ats)], digits=0),
                "landing_back_each_seed": ", ".join(str(landing_back(r, at)) for r, at in zip(group, ats)),
            })
        rows[profile] = changes
    return rows


def exploration_rows(folder: Path, learn_folder: Path) -> dict[str, dict[str, str]]:
    """Per setting of an exploration sweep (exploration x room), the figures of the exploration
    goals; ratios over `learn` seed by seed."""
    learn = {r.seed: r for r in load_runs(learn_folder)}
    groups: dict[str, list[tuple[int, dict[str, Any]]]] = {}
    for record, path in finished_runs(folder):
        name = ", ".join(f"{k}={v}" for k, v in record["settings"].items())
        groups.setdefault(name, []).append((int(record["seed"]), json.loads(path.read_text())))
    rows: dict[str, dict[str, str]] = {}
    for name, group in sorted(groups.items()):
        group.sort(key=lambda g: g[0])
        online = [summary["online"] for _, summary in group]
        last = [o["landing_at_fixations"][-1] for o in online]  # the curve's own x counts adaptations

        def over_learn(values: list[float], at: list[int]) -> str:
            ratios = [v / learn_px if (learn_px := landing_at(learn[seed], n)) else None
                      for (seed, _), v, n in zip(group, values, at) if seed in learn]
            return fmt(ratios) if ratios else "– (no learn run)"

        room = [summary["landing_error_px"] for _, summary in group]
        joint_range = [summary["landing_joint_range_px"] for _, summary in group]
        at_300 = [next((px for at, px in zip(o["landing_at_fixations"], [c[1] for c in s["landing_curve_px"]])
                        if at == 300), None) for o, (_, s) in zip(online, group)]
        row = {
            "seeds": ", ".join(str(seed) for seed, _ in group),
            "taught_percent": fmt([o["taught"] / o["fixations"] for o in online], scale=100.0, digits=1, unit=" %"),
            "landing_room_px": fmt(room, unit=" px"),
            "landing_room_over_learn": over_learn(room, last),
            "landing_joint_range_px": fmt(joint_range, digits=1, unit=" px"),
            "landing_joint_range_over_learn": over_learn(joint_range, last),
            "landing_room_at_300_px": fmt(at_300, unit=" px"),
            "fixations_to_90pct": fmt([s.get("fixations_to_90pct") or _to_90pct(o, s) for o, (_, s) in zip(online, group)],
                                      digits=0),
            # A stricter reading of the same curve: until the room's landing error stays within
            # twice its last value.
            "fixations_to_within_2x_last": fmt([_to_within(o, s, 2.0) for o, (_, s) in zip(online, group)], digits=0),
        }
        outcomes = sorted({k for o in online for k in o["outcomes"] if k != "taught"})
        for outcome in outcomes:
            row[f"refused: {outcome}"] = f"{np.median([o['outcomes'].get(outcome, 0) for o in online]):.0f}"
        rows[name] = row
    return rows


def _to_within(online: dict[str, Any], summary: dict[str, Any], factor: float) -> float | None:
    """Fixations from which every landing check is within `factor` times the last one."""
    curve = [px for _, px in summary["landing_curve_px"]]
    if not curve:
        return None
    at = online["landing_at_fixations"]
    outside = [n for n, px in enumerate(curve) if px > factor * curve[-1]]  # never the last (factor > 1)
    return float(at[outside[-1] + 1 if outside else 0])


def _to_90pct(online: dict[str, Any], summary: dict[str, Any]) -> float | None:
    """Fixations until the room's landing error has made 90 % of its improvement, from the
    random map's to the last check's (on the checks: their spacing is the resolution)."""
    start = online.get("landing_start_px")
    curve = [px for _, px in summary["landing_curve_px"]]
    if start is None or not curve:
        return None
    goal = start - 0.9 * (start - curve[-1])
    return next((float(at) for at, px in zip(online["landing_at_fixations"], curve) if px <= goal), None)


def band(values: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    q25, median, q75 = np.percentile(values, [25, 50, 75], axis=0)
    return median, q25, q75


def plot(name: str, profile: str, group: Sequence[Run], path: Path) -> None:
    """The median and interquartile band across seeds of the paper's curves and the landing error."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import FuncFormatter

    length = min(len(r.curves) for r in group)
    curves = np.stack([r.curves[:length] for r in group])  # (seeds, fixations, 4)
    n = np.arange(1, length + 1)
    fig, axes = plt.subplots(5, 1, figsize=(8, 11), sharex=True)
    panels = (("pan error [deg]", "pan", 1.0), ("tilt error [deg]", "tilt", 1.0),
              ("vergence error [deg]", "vergence", 1.0), ("retinal error [%]", "retinal", 100.0))
    for k, (ax, (label, key, scale)) in enumerate(zip(axes, panels)):
        median, q25, q75 = band(curves[:, :, k] * scale)
        ax.fill_between(n, q25, q75, color="tab:blue", alpha=0.4, lw=0, label="interquartile range")
        ax.plot(n, median, lw=0.6, color="navy", label=f"median of {len(group)} seeds")
        ax.axhline(GEOMETRIC.plot_values()[key], ls="--", lw=0.8, color="tab:red", label=GEOMETRIC.label)
        ax.set_ylabel(label)
        ax.set_ylim(0, max(3 * GEOMETRIC.plot_values()[key], float(np.percentile(median, 99)) * 1.1))
        ax.grid(alpha=0.3)
    axes[0].legend(loc="upper right", fontsize=8)
    ax = axes[4]
    checks = [int(at) for at, _ in group[0].summary["landing_curve_px"]]
    landing = np.array([[landing_at(r, at) or np.nan for at in checks] for r in group])
    median, q25, q75 = band(landing)
    ax.fill_between(checks, q25, q75, color="tab:green", alpha=0.25, lw=0)
    ax.plot(checks, median, "o-", ms=3, color="tab:green", label="median landing error")
    floors = [r.figures["floor_px"] for r in group if r.figures["floor_px"]]
    if floors:
        ax.axhline(float(np.median(floors)), ls=":", color="black",
                   label=f"(x, y, d) floor {np.median(floors):.1f} px")
    ax.set_yscale("log")
    plain = FuncFormatter(lambda v, _: f"{v:g}")
    ax.yaxis.set_major_formatter(plain)
    ax.yaxis.set_minor_formatter(plain)
    ax.tick_params(axis="y", which="minor", labelsize=7)
    ax.set_ylabel("landing error [px]")
    ax.set_xlabel("fixations")
    ax.grid(alpha=0.3, which="both")
    ax.legend(loc="upper right", fontsize=8)
    for change in group[0].summary["changes"]:
        for a in axes:
            a.axvline(change["at"], color="gray", lw=0.8, ls="-.")
    seeds = ", ".join(str(r.seed) for r in group)
    shown = "learn --no-pose" if name == "learn-nopose" else name
    fig.suptitle(f"{shown} ({profile} profile): median and interquartile range over seeds {seeds}")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--sweeps", type=Path, default=Path("runs"), help="where the sweep-NAME folders are")
    parser.add_argument("--figures", type=Path, default=None, help="write the plots into this folder")
    parser.add_argument("--plots", default=None,
                        help="which plots, NAME-PROFILE comma-separated (default: every experiment and profile)")
    parser.add_argument("--json", type=Path, default=None, help="also write every figure printed as JSON")
    parser.add_argument("--exploration", type=Path, default=None, help="an exploration sweep's folder")
    parser.add_argument("--learn", type=Path, default=Path("runs/sweep-learn-exploration"),
                        help="a learn sweep of as many fixations, for the exploration sweep's ratios")
    args = parser.parse_args()
    wanted = set(args.plots.split(",")) if args.plots else None
    report: dict[str, Any] = {}
    for name in EXPERIMENTS:
        folder = args.sweeps / f"sweep-{name}"
        if not (folder / "runs").is_dir():
            print(f"{name}: no sweep at {folder}")
            continue
        runs = load_runs(folder)
        if not runs:
            print(f"{name}: no finished run in {folder}")
            continue
        rows: Any = learn_rows(runs) if name.startswith("learn") else readaptation_rows(runs)
        report[name] = rows
        print(f"\n{name} ({folder}): median [interquartile range] across seeds")
        for profile, row in rows.items():
            print(f"  {profile}")
            for entry in (row if isinstance(row, list) else [row]):
                for key, value in entry.items():
                    print(f"    {key:<26} {value}")
                print()
        if args.figures:
            args.figures.mkdir(parents=True, exist_ok=True)
            for profile, group in by_profile(runs).items():
                if wanted is None or f"{name}-{profile}" in wanted:
                    path = args.figures / f"{name}-{profile}.png"
                    plot(name, profile, group, path)
                    print(f"  wrote {path}")
    if args.exploration:
        rows = exploration_rows(args.exploration, args.learn)
        report["exploration"] = rows
        print(f"\nexploration ({args.exploration}; learn: {args.learn}): median [interquartile range] across seeds")
        for name, row in rows.items():
            print(f"  {name}")
            for key, value in row.items():
                print(f"    {key:<34} {value}")
            print()
    if args.json:
        args.json.write_text(json.dumps(report, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
