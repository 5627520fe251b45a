"""A sweep's runs summed up across seeds: per setting, each figure's median, interquartile range
and extremes; the landing-error curves' median and interquartile band.

Figures are read from each run's own summary JSON (`headctl experiment`'s): the landing error
at the end and at each check, the paper's errors (last 10, mean of the last 200), the
representation's floor, for the re-adaptation experiments each change's recovery and the
landing error before it, at worst within 700 fixations after it and 700 after (online also
the fixations until their own measured landing was back, and its level before), and for the
online experiments the share of fixations that taught, the exploration's choices, and the
fixations until the landing error had made 90 % of its improvement (from the random map's
to the last).
"""
from __future__ import annotations

import csv
import json
import logging
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Sequence, TypedDict

import numpy as np

from headctl.experiments.runs import RunSpec, result_json, run_dir
from headctl.json_types import JSONObject

log = logging.getLogger(__name__)

IMPROVEMENT_SHARE = 0.9  # "90 % of the final improvement"
# The rows of the printed table, besides each change's recovery (all figures are in the CSV and JSON).
TABLE_FIGURES = ("landing_error_px", "retinal_error_last200", "taught_fraction", "fixations_to_90pct")
# Each change's recovery in the table: the retinal error's, then the measured landing's.
RECOVERY_PREFIXES = ("recovery_at_", "measured_landing_recovery_at_")


def fixations_to_share(curve: Sequence[tuple[float, float]], share: float = IMPROVEMENT_SHARE) -> float | None:
    """The first x of a (x, landing px) curve, starting at the untrained map, at which
    `share` of the improvement from the first to the last value has been made."""
    if len(curve) < 2:
        return None
    start, end = curve[0][1], curve[-1][1]
    if not start > end:
        return None
    bar = end + (1.0 - share) * (start - end)
    return next(float(x) for x, px in curve if px <= bar)


def run_figures(summary: JSONObject) -> tuple[dict[str, float | None], list[tuple[float, float]]]:
    """The figures of one run and its landing curve in fixations (from the untrained map when known)."""
    figures: dict[str, float | None] = {
        "landing_error_px": summary.get("landing_error_px"),
        "landing_joint_range_px": summary.get("landing_joint_range_px"),  # online runs: anywhere in the limits
        "landing_over_floor": summary.get("landing_over_floor"),
        "retinal_error_last10": summary["final"]["retinal_error"],
        "pan_deg_last10": summary["final"]["pan_deg"],
        "tilt_deg_last10": summary["final"]["tilt_deg"],
        "vergence_deg_last10": summary["final"]["vergence_deg"],
        "retinal_error_last200": summary["steady"]["retinal_error"],
        "pan_deg_last200": summary["steady"]["pan_deg"],
        "tilt_deg_last200": summary["steady"]["tilt_deg"],
        "vergence_deg_last200": summary["steady"]["vergence_deg"],
        "floor_px": summary.get("floor_px"),
        "seconds": summary.get("seconds"),
    }
    landing = [(float(at), float(px)) for at, px in summary.get("landing_curve_px", [])]
    online = summary.get("online")
    if online:
        fixations = online["fixations"]
        figures["taught_fraction"] = online["taught"] / fixations if fixations else None
        figures["adaptations"] = summary.get("fixations")
        # The curve's x is in adaptations; the fixations done at each check are kept beside it.
        landing = [(float(n), px) for n, (_, px) in zip(online.get("landing_at_fixations", []), landing)]
        start = online.get("landing_start_px")
        if start is not None:
            landing.insert(0, (0.0, float(start)))
            figures["fixations_to_90pct"] = fixations_to_share(landing)
        chosen = (online.get("exploration_stats") or {}).get("chosen") or {}
        if chosen:
            figures["target_fraction"] = chosen.get("target", 0) / max(1, sum(chosen.values()))
    for change in summary.get("changes", []):
        at = change["at"]
        figures[f"recovery_at_{at}"] = change.get("recovery_fixations")
        figures[f"landing_before_{at}_px"] = change.get("landing_before_px")
        figures[f"landing_700_after_{at}_px"] = change.get("landing_700_after_px")
        figures[f"landing_worst_after_{at}_px"] = change.get("landing_worst_after_px")
        if change.get("measured_landing_before_px") is not None:
            # The fixations' own landing: keyed by the change's fixation, the same in every seed
            # (`at` counts adaptations online, each seed its own).
            at_fixation = change["at_fixation"]
            figures[f"measured_landing_recovery_at_{at_fixation}"] = change["measured_landing_recovery_fixations"]
            figures[f"measured_landing_before_{at_fixation}_px"] = change["measured_landing_before_px"]
            figures[f"measured_landing_peak_after_{at_fixation}_px"] = change["measured_landing_peak_after_px"]
    return figures, landing


def spread(values: Sequence[float | None]) -> dict[str, float | int | None]:
    """n, median, quartiles and extremes of the finite values."""
    finite = np.array([v for v in values if v is not None and math.isfinite(v)], dtype=float)
    if not len(finite):
        return {"n": 0, "median": None, "q25": None, "q75": None, "min": None, "max": None}
    q25, median, q75 = np.percentile(finite, [25, 50, 75])
    return {"n": int(len(finite)), "median": float(median), "q25": float(q25), "q75": float(q75),
            "min": float(finite.min()), "max": float(finite.max())}


