"""An experiment's report written and told: CSV, plot, summary JSON and the printed summary.

`write_outputs` writes `<out>/<name>-<profile>[-nopose].csv` (per fixation: raw and averaged
errors), `.png` (like the paper's figures) and `.json` (`summary_of`), and returns the text
`headctl experiment` prints: the paper's figures beside the measured ones, the landing error
and the representation's floor, and the files written.
"""
from __future__ import annotations

import csv
import json
import logging
from pathlib import Path
from typing import NotRequired, TypedDict, cast

import numpy as np

from calib_free.sim.experiments import MEASURED_WINDOW, ExperimentResult, MeasuredRecovery
from headctl.experiments.online import OnlineResult
from headctl.experiments.paper import ExperimentReport, ExperimentRequest
from headctl.experiments.paper_figures import reference_for

log = logging.getLogger(__name__)

# The re-adaptation windows each experiment is held to (the paper's figs. 6, 8, 9).
RECOVERY_GOAL = {"baseline": 500, "prism": 700, "pan-defect": 700, "swap": 700}
STEADY_OVER = 200  # fixations in the steadier "mean of the last 200" figure


class ChangeSummary(TypedDict):
    """One change of the experiment (prism, defect, swap) and how the run recovered from it.

    `at` and `recovery_fixations` count the curves' steps (online: adaptations); `at_fixation`
    and the measured landing's figures (online runs only, None otherwise) count fixations."""
    at: int
    recovery_fixations: int | None
    goal_fixations: int | None
    before: dict[str, float]
    landing_before_px: float | None
    landing_worst_after_px: float | None
    landing_700_after_px: float | None
    at_fixation: int
    measured_landing_recovery_fixations: int | None
    measured_landing_before_px: float | None
    measured_landing_bar_px: float | None
    measured_landing_peak_after_px: float | None


class OnlineFigures(TypedDict):
    """The online run's own figures: its fixations, their outcomes, fine vergence, landing checks."""
    fixations: int
    taught: int
    outcomes: dict[str, int]
    fixations_per_s: float | None
    median_confidence_taught: float | None
    vergence: dict[str, float]
    measured_landing: dict[str, float | int | None]
    measured_landing_per_fixation_px: list[float | None]  # None: refused, or no image target
    landing_at_fixations: list[int]
    landing_start_px: float | None
    exploration: str
    exploration_stats: dict[str, dict[str, int]]
    room: str
    config: str


class OnlineSummary(TypedDict):
    """What an online run adds to its `RunSummary`."""
    landing_joint_range_px: float | None
    online: OnlineFigures


class _OverFloor(TypedDict, total=False):
    landing_over_floor: float  # with a floor: the landing error over it


class RunFigures(TypedDict):
    """A run's figures (`summarise`), in the order its keys are written."""
    experiment: str
    profile: str
    fixations: int
    seconds: float
    final: dict[str, float]
    steady: dict[str, float]
    landing_error_px: float | None
    floor_px: float | None
    refused: int
    landing_over_floor: NotRequired[float]
    changes: list[ChangeSummary]
    landing_curve_px: list[tuple[int, float]]


class _OnlinePart(TypedDict, total=False):
    landing_joint_range_px: float | None
    online: OnlineFigures


class RunSummary(RunFigures):
    """A run's summary JSON (`summary_of`): its figures, an online run's own, and the pose flag."""
    landing_joint_range_px: NotRequired[float | None]
    online: NotRequired[OnlineFigures]
    pose: bool


def output_stem(request: ExperimentRequest, out: Path) -> Path:
    """Where a run's files go, without their suffix."""
    return out / f"{request.spec().name}-{request.profile}{'' if request.pose else '-nopose'}"


def online_summary(result: OnlineResult) -> OnlineSummary:
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
            "measured_landing": result.measured_landing(),
            "measured_landing_per_fixation_px": [None if px is None else round(px, 4)
                                                 for px in result.measured_landing_px()],
            "landing_at_fixations": result.landing_fixations,
            "landing_start_px": result.landing_start_px,
            "exploration": result.exploration,
            "exploration_stats": result.exploration_stats,
            "room": result.room,
            "config": result.config_path,
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


def change_summaries(result: ExperimentResult, online: OnlineResult | None = None) -> list[ChangeSummary]:
    """Per change of the run's experiment: when the retinal error recovered, the landing error
    around it, and (online) when the fixations' own measured landing was back."""
    spec = result.spec
    # Online, `result` counts adaptations; the run's own spec has the changes at their fixations.
    at_fixations = online.spec.changes if online is not None else spec.changes
    changes: list[ChangeSummary] = []
    for change, at_fixation in zip(spec.changes, at_fixations):
        before = [px for at, px in result.landing if at <= change.at]
        after = [px for at, px in result.landing if change.at < at <= change.at + 700]
        measured = (online.measured_landing_recovery(at_fixation) if online is not None
                    else MeasuredRecovery(None, None, None, None))
        changes.append({"at": change.at, "recovery_fixations": result.recovery_fixations(change.at),
                        "goal_fixations": RECOVERY_GOAL.get(spec.name), "before": result.final(change.at),
                        "landing_before_px": before[-1] if before else None,
                        "landing_worst_after_px": max(after) if after else None,
                        "landing_700_after_px": after[-1] if after else None,
                        "at_fixation": at_fixation.at,
                        "measured_landing_recovery_fixations": measured.fixations,
                        "measured_landing_before_px": measured.before_px,
                        "measured_landing_bar_px": measured.bar_px,
                        "measured_landing_peak_after_px": measured.peak_after_px})
    return changes


