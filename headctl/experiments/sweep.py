"""`headctl experiment sweep NAME`: one experiment over a grid of seeds, profiles and settings, on Dask.

Runs from one seed differ from those of the next by more than many of the differences worth
measuring, so results are stated over several seeds with their spread. Each run of the grid
(one seed, one profile, one value of each `--set` key) is one `ExperimentRequest`
(`headctl.experiments.paper`) and one task: a worker runs it into a scratch directory, as
`headctl experiment NAME ...` with the same options would, and sends back the files it wrote
(CSV, JSON, PNG and its printed summary), which this process keeps under `<out>/runs/<run>/`
(`headctl.experiments.runs`); the workers need the project installed, not a shared folder.
Tasks go to a `dask.distributed` cluster: by default a local one on this machine
(`--workers` processes of one thread each), or an existing one (`--scheduler tcp://host:8786`).

A run's folder appears only once the run is complete (written beside it, then renamed), so
a sweep that is killed keeps every finished run, and run again it skips them. At the end
`<out>/summary.csv` and `summary.json` give, per setting, each figure's median,
interquartile range and extremes across the seeds (`headctl.experiments.summary`), and
`summary.png` the landing-error curves, median and interquartile band.
"""
from __future__ import annotations

import contextlib
import io
import itertools
import json
import logging
import os
import re
import shutil
import sys
import tempfile
import time
import uuid
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Iterator, Mapping, Sequence

from tqdm import tqdm

from headctl.errors import HeadctlError
from headctl.experiments.paper import ExperimentError, ExperimentRequest, run as run_experiment
from headctl.experiments.report import write_outputs
from headctl.experiments.runs import LOG_FILE, RUN_FILE, RUNS_DIR, RunSpec, result_json, run_dir

if TYPE_CHECKING:
    from distributed import Client

log = logging.getLogger(__name__)

# `headctl experiment` options a sweep may vary with --set (their argparse names).
SETTABLE = ("fixations", "exploration", "room", "config", "width", "height", "lens", "landing_every", "floor_samples")
# What a sweep decides for its runs itself.
RESERVED = ("seed", "profile", "out")


class SweepError(HeadctlError, ValueError):
    """A sweep that cannot be set up: a malformed grid, an option that cannot be swept."""


@dataclass(frozen=True)
class RunResult:
    """What one run gave back: its exit status (0, 1 failed, 2 refused), seconds, and the
    files it wrote (name -> content; `LOG_FILE`: what it printed)."""

    code: int
    seconds: float
    files: Mapping[str, bytes] = field(default_factory=dict)


# -- the grid -------------------------------------------------------------------------------
def parse_seeds(text: str) -> list[int]:
    """'0-4', '1,3,7' or '0-2,10' -> seeds, in order, each once."""
    seeds: list[int] = []
    for part in text.split(","):
        part = part.strip()
        match = re.fullmatch(r"(\d+)(?:-(\d+))?", part)
        if not match:
            raise SweepError(f"--seeds: got {text!r}, expected seeds such as '0-4' or '0,1,5' (integers >= 0)")
        low, high = int(match.group(1)), int(match.group(2) or match.group(1))
        if high < low:
            raise SweepError(f"--seeds: the range {part!r} runs backwards")
        seeds.extend(s for s in range(low, high + 1) if s not in seeds)
    return seeds


def parse_set(items: Sequence[str]) -> list[tuple[str, list[str]]]:
    """['exploration=random,teaching', 'fixations=300'] -> [(key, values)] (keys with '-' or '_')."""
    grid: list[tuple[str, list[str]]] = []
    for item in items:
        key, sep, values = item.partition("=")
        key = key.strip().lstrip("-").replace("-", "_")
        if not sep or not key or not values.strip():
            raise SweepError(f"--set {item!r}: expected key=value[,value...], such as exploration=random,teaching")
        if key in RESERVED:
            raise SweepError(f"--set {key}: the sweep sets it itself (use --seeds, --profiles, --out)")
        if key not in SETTABLE:
            raise SweepError(f"--set {key}: not an option a sweep can vary; expected one of {', '.join(SETTABLE)}")
        if any(k == key for k, _ in grid):
            raise SweepError(f"--set {key}: given twice")
        grid.append((key, [v.strip() for v in values.split(",") if v.strip()]))
    return grid


