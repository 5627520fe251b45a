"""Hostile runs: `headctl run` killed with SIGKILL again and again, and what the map keeps.

From an empty state directory, starts `headctl run --state-dir DIR --api-port 0` on the
default simulated head (configs/sim.yaml, the API on loopback), lets it learn for a random
time of `--min-s` to `--max-s` seconds (from the launch), reads its adaptations from the
API just before the kill, and kills it with SIGKILL; `--kills` times in a row. Each start
reports what it restored (`map.restored.adaptations`, `map.restored_from`, `map.problems`);
a last start reads what survived the last kill and is then stopped with SIGTERM. The
temporary files of saves cut short are counted before each start (the daemon removes them).

Reported: adaptations learned in all runs together against adaptations restored at the
end, and the adaptations lost at each kill (those learned after the last checkpoint).

    .venv/bin/python -m benchmarks.hostile.kills [--kills 15] [--min-s 20] [--max-s 60] [--seed 1]
"""
from __future__ import annotations

import argparse
import os
import random
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from calib_free.map.file import temporary_files
from headctl.api.client import ApiClient, ApiError

ROOT = Path(__file__).resolve().parents[2]

MAX_KILLS = 50
START_TIMEOUT_S = 60.0
MAX_RUN_S = 300.0


class Daemon:
    def __init__(self, state: Path, log: Any) -> None:
        (state / "api.url").unlink(missing_ok=True)
        self.started_s = time.monotonic()
        self.proc = subprocess.Popen([sys.executable, "-m", "headctl.cli.main", "--log-level", "WARNING", "run",
                                      "--state-dir", str(state), "--api-port", "0"], cwd=ROOT, stdout=log,
                                     stderr=subprocess.STDOUT)
        self.url_file = state / "api.url"
        self.client: ApiClient | None = None

    def wait_running(self) -> dict[str, Any]:
        deadline = time.monotonic() + START_TIMEOUT_S
        while True:
            if self.proc.poll() is not None:
                raise SystemExit(f"the daemon exited with {self.proc.returncode} while starting")
            if time.monotonic() > deadline:
                self.proc.kill()
                raise SystemExit(f"the daemon did not start within {START_TIMEOUT_S:.0f} s")
            try:
                if self.client is None and self.url_file.exists():
                    url = self.url_file.read_text().strip()
                    if url:
                        self.client = ApiClient(url, timeout_s=5.0)
                if self.client is not None:
                    status: dict[str, Any] = self.client.state()
                    if status["state"] in ("running", "degraded"):
                        return status
            except (OSError, ApiError, ValueError):
                pass
            time.sleep(0.1)

    def adaptations(self) -> int | None:
        try:
            assert self.client is not None
            return int(self.client.state()["learning"]["adaptations"])
        except (OSError, ApiError, KeyError, TypeError):
            return None


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--kills", type=int, default=15)
    parser.add_argument("--min-s", type=float, default=20.0)
    parser.add_argument("--max-s", type=float, default=60.0)
    parser.add_argument("--seed", type=int, default=1)
    args = parser.parse_args()
    if not 1 <= args.kills <= MAX_KILLS or not 0 < args.min_s <= args.max_s <= MAX_RUN_S:
        parser.error(f"--kills in 1..{MAX_KILLS}, 0 < --min-s <= --max-s <= {MAX_RUN_S:.0f}")
    rng = random.Random(args.seed)
    print(f"host: {os.cpu_count()} CPUs, load average {os.getloadavg()[0]:.2f}; {args.kills} kills, "
          f"{args.min_s:g}-{args.max_s:g} s apart, seed {args.seed}")
    learned_total = 0
    losses: list[int] = []
    problems: list[str] = []
    leftovers = 0
    with tempfile.TemporaryDirectory(prefix="hostile-kills-") as tmp:
        state = Path(tmp) / "state"
        state.mkdir()
        with open(Path(tmp) / "daemon.log", "wb") as log:
            last_seen: int | None = None
            for run in range(args.kills + 1):
                leftovers += len(temporary_files(state))
                daemon = Daemon(state, log)
                status = daemon.wait_running()
                restored = int(status["map"]["restored"]["adaptations"])
                problems += status["map"]["problems"]
                if last_seen is not None:
                    losses.append(last_seen - restored)
                line = (f"run {run + 1:2d}: restored {restored:4d} adaptations from "
                        f"{Path(status['map']['restored_from']).name}")
                if run == args.kills:
                    print(line)
                    daemon.proc.send_signal(signal.SIGTERM)
                    daemon.proc.wait(30)
                    break
                kill_at = daemon.started_s + rng.uniform(args.min_s, args.max_s)
                while time.monotonic() < kill_at - 0.5:
                    time.sleep(0.5)
                    if daemon.proc.poll() is not None:
                        raise SystemExit(f"the daemon exited with {daemon.proc.returncode} by itself")
                time.sleep(max(0.0, kill_at - time.monotonic()))
                seen = daemon.adaptations()
                daemon.proc.send_signal(signal.SIGKILL)
                daemon.proc.wait(10)
                last_seen = seen if seen is not None else restored
                learned_total += last_seen - restored
                print(f"{line}; killed after {time.monotonic() - daemon.started_s:4.1f} s at {last_seen:4d} "
                      f"adaptations ({last_seen - restored} learned in this run)", flush=True)
    kept = restored
    print(f"learned in all runs: {learned_total} adaptations; restored at the end: {kept} "
          f"({100.0 * kept / max(learned_total, 1):.0f} %); lost per kill: worst {max(losses)}, "
          f"median {sorted(losses)[len(losses) // 2]}, total {sum(losses)}")
    print(f"temporary files of cut-short saves found at start: {leftovers}; problems reported at restore: "
          f"{len(problems)}")
    for problem in problems:
        print(f"  {problem}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
