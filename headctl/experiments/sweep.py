"""`headctl experiment sweep NAME`: one experiment over a grid of seeds, profiles and settings, on Dask.

Runs from one seed differ from those of the next by more than many of the differences worth
measuring, so results are stated over several seeds with their spread. Each run of the grid
(one seed, one profile, one value of each `--set` key) is one task: a worker runs
`headctl experiment NAME ...` in a scratch directory and sends back the files it wrote (CSV,
JSON, PNG and its printed summary), which this process keeps under `<out>/runs/<run>/`; the
workers need the project installed, not a shared folder. Tasks go to a `dask.distributed`
cluster: by default a local one on this machine (`--workers` processes of one thread each),
or an existing one (`--scheduler tcp://host:8786`).

A run's folder appears only once the run is complete (written beside it, then renamed), so
a sweep that is killed keeps every finished run, and run again it skips them. At the end
`<out>/summary.csv` and `summary.json` give, per setting, each figure's median,
interquartile range and extremes across the seeds (`headctl.experiments.summary`), and
`summary.png` the landing-error curves, median and interquartile band.
"""
from __future__ import annotations

import argparse
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
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterator, Mapping, Sequence

from tqdm import tqdm

from headctl.errors import HeadctlError

log = logging.getLogger(__name__)

RUNS_DIR = "runs"
RUN_FILE = "run.json"  # what the run was: its argv and settings, written with its results
LOG_FILE = "output.txt"  # what the run printed
# `headctl experiment` options a sweep may vary with --set (their argparse names).
SETTABLE = ("fixations", "exploration", "room", "width", "height", "lens", "landing_every", "floor_samples")
# What a sweep decides for its runs itself.
RESERVED = ("seed", "profile", "out")


class SweepError(HeadctlError, ValueError):
    """A sweep that cannot be set up: a malformed grid, an option that cannot be swept."""


@dataclass(frozen=True)
class RunSpec:
    """One run of a sweep: the experiment's command line and the settings it stands for."""

    experiment: str
    profile: str
    seed: int
    settings: tuple[tuple[str, str], ...]  # (--set key, value), in the order given
    argv: tuple[str, ...]  # the `headctl experiment` arguments

    @property
    def run_id(self) -> str:
        parts = [self.experiment, self.profile, *(f"{k}={v}" for k, v in self.settings), f"seed{self.seed}"]
        return re.sub(r"[^A-Za-z0-9_.=+-]", "_", "-".join(parts))

    @property
    def setting_id(self) -> str:
        """The run's setting without its seed: runs with the same one are aggregated."""
        return ", ".join([f"profile={self.profile}", *(f"{k}={v}" for k, v in self.settings)])


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


def build_runs(experiment: str, seeds: Sequence[int], profiles: Sequence[str],
               grid: Sequence[tuple[str, Sequence[str]]], base: Sequence[str] = ()) -> list[RunSpec]:
    """Every run of the grid, each checked by the experiment command's own parser."""
    from headctl.cli.main import build_parser  # the cli imports this module through cmd_experiment

    parser = build_parser()
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
                    with contextlib.redirect_stderr(io.StringIO()) as err:
                        parser.parse_args(argv)
                except SystemExit:
                    raise SweepError(f"run {' '.join(argv)}: {err.getvalue().strip().splitlines()[-1]}") from None
                runs.append(RunSpec(experiment, profile, seed, settings, tuple(argv)))
    return runs


# -- one run, on a worker -------------------------------------------------------------------
def run_task(argv: Sequence[str]) -> dict[str, Any]:
    """Run `headctl <argv>` (an experiment, its `--out` added here) in a scratch directory;
    returns {"code": exit code, "seconds": ..., "files": {name: bytes}}."""
    import cv2

    from headctl.cli.main import main

    cv2.setNumThreads(1)  # one worker, one core: OpenCV's own threads would crowd the others
    started = time.monotonic()
    with tempfile.TemporaryDirectory(prefix="headctl-sweep-") as scratch:
        printed = io.StringIO()
        with contextlib.redirect_stdout(printed), contextlib.redirect_stderr(printed):
            try:
                code = main(["--log-level", "WARNING", *argv, "--out", scratch])
            except Exception as err:  # the run's failure is its result; the sweep goes on
                log.exception("sweep run %s failed", " ".join(argv))
                printed.write(f"\n{type(err).__name__}: {err}\n")
                code = 1
        files = {p.name: p.read_bytes() for p in Path(scratch).iterdir() if p.is_file()}
    files[LOG_FILE] = printed.getvalue().encode()
    return {"code": code, "seconds": time.monotonic() - started, "files": files}