def parse_options(argv: Sequence[str]) -> tuple[dict[str, str], bool]:
    """`headctl experiment` options as text (['--fixations', '20', '--no-pose']) -> (option ->
    value, pose)."""
    options: dict[str, str] = {}
    pose = True
    items = list(argv)
    while items:
        item = items.pop(0)
        if item in ("--pose", "--no-pose"):
            pose = item == "--pose"
            continue
        flag, sep, value = item.partition("=")
        if not flag.startswith("--") or not (sep or items):
            raise SweepError(f"{' '.join(argv)}: expected --option value, got {item!r}")
        options[flag[2:].replace("-", "_")] = value if sep else items.pop(0)
    return options, pose


def build_runs(experiment: str, seeds: Sequence[int], profiles: Sequence[str],
               grid: Sequence[tuple[str, Sequence[str]]], base: Sequence[str] = ()) -> list[RunSpec]:
    """Every run of the grid, each read into its `ExperimentRequest` (SweepError if one does
    not read); `base`: the experiment options every run shares, as on the command line."""
    base_options, pose = parse_options(base)
    runs = []
    keys = [k for k, _ in grid]
    for profile in profiles:
        for values in itertools.product(*(v for _, v in grid)):
            settings = tuple(zip(keys, values))
            for seed in seeds:
                argv = ["experiment", experiment, "--profile", profile, "--seed", str(seed), *base]
                for key, value in settings:
                    argv += [f"--{key.replace('_', '-')}", value]
                try:
                    request = ExperimentRequest.from_options(experiment, profile, seed,
                                                             {**base_options, **dict(settings)}, pose)
                except ExperimentError as err:
                    raise SweepError(f"run {' '.join(argv)}: {err}") from None
                runs.append(RunSpec(experiment, profile, seed, settings, tuple(argv), request))
    return runs


# -- one run, on a worker -------------------------------------------------------------------
def run_task(run: RunSpec) -> RunResult:
    """Run the experiment of `run` into a scratch directory; returns its exit status, time and
    files (CSV, JSON, PNG and what it printed)."""
    import cv2

    cv2.setNumThreads(1)  # one worker, one core: OpenCV's own threads would crowd the others
    started = time.monotonic()
    printed = io.StringIO()

    def say(text: str) -> None:
        printed.write(text + "\n")

    with tempfile.TemporaryDirectory(prefix="headctl-sweep-") as scratch:
        try:
            say(write_outputs(run_experiment(run.request, say=say), Path(scratch)))
            code = 0
        except ExperimentError as err:
            say(str(err))
            code = 2
        except Exception as err:  # the run's failure is its result; the sweep goes on
            log.exception("sweep run %s failed", " ".join(run.argv))
            printed.write(f"\n{type(err).__name__}: {err}\n")
            code = 1
        files = {p.name: p.read_bytes() for p in Path(scratch).iterdir() if p.is_file()}
    files[LOG_FILE] = printed.getvalue().encode()
    return RunResult(code, time.monotonic() - started, files)


# -- keeping runs ---------------------------------------------------------------------------
def finished(out: Path, run: RunSpec) -> bool:
    """Whether `run` has a complete folder: the run's record and its summary JSON parse, and
    the record is of this run (the same command line: a sweep with other options redoes it)."""
    folder = run_dir(out, run)
    try:
        record = json.loads((folder / RUN_FILE).read_text())
        json.loads(result_json(folder).read_text())
    except (OSError, ValueError, StopIteration):
        return False
    return bool(record.get("code") == 0 and record.get("argv") == list(run.argv))


