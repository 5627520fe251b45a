"""The runs of `benchmarks.bench.looks_daemon` together: the figures the results pages give.

A run is a set of seeds, one JSON file each (`looks_daemon --json`). For each run given, and
for all of them together, this prints the figures of the looks' goal:

- on target, of the looks the daemon took on (not refused before the head moved): each seed's
  share, their median [IQR], and the looks pooled, with the pooled share's 95 % interval
  (Wilson's score interval);
- the same without the looks that ended at the joint limits (their target beyond them);
- truly on target: counted on target and truly within `LOOK_ALIKE_PX` of the fovea; the
  look-alikes (counted on target, truly farther): their pixel, how far, and where the eyes
  ended against the vergence the first saccade planned (runs that recorded it);
- the final error's p90 (the daemon's own) and the look time's p50: median [IQR] of the seeds;
- the failures by kind (`failure_class`);
- by the image's columns (`--columns`): the looks taken on, on target, look-alikes and
  failures, where in the image the looks fail.

`--plot FILE` draws every look taken on at its pixel by how it ended, and each run's seeds
and pooled share against the goal. `--json FILE` writes the figures.

    .venv/bin/python -m benchmarks.bench.looks_runs --run NAME=FILE[,FILE...] [--run ...]
        [--columns 8] [--plot FILE.png] [--json FILE]

A FILE may be a glob (quoted): `--run 21c49fa='runs/looks22-sim-*.json'`.
"""
from __future__ import annotations

import argparse
import collections
import enum
import glob
import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from calib_free.gaze.look import LookOutcome

LOOK_ALIKE_PX = 3.0  # counted on target, truly this far from the fovea or farther: a look-alike
GOAL = 0.95  # of the looks taken on, on target
Z_95 = 1.959964


class FailureClass(enum.StrEnum):
    """How a look taken on failed, in the words the results pages use."""

    AMBIGUOUS = "ambiguous"  # two places match the target's patch and nothing tells which is it
    JOINT_LIMITS = "at the joint limits"  # the target beyond them: the head stopped there
    OFF_THE_FOVEA = "off the fovea after the corrective steps"
    OTHER = "other"


def failure_class(row: dict[str, Any]) -> FailureClass:
    """The kind of a failed look of a `looks_daemon` run: at the joint limits by its outcome
    (whatever else its detail says), else ambiguous by its detail, else off the fovea by its
    outcome, else other."""
    if row["outcome"] == LookOutcome.OUT_OF_REACH:
        return FailureClass.JOINT_LIMITS
    if "ambiguous: two places match" in (row.get("detail") or ""):
        return FailureClass.AMBIGUOUS
    if row["outcome"] == LookOutcome.NOT_ON_TARGET:
        return FailureClass.OFF_THE_FOVEA
    return FailureClass.OTHER


def wilson_interval(successes: int, trials: int, z: float = Z_95) -> tuple[float, float]:
    """The score interval of a share of `successes` in `trials` (Wilson): unlike p ± z·se, it
    stays within [0, 1] and is not too narrow near them."""
    if trials <= 0:
        raise ValueError("a share of no trials has no interval")
    p = successes / trials
    centre = (p + z * z / (2 * trials)) / (1 + z * z / trials)
    half = z / (1 + z * z / trials) * math.sqrt(p * (1 - p) / trials + z * z / (4 * trials * trials))
    return max(0.0, centre - half), min(1.0, centre + half)


@dataclass(frozen=True)
class Seed:
    """One seed's file of a run: its name and its looks."""

    path: Path
    rows: list[dict[str, Any]]
    final_p90_px: float | None
    look_time_p50_s: float | None

    world: str | None = None
    config: str | None = None

    @classmethod
    def read(cls, path: Path) -> "Seed":
        try:
            data = json.loads(path.read_text())
        except (OSError, json.JSONDecodeError) as err:
            raise SystemExit(f"{path}: cannot read a looks_daemon result ({err})") from None
        if not isinstance(data, dict) or "rows" not in data:
            raise SystemExit(f"{path}: no 'rows': not a file of `looks_daemon --json`")
        return cls(path, list(data["rows"]), (data.get("final_error_px") or {}).get("p90"),
                   (data.get("duration_s") or {}).get("p50"), data.get("world"), data.get("config"))

    @property
    def taken_on(self) -> list[dict[str, Any]]:
        return [r for r in self.rows if r["state"] != "refused"]