# -- keeping runs ---------------------------------------------------------------------------
def run_dir(out: Path, run: RunSpec) -> Path:
    return out / RUNS_DIR / run.run_id


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


def result_json(folder: Path) -> Path:
    """The experiment's own summary JSON in a run's folder."""
    return next(p for p in sorted(folder.glob("*.json")) if p.name != RUN_FILE)


def keep(out: Path, run: RunSpec, result: Mapping[str, Any]) -> Path:
    """Write a run's files into its folder: beside it first, then renamed into place."""
    folder = run_dir(out, run)
    folder.parent.mkdir(parents=True, exist_ok=True)
    scratch = folder.parent / f".{folder.name}.{uuid.uuid4().hex[:8]}.tmp"
    scratch.mkdir()
    for name, data in result["files"].items():
        (scratch / Path(name).name).write_bytes(data)
    record = {"experiment": run.experiment, "profile": run.profile, "seed": run.seed,
              "settings": dict(run.settings), "argv": list(run.argv), "code": result["code"],
              "seconds": round(float(result["seconds"]), 2)}
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
def dask_client(scheduler: str | None, workers: int) -> Iterator[Any]:
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
        futures = {client.submit(run_task, list(r.argv), key=f"headctl-run-{r.run_id}-{uuid.uuid4().hex[:6]}",
                                 pure=False): r for r in todo}
        with tqdm(total=len(runs), initial=len(done), desc="sweep", unit="run", disable=not progress,
                  file=sys.stderr) as bar:
            for future in as_completed(futures):
                run = futures[future]
                try:
                    result = future.result()
                except Exception as err:  # the task itself failed (a worker died): keep going
                    log.error("run %s failed on its worker: %s", run.run_id, err)
                    result = {"code": 1, "seconds": 0.0,
                              "files": {LOG_FILE: f"{type(err).__name__}: {err}\n".encode()}}
                keep(out, run, result)
                if result["code"] != 0:
                    failed.append(run)
                    log.error("run %s failed (exit %s); its output is in %s", run.run_id, result["code"],
                              run_dir(out, run) / LOG_FILE)
                bar.update(1)
                bar.set_postfix(failed=len(failed), refresh=False)
    return done, failed


# -- the command ----------------------------------------------------------------------------
def add_arguments(p: argparse.ArgumentParser) -> None:
    """The sweep's options on `headctl experiment`'s parser."""
    group = p.add_argument_group("sweep (headctl experiment sweep NAME ...)")
    group.add_argument("swept", nargs="?", metavar="NAME", help="with sweep: the experiment to run over the grid")
    group.add_argument("--seeds", default="0-4", help="seeds, such as 0-4 or 0,1,5 (default 0-4)")
    group.add_argument("--profiles", default="default", help="gaze map profiles, comma-separated (default: default)")
    group.add_argument("--set", action="append", default=[], metavar="KEY=V1,V2",
                       help=f"one more axis of the grid; KEY one of {', '.join(SETTABLE)} (repeatable)")
    group.add_argument("--scheduler", default=None, metavar="tcp://HOST:8786",
                       help="an existing Dask scheduler (the project installed on its workers); "
                            "default: a local cluster")
    group.add_argument("--workers", type=int, default=2,
                       help="processes of the local cluster, one thread each (default 2)")


def run(args: argparse.Namespace, base: Sequence[str]) -> int:
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


__all__ = ["RunSpec", "SweepError", "add_arguments", "build_runs", "parse_seeds", "parse_set", "pending", "run",
           "run_sweep", "run_task"]
