"""A sweep's runs and where each is kept: what the sweep (`headctl.experiments.sweep`) writes and
its summary (`headctl.experiments.summary`) reads.

Each run is kept under `<out>/runs/<run id>/`: the experiment's own files (CSV, JSON, PNG),
what it printed (`output.txt`) and its record (`run.json`: the run's command line, settings,
exit status and time).
"""
from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from headctl.experiments.paper import ExperimentRequest

RUNS_DIR = "runs"
RUN_FILE = "run.json"  # what the run was: its argv and settings, written with its results
LOG_FILE = "output.txt"  # what the run printed


@dataclass(frozen=True)
class RunSpec:
    """One run of a sweep: the experiment's request, and the command line and settings it
    stands for (what its record keeps and a resumed sweep compares)."""

    experiment: str
    profile: str
    seed: int
    settings: tuple[tuple[str, str], ...]  # (--set key, value), in the order given
    argv: tuple[str, ...]  # the `headctl experiment` arguments of the same run
    request: ExperimentRequest

    @property
    def run_id(self) -> str:
        parts = [self.experiment, self.profile, *(f"{k}={v}" for k, v in self.settings), f"seed{self.seed}"]
        return re.sub(r"[^A-Za-z0-9_.=+-]", "_", "-".join(parts))

    @property
    def setting_id(self) -> str:
        """The run's setting without its seed: runs with the same one are aggregated."""
        return ", ".join([f"profile={self.profile}", *(f"{k}={v}" for k, v in self.settings)])


def run_dir(out: Path, run: RunSpec) -> Path:
    return out / RUNS_DIR / run.run_id


def result_json(folder: Path) -> Path:
    """The experiment's own summary JSON in a run's folder."""
    return next(p for p in sorted(folder.glob("*.json")) if p.name != RUN_FILE)


__all__ = ["LOG_FILE", "RUNS_DIR", "RUN_FILE", "RunSpec", "result_json", "run_dir"]