def is_look_alike(row: dict[str, Any]) -> bool:
    return bool(row["on_target"]) and (row.get("true_error_px") or 0.0) >= LOOK_ALIKE_PX


def quartiles(values: list[float]) -> dict[str, float] | None:
    if not values:
        return None
    p25, p50, p75 = (float(v) for v in np.percentile(values, [25, 50, 75]))
    return {"median": p50, "p25": p25, "p75": p75}


def figures(seeds: list[Seed], width: int, columns: int) -> dict[str, Any]:
    """The figures of the looks of `seeds` (see the module doc); `width` the image's, in px."""
    rows = [r for s in seeds for r in s.taken_on]
    if not rows:
        raise SystemExit(", ".join(str(s.path) for s in seeds) + ": no look was taken on")
    on = sum(bool(r["on_target"]) for r in rows)
    within_reach = [r for r in rows if r["outcome"] != LookOutcome.OUT_OF_REACH]
    look_alikes = [r for r in rows if is_look_alike(r)]
    low, high = wilson_interval(on, len(rows))
    failures = collections.Counter(failure_class(r) for r in rows if not r["on_target"])
    shares = [sum(bool(r["on_target"]) for r in s.taken_on) / len(s.taken_on) for s in seeds if s.taken_on]
    bands: list[dict[str, Any]] = []
    edges = np.linspace(0.0, float(width), columns + 1)
    for left, right in zip(edges[:-1], edges[1:]):
        mine = [r for r in rows if left <= r["xy"][0] < right or (right == edges[-1] and r["xy"][0] == right)]
        bands.append({"x_px": [float(left), float(right)], "taken_on": len(mine),
                      "on_target": sum(bool(r["on_target"]) for r in mine),
                      "look_alikes": sum(is_look_alike(r) for r in mine),
                      "failed": sum(not r["on_target"] for r in mine)})
    return {
        "files": [str(s.path) for s in seeds],
        "taken_on": len(rows), "on_target": on,
        "seeds_on_target_fraction": shares,
        "on_target_fraction": quartiles(shares),
        "pooled": {"fraction": on / len(rows), "interval_95": [low, high]},
        "pooled_without_joint_limits": sum(bool(r["on_target"]) for r in within_reach) / len(within_reach)
        if within_reach else None,
        "truly_on_target": {"looks": on - len(look_alikes), "fraction": (on - len(look_alikes)) / len(rows)},
        "look_alikes": [{"xy": [round(float(v), 1) for v in r["xy"]], "true_error_px": round(r["true_error_px"], 2),
                         "vergence_off_deg": r.get("vergence_off_deg")} for r in look_alikes],
        "final_error_p90_px": quartiles([s.final_p90_px for s in seeds if s.final_p90_px is not None]),
        "look_time_p50_s": quartiles([s.look_time_p50_s for s in seeds if s.look_time_p50_s is not None]),
        "failures": {str(kind): failures[kind] for kind in FailureClass},
        "by_column": bands,
    }


def vergence_note(look_alike: dict[str, Any]) -> str:
    """Where a look-alike's eyes ended against the vergence its first saccade planned, where the
    run recorded it."""
    off = look_alike.get("vergence_off_deg")
    return "" if off is None else f" (eyes {off:+.1f} deg from the planned vergence)"


