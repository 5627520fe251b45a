"""A soak: the daemon on the simulated head for a long run, faults injected at random, and what
it holds per interval: resident memory, threads, open files, CPU, the map file, the log.

`headctl run --config configs/sim.yaml` runs in a child process (a temporary state directory,
the API on 127.0.0.1, its log beside the state directory), in real time: the manual clock
cannot drive a daemon in another process. Through the run, after random gaps (exponential,
mean `--fault-every` seconds), one fault of the table `FAULTS` (soak_faults.py) is injected:
each is an injection, the soak's own part in ending it (a restored bus, a camera resumed; none
where the service must heal alone, as after a `kill -9` of its servo process), how the status
shows it and how to tell it healed. A fault the service being measured does not offer (not
among the simulated faults its API schema lists, or refused with 404/422) is marked
unsupported and not injected again. Healed means: the service `running` with no fault listed,
and the fault's own check (a new servo process, no open hardware-error episode), within
`--heal-timeout-s`; one that did not heal leaves the service restarted by the soak, as a
person would, and the run goes on (each restart starts a new generation of samples).

Every `--report-every` seconds (the "hour" of a short run) a row: the service's and its
servo process's resident memory, threads and open files (/proc), the service's CPU share, the
map file's size and adaptation count (the file read as the daemon would read it), the log's
bytes. The verdict, exit 1 when it fails:
- flat: per generation, over the rows after the first (start-up: compilation, caches), the
  least-squares growth over the span (slope times span) of each figure within its tolerance
  (`TOLERANCES`); fewer than 3 rows judge nothing;
- every injected fault reported (in the status's faults, events or hardware errors while it
  lasted) and healed, with the time to heal (from the soak's heal action, or from the
  injection for a fault the service heals alone): p50 and max per fault;
- no map lost: the map file always loads, its adaptation count never goes backwards, every
  restart restores at least what the file last held, and the file at the end holds at least
  what the status last showed.

    .venv/bin/python -m benchmarks.hostile.soak [--seconds 180] [--report-every 30]
        [--fault-every 8] [--faults bus_down,servo_kill,...] [--seed 1] [--json out.json] [--csv out.csv]
"""
from __future__ import annotations

import argparse
import csv
import json
import os
import signal
import random
import statistics
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import asdict
from pathlib import Path
from typing import Any

from benchmarks.hostile.soak_faults import FAULTS, Episode, Unsupported
from benchmarks.support.daemon_process import ROOT, BenchDaemon
from benchmarks.support.procfs import alive, child_running, sample, trend
from calib_free.errors import CalibFreeError
from calib_free.map.file import read_map
from headctl.api.client import ApiClient, ApiError

CONFIG = ROOT / "configs" / "sim.yaml"
SERVO_MARKER = "multiprocessing.spawn"  # the servo process's command line (the resource tracker is the other child)
MAX_SECONDS = 48 * 3600.0
START_TIMEOUT_S = 120.0
POLL_S = 0.1
MAX_EPISODES = 100_000
TOLERANCES: dict[str, Callable[[float], float]] = {  # allowed growth over the span judged, from the median
    "rss_kb": lambda median: max(16 * 1024, 0.10 * median),
    "threads": lambda median: 2,
    "open_files": lambda median: 4,
    "servo_rss_kb": lambda median: max(8 * 1024, 0.10 * median),
    "servo_threads": lambda median: 1,
    "servo_open_files": lambda median: 2,
    "map_bytes": lambda median: 0.05 * median,
    "log_bytes_per_interval": lambda median: max(256 * 1024, median),
}


class SoakError(Exception):
    """The soak could not run (the daemon would not start, its API would not answer)."""


class Daemon(BenchDaemon):
    def __init__(self, state_dir: Path) -> None:
        super().__init__(CONFIG, state_dir, SoakError)
        self.client: ApiClient | None = None

    def start(self, timeout_s: float = START_TIMEOUT_S) -> dict[str, Any]:
        deadline = time.monotonic() + timeout_s
        self.client = ApiClient(self.wait_url(deadline), timeout_s=10.0)
        while time.monotonic() < deadline:
            self.check_alive()
            status = self.status()
            if status is not None and status["state"] in ("running", "degraded"):
                return status
            time.sleep(0.2)
        raise SoakError(f"the daemon is not running after {timeout_s:.0f} s; its log ends:\n{self.tail()}")

    def status(self) -> dict[str, Any] | None:
        try:
            assert self.client is not None
            return self.client.state()
        except (ApiError, ValueError):
            return None

    def servo_pid(self) -> int | None:
        """The live servo process: the one the status names (it forks from the service's fork
        server, so it is no child of the service), else a child by its command line."""
        loop = (self.status() or {}).get("servo_loop") or {}
        pid = loop.get("pid") if isinstance(loop, dict) else None
        if isinstance(pid, int) and alive(pid):
            return pid
        return child_running(self.proc.pid, SERVO_MARKER)