@dataclass
class SettingSummary:
    setting: str
    seeds: list[int] = field(default_factory=list)
    figures: dict[str, list[float | None]] = field(default_factory=dict)  # figure -> one value per seed
    curves: list[list[tuple[float, float]]] = field(default_factory=list)

    def spreads(self) -> dict[str, dict[str, float | int | None]]:
        return {name: spread(values) for name, values in self.figures.items()}


class SettingFigures(TypedDict):
    """One setting in summary.json: its seeds, each figure's spread and its value per seed."""
    seeds: list[int]
    figures: dict[str, dict[str, float | int | None]]
    per_seed: dict[str, list[float | None]]


class SweepSummaryDict(TypedDict):
    """summary.json: the sweep's experiment and its settings."""
    experiment: str
    settings: dict[str, SettingFigures]


@dataclass
class SweepSummary:
    experiment: str
    settings: dict[str, SettingSummary]

    def as_dict(self) -> SweepSummaryDict:
        return {"experiment": self.experiment,
                "settings": {k: {"seeds": s.seeds, "figures": s.spreads(), "per_seed": s.figures}
                             for k, s in self.settings.items()}}

    def table(self) -> str:
        lines = [f"{self.experiment}: median [interquartile range] across seeds"]
        for name, s in self.settings.items():
            lines.append(f"  {name} (seeds {', '.join(map(str, s.seeds))})")
            spreads = s.spreads()
            recoveries = [figure for prefix in RECOVERY_PREFIXES
                          for figure in sorted((f for f in spreads if f.startswith(prefix)),
                                               key=lambda f: int(f.rsplit("_", 1)[1]))]
            for figure in (*TABLE_FIGURES, *recoveries):
                sp = spreads.get(figure)
                if sp is None or sp["median"] is None:
                    continue
                lines.append(f"    {figure:<34} {sp['median']:10.4g} [{sp['q25']:.4g}, {sp['q75']:.4g}]  n={sp['n']}")
        return "\n".join(lines)


def summarise_sweep(runs: Sequence[RunSpec], out: Path) -> SweepSummary:
    """Read the finished runs' JSON; write summary.csv, summary.json and summary.png into `out`."""
    settings: dict[str, SettingSummary] = {}
    experiment = runs[0].experiment if runs else ""
    for run in runs:
        try:
            summary = json.loads(result_json(run_dir(out, run)).read_text())
        except (OSError, ValueError, StopIteration) as err:
            log.warning("sweep: run %s has no readable summary: %s", run.run_id, err)
            continue
        figures, curve = run_figures(summary)
        s = settings.setdefault(run.setting_id, SettingSummary(run.setting_id))
        s.seeds.append(run.seed)
        for name in set(s.figures) | set(figures):
            s.figures.setdefault(name, [None] * (len(s.seeds) - 1)).append(figures.get(name))
        s.curves.append(curve)
    result = SweepSummary(experiment, settings)
    (out / "summary.json").write_text(json.dumps(result.as_dict(), indent=2) + "\n")
    with open(out / "summary.csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["setting", "figure", "n", "median", "q25", "q75", "min", "max"])
        for name, s in settings.items():
            for figure, sp in sorted(s.spreads().items()):
                w.writerow([name, figure, sp["n"], *("" if sp[k] is None else f"{sp[k]:.6g}"
                                                     for k in ("median", "q25", "q75", "min", "max"))])
    plot_curves(result, out / "summary.png")
    return result


def median_band(curves: Sequence[Sequence[tuple[float, float]]]) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """x, median, 25th and 75th percentile of curves put on the first curve's x (interpolated)."""
    usable = [c for c in curves if len(c) >= 2]
    if not usable:
        empty = np.zeros(0)
        return empty, empty, empty, empty
    x = np.array([p[0] for p in usable[0]])
    ys = np.array([np.interp(x, [p[0] for p in c], [p[1] for p in c]) for c in usable])
    q25, median, q75 = np.percentile(ys, [25, 50, 75], axis=0)
    return x, median, q25, q75


def plot_curves(summary: SweepSummary, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(8, 4.5))
    for name, s in summary.settings.items():
        x, median, q25, q75 = median_band(s.curves)
        if not len(x):
            continue
        line, = ax.plot(x, median, "-", lw=1.2, label=f"{name} (n={len(s.curves)})")
        ax.fill_between(x, q25, q75, color=line.get_color(), alpha=0.2, lw=0)
    ax.set_yscale("log")
    ax.set_xlabel("fixations")
    ax.set_ylabel("median landing error [px]")
    ax.set_title(f"{summary.experiment}: median and interquartile range across seeds")
    ax.grid(alpha=0.3, which="both")
    if summary.settings:
        ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


__all__ = ["SettingFigures", "SweepSummary", "SweepSummaryDict", "fixations_to_share", "median_band", "run_figures",
           "spread", "summarise_sweep"]