def report(name: str, f: dict[str, Any]) -> str:
    """`f` (`figures`) as the lines the results pages quote."""
    def pct(v: float) -> str:
        return f"{100 * v:.1f} %"

    def spread(q: dict[str, float] | None, unit: str, digits: int) -> str:
        return "—" if q is None else f"{q['median']:.{digits}f} [{q['p25']:.{digits}f}, {q['p75']:.{digits}f}] {unit}"

    share = f["on_target_fraction"]
    pooled = f["pooled"]
    lines = [f"## {name} ({len(f['files'])} seeds)",
             f"on target, of the looks taken on: {pct(share['median'])} [{pct(share['p25'])}, {pct(share['p75'])}] "
             f"(seeds {', '.join(f'{100 * v:.1f}' for v in f['seeds_on_target_fraction'])})",
             f"pooled: {f['on_target']} of {f['taken_on']}, {pct(pooled['fraction'])} "
             f"(95 % interval {pct(pooled['interval_95'][0])} to {pct(pooled['interval_95'][1])})",
             "without the looks at the joint limits: " + ("—" if f["pooled_without_joint_limits"] is None
                                                          else pct(f["pooled_without_joint_limits"])),
             f"truly on target (within {LOOK_ALIKE_PX:g} px): {f['truly_on_target']['looks']} of {f['taken_on']}, "
             f"{pct(f['truly_on_target']['fraction'])}; look-alikes {len(f['look_alikes'])}"
             + ("" if not f["look_alikes"] else ": " + ", ".join(
                 f"({a['xy'][0]:.0f}, {a['xy'][1]:.0f}) {a['true_error_px']:.1f} px" + vergence_note(a)
                 for a in f["look_alikes"])),
             f"final error p90 {spread(f['final_error_p90_px'], 'px', 2)}; "
             f"look time p50 {spread(f['look_time_p50_s'], 's', 2)}",
             "failed: " + ", ".join(f"{kind} {count}" for kind, count in f["failures"].items()),
             "by column (x px: taken on, on target, look-alikes, failed): " + "; ".join(
                 f"{b['x_px'][0]:.0f}-{b['x_px'][1]:.0f}: {b['taken_on']}, {b['on_target']}, {b['look_alikes']}, "
                 f"{b['failed']}" for b in f["by_column"])]
    return "\n".join(lines)


