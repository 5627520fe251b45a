"""Learning-curve plots like the paper's figures 5, 6, 8 and 9 (matplotlib, no display needed)."""
from __future__ import annotations

import logging
from pathlib import Path

import matplotlib

matplotlib.use("Agg")  # a daemon or CI machine has no display
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from calib_free.sim.experiments import ExperimentResult  # noqa: E402
from headctl.experiments.paper_figures import reference_for  # noqa: E402

log = logging.getLogger(__name__)



def plot_learning_curves(result: ExperimentResult, path: Path, floor_px: float | None = None,
                         title: str | None = None, online: bool = False) -> Path:
    """Pan, tilt, vergence and retinal error (averaged over the last 10) and landing error.

    `online`: the curves are per taught fixation and the references are figure 7's."""
    paper = reference_for(online)  # drawn as dashed references
    reference, reference_label = paper.plot_values(), paper.label
    n = np.arange(1, len(result.retinal_error) + 1)
    out = result.averaged(result.output_error)
    retinal = result.averaged(result.retinal_error) * 100.0
    fig, axes = plt.subplots(5, 1, figsize=(8, 11), sharex=True)
    panels = [(out[:, 0], "pan error [deg]", "pan"), (out[:, 1], "tilt error [deg]", "tilt"),
              (out[:, 2], "vergence error [deg]", "vergence"), (retinal, "retinal error [%]", "retinal")]
    for ax, (values, label, key) in zip(axes, panels):
        ax.plot(n, values, lw=0.7, color="tab:blue")
        ax.axhline(reference[key], ls="--", lw=0.8, color="tab:red", label=reference_label)
        ax.set_ylabel(label)
        ax.set_ylim(0, max(3 * reference[key], np.percentile(values, 99) * 1.1))
        ax.grid(alpha=0.3)
    axes[0].legend(loc="upper right", fontsize=8)
    ax = axes[4]
    if result.landing:
        at, px = zip(*result.landing)
        ax.plot(at, px, "o-", ms=3, color="tab:green", label="median landing error")
    if floor_px is not None:
        ax.axhline(floor_px, ls=":", color="black", label=f"representation floor {floor_px:.1f} px")
        ax.axhline(1.5 * floor_px, ls="--", lw=0.8, color="gray", label="1.5 x floor")
    ax.set_ylabel("landing error [px]")
    ax.set_xlabel("adaptations (taught fixations)" if online else "fixations")
    ax.set_ylim(bottom=0)
    ax.grid(alpha=0.3)
    ax.legend(loc="upper right", fontsize=8)
    for change in result.spec.changes:
        for a in axes:
            a.axvline(change.at, color="gray", lw=0.8, ls="-.")
    fig.suptitle(title or f"{result.spec.name}: {result.spec.description}")
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    log.info("plot written to %s", path)
    return path