def summarise(result: ExperimentResult, floor_px: float | None, profile: str, learn_s: float,
              online: OnlineResult | None = None) -> RunFigures:
    spec = result.spec
    landing_px = result.landing[-1][1] if result.landing else None
    # A run without landing checks has no landing error to divide by the floor (a TypeError).
    over_floor: _OverFloor = {"landing_over_floor": cast(float, landing_px) / floor_px} if floor_px else {}
    return {"experiment": spec.name, "profile": profile, "fixations": spec.fixations,
            "seconds": round(learn_s, 2), "final": result.final(), "steady": result.final(over=STEADY_OVER),
            "landing_error_px": landing_px, "floor_px": floor_px, "refused": result.refused, **over_floor,
            "changes": change_summaries(result, online), "landing_curve_px": result.landing}


def summary_of(report: ExperimentReport) -> RunSummary:
    """The run's summary JSON: the figures, online the fixations' outcomes, and the pose flag."""
    figures = summarise(report.result, report.floor_px, report.request.profile, report.seconds, report.online)
    online: _OnlinePart = {}
    if report.online is not None:
        extra = online_summary(report.online)
        online = {"landing_joint_range_px": extra["landing_joint_range_px"], "online": extra["online"]}
    return {**figures, **online, "pose": report.request.pose}


def format_summary(s: RunSummary) -> str:
    f, st = s["final"], s["steady"]
    counted = "adaptations (taught fixations)" if "online" in s else "fixations"
    paper = reference_for("online" in s)
    lines = [f"{s['experiment']} ({s['profile']} profile), {s['fixations']} {counted} in {s['seconds']:.1f} s",
             f"                   last 10 (paper)  last 200    paper {paper.figure} ({paper.fixations:,} fixations)",
             f"  pan error        {f['pan_deg']:7.2f} deg   {st['pan_deg']:7.2f} deg   {paper.pan_deg:.2f} deg",
             f"  tilt error       {f['tilt_deg']:7.2f} deg   {st['tilt_deg']:7.2f} deg   {paper.tilt_deg:.2f} deg",
             f"  vergence error   {f['vergence_deg']:7.2f} deg   {st['vergence_deg']:7.2f} deg   "
             f"{paper.vergence_deg:.2f} deg",
             f"  retinal error    {100 * f['retinal_error']:7.2f} %     {100 * st['retinal_error']:7.2f} %     "
             f"{100 * paper.retinal_error:.2f} %"]
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
        if c["measured_landing_before_px"] is not None:
            back = c["measured_landing_recovery_fixations"]
            back_text = "not within the run" if back is None else f"{back} fixations"
            peak = c["measured_landing_peak_after_px"]
            lines.append(f"    measured landing (median of {MEASURED_WINDOW}) back to its level before "
                         f"({c['measured_landing_before_px']:.2f} px: back at <= {c['measured_landing_bar_px']:.2f} px) "
                         f"after {back_text} from fixation {c['at_fixation']}"
                         + ("" if peak is None else f", at worst {peak:.2f} px")
                         + (f" (goal <= {goal})" if goal else ""))
        if c["landing_worst_after_px"] is not None:
            lines.append(f"    landing error {c['landing_before_px']:.1f} px before, {c['landing_worst_after_px']:.1f} px "
                         f"at worst after, {c['landing_700_after_px']:.1f} px 700 fixations after")
    if s["refused"]:
        lines.append(f"  refused samples: {s['refused']}")
    if "online" in s:
        o = s["online"]
        lines.append(f"  in the simulated world of {o['config']} ({o['room']} room)")
        lines.append(f"  fixations {o['fixations']}, taught {o['taught']} ({o['fixations_per_s']:.1f} fixations/s); "
                     "the curves above are per taught fixation")
        for outcome, count in sorted(o["outcomes"].items(), key=lambda kv: -kv[1]):
            lines.append(f"    {outcome:<34} {count:6d}")
        ml = o["measured_landing"]
        if ml["median_px"] is not None:
            lines.append(f"  landing as the fixations measured it: median {ml['median_px']:.2f} px, p90 "
                         f"{ml['p90_px']:.2f} px (the last {ml['fixations']} taught fixations with an aim)")
        v = o["vergence"]
        lines.append(f"  fine vergence: {v['converged']} of {v['matched']} converged "
                     f"({100 * v['converged_fraction']:.1f} %), median {v['median_steps']:.0f} steps; "
                     f"median confidence of taught fixations {o['median_confidence_taught']:.2f}")
    return "\n".join(lines)


def write_outputs(report: ExperimentReport, out: Path) -> str:
    """Write the report's CSV, PNG and JSON into `out` (made if missing); returns the text to
    print: the summary and the files written."""
    from headctl.experiments.plots import plot_learning_curves  # matplotlib only when plotting

    out.mkdir(parents=True, exist_ok=True)
    stem = output_stem(report.request, out)
    spec = report.spec
    write_csv(report.result, stem.with_suffix(".csv"))
    plot_learning_curves(report.result, stem.with_suffix(".png"), report.floor_px,
                         title=f"{spec.name} ({report.request.profile} profile): {spec.description}",
                         online=report.online is not None)
    summary = summary_of(report)
    stem.with_suffix(".json").write_text(json.dumps(summary, indent=2) + "\n")
    return f"{format_summary(summary)}\nwrote {stem}.csv, {stem}.png, {stem}.json"


__all__ = ["RECOVERY_GOAL", "STEADY_OVER", "ChangeSummary", "OnlineFigures", "OnlineSummary",
           "RunFigures", "RunSummary", "change_summaries", "format_summary", "online_summary", "output_stem",
           "summarise", "summary_of", "write_csv", "write_outputs"]