def keep(out: Path, run: RunSpec, result: RunResult) -> Path:
    """Write a run's files into its folder: beside it first, then renamed into place."""
    folder = run_dir(out, run)
    folder.parent.mkdir(parents=True, exist_ok=True)
    scratch = folder.parent / f".{folder.name}.{uuid.uuid4().hex[:8]}.tmp"
    scratch.mkdir()
    for name, data in result.files.items():
        (scratch / Path(name).name).write_bytes(data)
    record = {"experiment": run.experiment, "profile": run.profile, "seed": run.seed,
              "settings": dict(run.settings), "argv": list(run.argv), "code": result.code,
              "seconds": round(float(result.seconds), 2)}
    (scratch / RUN_FILE).write_text(json.dumps(record, indent=2) + "\n")
    if folder.exists():  # a failed run's folder, run again
        shutil.rmtree(folder)
    os.replace(scratch, folder)
    return folder


def clean_scratch(out: Path) -> None:
    """Remove what a killed sweep left half-written."""
    for stale in (out / RUNS_DIR).glob(".*.tmp"):
        shutil.rmtree(stale, ignore_errors=True)


# -- the cluster ----------------------------------------------------------------------------
@contextlib.contextmanager
def dask_client(scheduler: str | None, workers: int) -> Iterator[Client]:
    """A `distributed.Client`: of an existing cluster, or of a local one of `workers`
    single-threaded processes (closed on exit)."""
    from distributed import Client, LocalCluster

    # Dask tells of every worker and connection at INFO: its warnings are what matter here.
    logging.getLogger("distributed").setLevel(max(logging.WARNING, logging.getLogger().getEffectiveLevel()))
    if scheduler:
        with Client(scheduler) as client:
            yield client
        return
    with warnings.catch_warnings():
        # Its HTTP endpoint takes another port when 8787 is taken (another cluster): nothing to tell.
        warnings.filterwarnings("ignore", message="Port .* is already in use", category=UserWarning)
        cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=None,
                               silence_logs=logging.ERROR)
    with cluster, Client(cluster) as client:
        yield client


def pending(runs: Sequence[RunSpec], out: Path) -> tuple[list[RunSpec], list[RunSpec]]:
    """(runs finished before, runs to do), once what a killed sweep left half-written is removed."""
    (out / RUNS_DIR).mkdir(parents=True, exist_ok=True)
    clean_scratch(out)
    done = [r for r in runs if finished(out, r)]
    return done, [r for r in runs if r not in done]


def run_sweep(runs: Sequence[RunSpec], out: Path, scheduler: str | None = None, workers: int = 2,
              progress: bool = True) -> tuple[list[RunSpec], list[RunSpec]]:
    """Run what is not finished yet; returns (runs skipped as finished, runs that failed)."""
    from distributed import as_completed

    done, todo = pending(runs, out)
    failed: list[RunSpec] = []
    if not todo:
        return done, failed
    with dask_client(scheduler, workers) as client:
        futures = {client.submit(run_task, r, key=f"headctl-run-{r.run_id}-{uuid.uuid4().hex[:6]}",
                                 pure=False): r for r in todo}
        with tqdm(total=len(runs), initial=len(done), desc="sweep", unit="run", disable=not progress,
                  file=sys.stderr) as bar:
            for future in as_completed(futures):
                run = futures[future]
                try:
                    result = future.result()
                except Exception as err:  # the task itself failed (a worker died): keep going
                    log.error("run %s failed on its worker: %s", run.run_id, err)
                    result = RunResult(1, 0.0, {LOG_FILE: f"{type(err).__name__}: {err}\n".encode()})
                keep(out, run, result)
                if result.code != 0:
                    failed.append(run)
                    log.error("run %s failed (exit %s); its output is in %s", run.run_id, result.code,
                              run_dir(out, run) / LOG_FILE)
                bar.update(1)
                bar.set_postfix(failed=len(failed), refresh=False)
    return done, failed


__all__ = ["LOG_FILE", "RUNS_DIR", "RUN_FILE", "RunResult", "RunSpec", "SETTABLE", "SweepError", "build_runs",
           "finished", "parse_options", "parse_seeds", "parse_set", "pending", "result_json", "run_dir", "run_sweep",
           "run_task"]