# --- the run ------------------------------------------------------------------------------------
class Soak:
    def __init__(self, args: argparse.Namespace, folder: Path) -> None:
        self.args = args
        self.rng = random.Random(args.seed)
        self.state_dir = folder / "state"
        self.state_dir.mkdir()
        self.began_s = time.monotonic()  # again once the first daemon runs: its start-up is no part of the run
        self.generation = 0
        self.rows: list[dict[str, Any]] = []
        self.episodes: list[Episode] = []
        self.map_problems: list[str] = []
        self.unsupported: dict[str, str] = {}
        self.offered: set[str] = set()
        self.image_size = (320, 240)
        self.burst = int(args.burst)
        self.file_adaptations = 0  # what the map file last held
        self.status_adaptations = 0  # what the status last showed
        self.last_row: dict[str, Any] | None = None
        self.final_map_adaptations: int | None = None  # the file after the final SIGTERM
        self.next_row_s = args.report_every
        self.daemon = self.start_daemon()
        self.began_s = time.monotonic()

    @property
    def client(self) -> ApiClient:
        assert self.daemon.client is not None
        return self.daemon.client

    def servo_pid(self) -> int | None:
        return self.daemon.servo_pid()

    def status(self) -> dict[str, Any] | None:
        return self.daemon.status()

    def now_s(self) -> float:
        return time.monotonic() - self.began_s

    def start_daemon(self) -> Daemon:
        daemon = Daemon(self.state_dir)
        status = daemon.start()
        restored = int(status["map"]["restored"]["adaptations"])
        if restored < self.file_adaptations:
            self.map_problems.append(f"generation {self.generation}: restored {restored} adaptations, the map file "
                                     f"last held {self.file_adaptations}")
        self.map_problems += [f"generation {self.generation}: {p}" for p in status["map"]["problems"]]
        self.image_size = tuple(status.get("image_size") or self.image_size)  # type: ignore[assignment]
        schema = daemon.client.request("GET", "/openapi.json") if daemon.client else {}
        self.offered = set(schema.get("components", {}).get("schemas", {}).get("SimFault", {}).get("enum", []))
        return daemon

    def restart_daemon(self) -> None:
        """What a person would do with a service that did not heal: stop it, start it again."""
        code = self.daemon.stop()
        print(f"  ({self.now_s():7.1f} s) the soak restarts the daemon (it exited with {code})", flush=True)
        self.log_offset += self.daemon.log_path.stat().st_size
        self.generation += 1
        self.last_row = None
        self.daemon = self.start_daemon()

    log_offset = 0  # the logs of earlier generations (each generation's daemon starts its log again)

    def log_bytes(self) -> int:
        try:
            return self.log_offset + self.daemon.log_path.stat().st_size
        except FileNotFoundError:
            return self.log_offset

    # -- sampling ------------------------------------------------------------------------------
    def read_map_file(self) -> int | None:
        path = self.state_dir / "gaze_map.npz"
        if not path.exists():
            return None
        try:
            adaptations = int(read_map(path).adaptations)
        except (CalibFreeError, OSError) as err:
            self.map_problems.append(f"{self.now_s():.1f} s: {err}")
            return None
        if adaptations < self.file_adaptations:
            self.map_problems.append(f"{self.now_s():.1f} s: the map file went back from {self.file_adaptations} "
                                     f"to {adaptations} adaptations")
        self.file_adaptations = max(self.file_adaptations, adaptations)
        return adaptations

    def tick(self) -> dict[str, Any] | None:
        """Poll the status (for the map's progress); a row once its interval has come."""
        status = self.daemon.status()
        if status is not None:
            adaptations = int(status.get("learning", {}).get("adaptations", self.status_adaptations) or 0)
            self.status_adaptations = max(self.status_adaptations, adaptations)
        if self.now_s() >= self.next_row_s:
            self.next_row_s += self.args.report_every
            self.take_row(status)
        return status

    def take_row(self, status: dict[str, Any] | None) -> None:
        now = self.now_s()
        service, servo_pid = sample(self.daemon.proc.pid), self.daemon.servo_pid()
        servo = sample(servo_pid) if servo_pid is not None else None
        map_path = self.state_dir / "gaze_map.npz"
        log_bytes = self.log_bytes()
        row: dict[str, Any] = {
            "t_s": round(now, 1), "generation": self.generation, "state": (status or {}).get("state", "?"),
            "rss_kb": service.rss_kb, "threads": service.threads, "open_files": service.open_files,
            "cpu_percent": None, "servo_pid": servo_pid, "servo_rss_kb": servo.rss_kb if servo else None,
            "servo_threads": servo.threads if servo else None, "servo_open_files": servo.open_files if servo else None,
            "map_bytes": map_path.stat().st_size if map_path.exists() else None,
            "map_adaptations": self.read_map_file(), "adaptations": self.status_adaptations,
            "log_bytes": log_bytes, "log_bytes_per_interval": None, "faults_injected": len(self.episodes),
            "_cpu_s": service.cpu_s}
        last = self.last_row
        if last is not None and service.cpu_s is not None and last["_cpu_s"] is not None:
            row["cpu_percent"] = round(100.0 * (service.cpu_s - last["_cpu_s"]) / max(now - last["t_s"], 1e-3), 1)
        if self.rows:
            row["log_bytes_per_interval"] = log_bytes - self.rows[-1]["log_bytes"]
        self.rows.append(row)
        self.last_row = row
        print_row(row, header=len(self.rows) == 1)

    def wait(self, seconds: float, until: Callable[[dict[str, Any]], bool] | None = None) -> dict[str, Any] | None:
        """Poll for `seconds` (sampling as it goes), or until `until(status)`: the status it ended on."""
        deadline = time.monotonic() + max(0.0, seconds)
        status = None
        while True:
            status = self.tick()
            if until is not None and status is not None and until(status):
                return status
            if time.monotonic() >= deadline:
                return None if until is not None else status
            self.daemon.check_alive()
            time.sleep(min(POLL_S, max(0.0, deadline - time.monotonic())))

    # -- one episode ---------------------------------------------------------------------------
    def episode(self, name: str) -> Episode:
        fault = FAULTS[name]
        episode = Episode(name, self.generation, round(self.now_s(), 3), time.time())
        log_before = self.log_bytes()
        self.episodes.append(episode)
        try:
            fault.inject(self, episode)
        except Unsupported as err:
            episode.unsupported = self.unsupported[name] = str(err)
            print(f"  ({episode.injected_s:7.1f} s) {name}: unsupported by this service: {err}", flush=True)
            return episode

        def seen(status: dict[str, Any]) -> bool:
            if episode.reported_s is None and fault.seen(self, status, episode):
                episode.reported_s = round(self.now_s(), 3)
            return False

        self.wait(fault.hold_s, seen)
        if fault.heal is not None:
            fault.heal(self, episode)
        episode.heal_from_s = round(self.now_s(), 3) if fault.heal is not None else episode.injected_s

        def healed(status: dict[str, Any]) -> bool:
            seen(status)
            return status["state"] == "running" and not status["faults"] and fault.check(self, status, episode)

        if self.wait(self.args.heal_timeout_s, healed) is not None:
            episode.healed_s = round(self.now_s(), 3)
        episode.log_bytes = self.log_bytes() - log_before
        reported = "reported" if episode.reported_s is not None else "NOT reported"
        outcome = (f"healed in {episode.time_to_heal_s:.2f} s" if episode.healed_s is not None
                   else f"NOT healed within {self.args.heal_timeout_s:g} s")
        target = f" {episode.target}" if episode.target else ""
        print(f"  ({episode.injected_s:7.1f} s) {name}{target}: {reported if fault.must_report else 'load'}, "
              f"{outcome}{'; ' + episode.failures[0] if episode.failures else ''}", flush=True)
        if episode.healed_s is None:
            self.restart_daemon()
        return episode

    def run(self) -> None:
        names = [n for n in self.args.faults]
        end_s = self.args.seconds
        while self.now_s() < end_s and len(self.episodes) < MAX_EPISODES:
            gap = min(self.rng.expovariate(1.0 / self.args.fault_every), max(0.0, end_s - self.now_s()))
            self.wait(gap)
            choices = [n for n in names if n not in self.unsupported]
            if self.now_s() >= end_s or not choices:
                continue
            self.episode(self.rng.choices(choices, [FAULTS[n].weight for n in choices])[0])
        if not self.rows or self.now_s() - self.rows[-1]["t_s"] > 1.0:
            self.take_row(self.daemon.status())
        code = self.daemon.stop()
        if code != 0:
            self.map_problems.append(f"the daemon exited with {code} on SIGTERM")
        final = self.final_map_adaptations = self.read_map_file()
        if (final or 0) < self.status_adaptations:  # no file at all: fine only for a map never adapted
            self.map_problems.append(f"the map file at the end holds {final} adaptations, the status last showed "
                                     f"{self.status_adaptations}")


