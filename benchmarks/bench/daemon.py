"""The service's timing: servo loop period jitter at 100 Hz while learning, and the latency
from a frame's exposure to the vergence command it leads to being on the bus.

Runs `headctl run` on the simulated head (configs/sim.yaml: servo bus and cameras in real
time, fixations, the adapter learning, checkpoints) in a child process with a temporary
state directory for `--seconds`, then reads the daemon's own figures from its HTTP API:
the servo loop's cycle periods (the last 6,000 cycles, 60 s at 100 Hz) and, for every
fine-vergence step, the time from the exposure of the pair it reacts to until the loop
wrote the command. As a baseline, the same `ServoLoop` runs in this process on an idle
simulated bus (no cameras, no learning, the same thread priority) for up to 10 s.

    .venv/bin/python -m benchmarks.bench.daemon [--seconds 30] [--config configs/sim.yaml]
"""
from __future__ import annotations

import argparse
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from drivers.servo.config import ServoBusConfig
from drivers.sim.servos import SimulatedServoBus
from headctl.config.head import load_config
from headctl.service.servo_io.loop import ServoLoop
from headctl.api.client import ApiClient, ApiError

ROOT = Path(__file__).resolve().parents[2]


def idle_baseline(config_path: Path, seconds: float) -> dict:
    config = load_config(config_path)
    with SimulatedServoBus(ServoBusConfig.from_mapping({"backend": "sim", "port": "sim:bench", "joints": {
            j: {"id": c.servo_id, "min_angle": c.min_angle, "max_angle": c.max_angle}
            for j, c in config.servo_bus.joints.items()}})) as bus:
        bus.enable()
        loop = ServoLoop(bus, config.service.servo_rate_hz, realtime_priority=config.service.realtime_priority)
        loop.start()
        time.sleep(seconds)
        loop.stop()
        return loop.timing()


def run_daemon(config_path: Path, seconds: float) -> dict:
    with tempfile.TemporaryDirectory(prefix="bench-daemon-") as state:
        proc = subprocess.Popen([sys.executable, "-m", "headctl.cli.main", "--log-level", "WARNING", "run",
                                 "--config", str(config_path), "--state-dir", state, "--api-port", "0"], cwd=ROOT,
                                stderr=subprocess.DEVNULL)
        url_file = Path(state) / "api.url"
        try:
            deadline = time.monotonic() + 30
            while True:
                try:
                    client = ApiClient(url_file.read_text().strip())
                    if client.state()["state"] == "running":
                        break
                except (OSError, ApiError):
                    pass
                if time.monotonic() > deadline or proc.poll() is not None:
                    raise SystemExit("the daemon did not start")
                time.sleep(0.1)
            time.sleep(seconds)  # the measurement itself: the daemon learns meanwhile
            status = client.state()
        finally:
            proc.send_signal(signal.SIGTERM)
            proc.wait(10)
        return status


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seconds", type=float, default=30.0)
    parser.add_argument("--config", type=Path, default=ROOT / "configs" / "sim.yaml")
    args = parser.parse_args()
    print(f"host: {os.cpu_count()} CPUs, load average {os.getloadavg()[0]:.2f}")
    status = run_daemon(args.config, args.seconds)
    base = idle_baseline(args.config, min(args.seconds, 10.0))
    loop = status["servo_loop"]
    fix = status["fixation"]
    lat = fix["vergence_latency_ms"]
    print(f"daemon on {args.config.name} for {args.seconds:.0f} s: {fix['done']} fixations, {fix['taught']} taught, "
          f"{status['learning']['adaptations']} adaptations")
    print(f"{'servo loop at ' + str(loop['rate_hz']) + ' Hz':<34} {'cycles':>7} {'period p50':>11} {'p99':>8} "
          f"{'|jitter| p50':>13} {'p99':>8} {'overruns':>9}")
    for name, t in (("while learning (the daemon)", loop), ("idle bus, no cameras (baseline)", base)):
        print(f"{name:<34} {t['cycles']:>7} {t['period_p50_ms']:>9.3f}ms {t['period_p99_ms']:>6.3f}ms "
              f"{t['jitter_p50_ms']:>11.3f}ms {t['jitter_p99_ms']:>6.3f}ms {t['overruns']:>9}")
    if lat["count"]:
        print(f"frame-to-command latency, fine vergence ({lat['count']} steps): p50 {lat['p50']:.1f} ms, "
              f"p99 {lat['p99']:.1f} ms (exposure of the pair -> goal written by the servo loop)")
    else:
        print("no fine-vergence step in the run: raise --seconds")
    return 0


if __name__ == "__main__":
    sys.exit(main())
