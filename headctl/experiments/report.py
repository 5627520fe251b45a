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
from typing import Any

import numpy as np

from calib_free.sim.experiments import ExperimentResult
from headctl.experiments.online import OnlineResult
from headctl.experiments.paper import ExperimentReport, ExperimentRequest

log = logging.getLogger(__name__)

# The paper's figures for each experiment: what `learn` is compared with (fig. 5), and the
# re-adaptation windows the issue sets (figs. 6, 8, 9).
PAPER_LEARN = {"pan_deg": 1.3, "tilt_deg": 1.07, "vergence_deg": 0.5, "retinal_error": 0.0368}
RECOVERY_GOAL = {"baseline": 500, "prism": 700, "pan-defect": 700, "swap": 700}
STEADY_OVER = 200  # fixations in the steadier "mean of the last 200" figure


def output_stem(request: ExperimentRequest, out: Path) -> Path:
    """Where a run's files go, without their suffix."""
    return out / f"{request.spec().name}-{request.profile}{'' if request.pose else '-nopose'}"


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


def summary_of(report: ExperimentReport) -> dict:
    """The run's summary JSON: the figures, online the fixations' outcomes, and the pose flag."""
    summary = summarise(report.result, report.floor_px, report.request.profile, report.seconds)
    if report.online is not None:
        extra = online_summary(report.online)
        extra["online"]["room"] = report.request.room or "generated"
        summary.update(extra)
    summary["pose"] = report.request.pose
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


__all__ = ["PAPER_LEARN", "RECOVERY_GOAL", "STEADY_OVER", "format_summary", "online_summary", "output_stem",
           "summarise", "summary_of", "write_csv", "write_outputs"]