# --- the report -----------------------------------------------------------------------------------
COLUMNS = [("t_s", 8), ("generation", 3), ("state", 9), ("rss_kb", 8), ("threads", 4), ("open_files", 5),
           ("cpu_percent", 6), ("servo_rss_kb", 8), ("servo_threads", 4), ("servo_open_files", 5),
           ("map_bytes", 9), ("map_adaptations", 6), ("log_bytes", 10), ("log_bytes_per_interval", 10),
           ("faults_injected", 5)]
HEADINGS = ["t s", "gen", "state", "RSS kB", "thr", "fds", "CPU %", "servo kB", "thr", "fds", "map B", "adapt",
            "log B", "log B/int", "flt"]


def print_row(row: dict[str, Any], header: bool) -> None:
    if header:
        print(" ".join(f"{h:>{w}}" for h, (_, w) in zip(HEADINGS, COLUMNS)))
    print(" ".join(f"{'-' if row[k] is None else row[k]!s:>{w}}" for k, w in COLUMNS), flush=True)


def judge_trends(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """Per generation, each figure's growth over the rows after the first, against its tolerance."""
    judged: dict[str, Any] = {}
    for generation in sorted({r["generation"] for r in rows}):
        mine = [r for r in rows if r["generation"] == generation][1:]
        for key, tolerance in TOLERANCES.items():
            points = [(r["t_s"], float(r[key])) for r in mine if r[key] is not None]
            values = [v for _, v in points]
            median = statistics.median(values) if values else 0.0
            line = trend([t for t, _ in points], values, tolerance(median))
            judged[f"{generation}:{key}"] = {"generation": generation, "figure": key, "points": line.points,
                                             "growth": round(line.growth, 1), "tolerance": round(line.tolerance, 1),
                                             "slope_per_hour": round(line.slope_per_s * 3600, 1),
                                             "growing": line.growing}
    return judged


def verdict(soak: Soak) -> dict[str, Any]:
    trends = judge_trends(soak.rows)
    faults: dict[str, Any] = {}
    for name in sorted({e.fault for e in soak.episodes}):
        mine = [e for e in soak.episodes if e.fault == name and not e.unsupported]
        heal_times = [e.time_to_heal_s for e in mine if e.time_to_heal_s is not None]
        faults[name] = {
            "injected": len(mine), "unsupported": soak.unsupported.get(name, ""),
            "reported": sum(e.reported_s is not None for e in mine), "must_report": FAULTS[name].must_report,
            "healed": len(heal_times), "heal_p50_s": round(statistics.median(heal_times), 3) if heal_times else None,
            "heal_max_s": max(heal_times) if heal_times else None,
            "log_bytes_max": max((e.log_bytes for e in mine), default=0),
            "failures": [f for e in mine for f in e.failures][:5]}
    growing = [k for k, t in trends.items() if t["growing"]]
    unreported = [n for n, f in faults.items() if f["must_report"] and f["reported"] < f["injected"]]
    unhealed = [n for n, f in faults.items() if f["healed"] < f["injected"]]
    unanswered = [n for n, f in faults.items() if f["failures"]]
    return {"flat": not growing, "growing": growing, "trends": trends, "faults": faults,
            "all_reported": not unreported, "unreported": unreported, "all_healed": not unhealed,
            "unhealed": unhealed, "all_answered": not unanswered, "unanswered": unanswered,
            "map_kept": not soak.map_problems, "map_problems": soak.map_problems,
            "restarts_by_the_soak": soak.generation, "final_map_adaptations": soak.final_map_adaptations,
            "passed": not (growing or unreported or unhealed or unanswered or soak.map_problems)}


def print_verdict(result: dict[str, Any]) -> None:
    print("\nfault               injected reported healed  heal p50 s  heal max s  log B max")
    for name, f in result["faults"].items():
        if f["unsupported"]:
            print(f"{name:20s} unsupported by this service ({f['unsupported'][:90]})")
            continue
        reported = f"{f['reported']:8d}" if f["must_report"] else "    load"
        p50, top = (f"{f[k]:10.2f}" if f[k] is not None else "         -" for k in ("heal_p50_s", "heal_max_s"))
        print(f"{name:20s} {f['injected']:8d} {reported} {f['healed']:6d}  {p50}  {top}  {f['log_bytes_max']:9d}")
    for key in result["growing"]:
        t = result["trends"][key]
        print(f"growing: generation {t['generation']} {t['figure']}: +{t['growth']:g} over the run "
              f"(tolerance {t['tolerance']:g}; {t['slope_per_hour']:g} per hour)")
    print(f"resources: {'flat' if result['flat'] else 'GROWING'}; faults reported: "
          f"{'all' if result['all_reported'] else 'NOT ' + ', '.join(result['unreported'])}; healed: "
          f"{'all' if result['all_healed'] else 'NOT ' + ', '.join(result['unhealed'])}; requests answered: "
          f"{'all' if result['all_answered'] else 'NOT in ' + ', '.join(result['unanswered'])}; map: "
          f"{'kept' if result['map_kept'] else 'LOST'}; restarts by the soak: {result['restarts_by_the_soak']}")
    for problem in result["map_problems"]:
        print(f"  map: {problem}")
    print(f"verdict: {'PASS' if result['passed'] else 'FAIL'}")


def write_outputs(soak: Soak, result: dict[str, Any], args: argparse.Namespace) -> None:
    rows = [{k: v for k, v in r.items() if not k.startswith("_")} for r in soak.rows]
    if args.json:
        Path(args.json).write_text(json.dumps({
            "command": sys.argv, "date": time.strftime("%Y-%m-%d %H:%M:%S %Z"), "cpus": os.cpu_count(),
            "args": {k: v for k, v in vars(args).items()}, "rows": rows,
            "episodes": [asdict(e) | {"time_to_heal_s": e.time_to_heal_s} for e in soak.episodes],
            "verdict": result}, indent=1))
    if args.csv:
        with open(args.csv, "w", newline="") as f:
            writer = csv.DictWriter(f, fieldnames=[k for k, _ in COLUMNS] + ["servo_pid", "adaptations"])
            writer.writeheader()
            writer.writerows({k: r.get(k) for k in writer.fieldnames} for r in rows)


def parse(argv: list[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seconds", type=float, default=180.0, help="how long the soak runs (real time)")
    parser.add_argument("--report-every", type=float, default=30.0, help="seconds between rows (the run's 'hour')")
    parser.add_argument("--fault-every", type=float, default=8.0, help="mean gap between faults, seconds")
    parser.add_argument("--heal-timeout-s", type=float, default=30.0)
    parser.add_argument("--burst", type=int, default=50, help="requests or looks in one burst")
    parser.add_argument("--faults", default=",".join(FAULTS), help=f"comma-separated, of: {', '.join(FAULTS)}")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--json", help="write rows, episodes and the verdict here")
    parser.add_argument("--csv", help="write the rows here")
    args = parser.parse_args(argv)
    args.faults = [n.strip() for n in args.faults.split(",") if n.strip()]
    unknown = [n for n in args.faults if n not in FAULTS]
    if unknown:
        parser.error(f"--faults: unknown {', '.join(unknown)}; known: {', '.join(FAULTS)}")
    if not 0 < args.seconds <= MAX_SECONDS or not 0 < args.report_every <= args.seconds:
        parser.error(f"0 < --report-every <= --seconds <= {MAX_SECONDS:.0f}")
    if not 0 < args.fault_every <= 3600 or not 0 < args.heal_timeout_s <= 600 or not 1 <= args.burst <= 1000:
        parser.error("0 < --fault-every <= 3600, 0 < --heal-timeout-s <= 600, 1 <= --burst <= 1000")
    return args


def main(argv: list[str] | None = None) -> int:
    args = parse(argv)
    print(f"host: {os.cpu_count()} CPUs, load average {os.getloadavg()[0]:.2f}; {args.seconds:g} s, a row every "
          f"{args.report_every:g} s, a fault every {args.fault_every:g} s on average, seed {args.seed}", flush=True)
    with tempfile.TemporaryDirectory(prefix="hostile-soak-") as tmp:
        try:
            soak = Soak(args, Path(tmp))
        except SoakError as err:
            print(f"soak: {err}", file=sys.stderr)
            return 2
        # SIGTERM (a soak stopped from outside) ends it as Ctrl-C does: its daemon is stopped.
        signal.signal(signal.SIGTERM, signal.default_int_handler)
        try:
            soak.run()
        except SoakError as err:
            soak.daemon.stop()
            print(f"soak: {err}", file=sys.stderr)
            return 2
        except KeyboardInterrupt:
            soak.daemon.stop()
            print("soak: stopped before its end", file=sys.stderr)
            return 2
        result = verdict(soak)
    print_verdict(result)
    write_outputs(soak, result, args)
    return 0 if result["passed"] else 1


if __name__ == "__main__":
    sys.exit(main())