def plot(runs: dict[str, list[Seed]], figures_by_run: dict[str, dict[str, Any]], together: dict[str, dict[str, Any]],
         size: tuple[int, int], path: Path) -> None:
    """Every look taken on at its pixel by how it ended (the first config's runs: one world);
    each run's seeds and pooled share, and each world's runs pooled."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    width, height = size
    fig, (image, shares) = plt.subplots(1, 2, figsize=(12, 4.6), gridspec_kw={"width_ratios": [1.6, 1]})
    styles = {"on target": ("o", "#b8b8b8", 8), "look-alike": ("X", "#e07000", 40),
              FailureClass.AMBIGUOUS: ("s", "#c00000", 22), FailureClass.JOINT_LIMITS: ("^", "#1f5fbf", 26),
              FailureClass.OFF_THE_FOVEA: ("D", "#7a2a9a", 20), FailureClass.OTHER: ("P", "#000000", 26)}
    groups: dict[str, list[list[float]]] = collections.defaultdict(list)
    first = next(iter(runs.values()))[0]
    for seeds in runs.values():
        if (seeds[0].config, seeds[0].world) != (first.config, first.world):
            continue
        for seed in seeds:
            for r in seed.taken_on:
                key = ("look-alike" if is_look_alike(r) else "on target") if r["on_target"] else failure_class(r)
                groups[str(key)].append(r["xy"])
    for key, (marker, colour, area) in styles.items():
        points = np.array(groups.get(str(key), []), dtype=float).reshape(-1, 2)
        if len(points):
            image.scatter(points[:, 0], points[:, 1], marker=marker, c=colour, s=area, linewidths=0.4,
                          label=f"{key} ({len(points)})")
    image.set_xlim(0, width)
    image.set_ylim(height, 0)
    image.set_aspect("equal")
    image.set_xlabel("x (px, left image)")
    image.set_ylabel("y (px)")
    image.set_title(f"where the looks taken on ended, by how: {first.config} ({first.world})", fontsize=10)
    image.legend(loc="upper center", bbox_to_anchor=(0.5, -0.14), ncol=3, fontsize=8, frameon=False)
    rows = [*figures_by_run.items(), *((f"together: {world}", f) for world, f in together.items())]
    names = [name for name, _ in rows]
    for i, (name, f) in enumerate(rows):
        seeds = f["seeds_on_target_fraction"]
        shares.scatter([100 * v for v in seeds], [i] * len(seeds), c="#7f7f7f", s=14, zorder=2)
        low, high = f["pooled"]["interval_95"]
        shares.errorbar([100 * f["pooled"]["fraction"]], [i], xerr=[[100 * (f["pooled"]["fraction"] - low)],
                                                                   [100 * (high - f["pooled"]["fraction"])]],
                        fmt="o", c="#1f5fbf", capsize=4, zorder=3)
    shares.axvline(100 * GOAL, c="#c00000", ls="--", lw=1, label=f"goal {100 * GOAL:g} %")
    shares.set_yticks(range(len(names)), names)
    shares.invert_yaxis()
    shares.set_xlabel("on target, % of the looks taken on")
    shares.set_title("seeds (grey), pooled with its 95 % interval")
    shares.legend(loc="lower left", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def parse_run(text: str) -> tuple[str, list[Path]]:
    """NAME=FILE[,FILE...] (each FILE a path or a glob) as its name and its files, sorted."""
    name, sep, files = text.partition("=")
    if not sep or not name or not files:
        raise argparse.ArgumentTypeError(f"--run {text!r}: expected NAME=FILE[,FILE...]")
    paths: list[Path] = []
    for pattern in files.split(","):
        matched = sorted(glob.glob(pattern))
        if not matched:
            raise argparse.ArgumentTypeError(f"--run {name}: no file matches {pattern!r}")
        paths.extend(Path(p) for p in matched)
    return name, paths


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--run", type=parse_run, action="append", required=True,
                        help="NAME=FILE[,FILE...]: one run's files of looks_daemon --json (globs allowed)")
    parser.add_argument("--columns", type=int, default=8, help="the image's columns to count by (default 8)")
    parser.add_argument("--width", type=int, default=320, help="the left image's width, px (default 320)")
    parser.add_argument("--height", type=int, default=240, help="its height, px, for --plot (default 240)")
    parser.add_argument("--plot", type=Path, help="draw the looks and the shares here (PNG)")
    parser.add_argument("--json", type=Path, help="write the figures here")
    args = parser.parse_args(argv)
    if args.columns < 1:
        parser.error(f"--columns must be at least 1, got {args.columns}")
    names = [name for name, _ in args.run]
    if len(set(names)) != len(names):
        parser.error(f"--run names must differ, got {', '.join(names)}")
    runs = {name: [Seed.read(p) for p in paths] for name, paths in args.run}
    for name, seeds in runs.items():
        kinds = sorted({f"{s.config} ({s.world})" for s in seeds})
        if len(kinds) > 1:
            parser.error(f"--run {name}: its files are of {len(kinds)} configs or worlds ({', '.join(kinds)}): "
                         "one run is one config's seeds")
    by_run = {name: figures(seeds, args.width, args.columns) for name, seeds in runs.items()}
    out: dict[str, Any] = {"runs": by_run, "together": {}}
    for name, f in by_run.items():
        print(report(name, f) + "\n")
    # The runs of one config and world pooled (the results pages' "together").
    worlds: dict[str, list[str]] = collections.defaultdict(list)
    for name, seeds in runs.items():
        worlds[f"{seeds[0].config} ({seeds[0].world})"].append(name)
    for world, members in worlds.items():
        if len(members) > 1:
            out["together"][world] = figures([s for m in members for s in runs[m]], args.width, args.columns)
            print(report(f"together: {world}, {' + '.join(members)}", out["together"][world]) + "\n")
    if args.plot is not None:
        plot(runs, by_run, out["together"], (args.width, args.height), args.plot)
    if args.json is not None:
        args.json.write_text(json.dumps(out, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
