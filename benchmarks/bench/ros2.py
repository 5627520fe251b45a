"""The ROS 2 interface's cost and latency on the simulated head (320 x 240, two eyes, 30 fps).

Runs the service in this process with `ros2: {enabled: true, localhost_only: true}` (the servo
loop in its own process, as `headctl run` does) and a subscriber to every stream in a second
process (`tests.headctl.ros2.wire_peer`'s `Peer`, over loopback), so every sample is
serialised and sent. Over `--seconds`:

- the latency from the data's own time to the end of its write: joint states from the servo
  read (`BusState.time_s`), images from the frame's time (the exposure, simulated cameras),
  for each of image_raw, image_raw/compressed and camera_info of both eyes (p50, p99);
- what was published and at what rate;
- the CPU time of the interface's threads (`ros2-*`) and of Cyclone DDS's own threads in
  this process (every thread whose name is not one of the service's), as a share of one core,
  from /proc/self/task/*/stat.

    .venv/bin/python -m benchmarks.bench.ros2 [--seconds 30] [--no-compressed]
"""
from __future__ import annotations

import argparse
import dataclasses
import os
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

from headctl.api.compose import serve
from headctl.config.head import load_config
from headctl.config.ros2 import Ros2Config, Ros2Images
from headctl.ros2.interface import Ros2Interface

CLOCK_TICKS = os.sysconf("SC_CLK_TCK")
# The service's own threads (everything else in this process is the interface's or DDS's).
SERVICE_THREADS = ("MainThread", "python", "camera-left", "camera-right", "servo-link", "fixation", "gaze-adapter",
                   "api-server", "supervisor", "AnyIO worker", "asyncio", "Thread-", "numba", "QueueFeederThread", "correspondence")

PEER = """
import os, sys, time
from cyclonedds.domain import Domain
from headctl.config.ros2 import Ros2Config
from headctl.ros2.node import LOCALHOST_XML
from headctl.ros2.streams import JOINT_STATES, TF, image_topics
from tests.headctl.ros2.peer import Peer
domain = Domain(int(sys.argv[1]), LOCALHOST_XML)
peer = Peer(Ros2Config(enabled=True, domain_id=int(sys.argv[1]), localhost_only=True))
for spec in (JOINT_STATES, TF, *image_topics("left"), *image_topics("right")):
    peer.subscribe(spec)
time.sleep(float(sys.argv[2]))
print({name: len(s) for name, s in peer.samples.items()}, flush=True)
peer.close()
os._exit(0)  # no finalisers of the binding's entities at interpreter exit
"""


def thread_cpu() -> dict[str, float]:
    """CPU seconds so far of each thread of this process, by `name:tid`: a Python thread's
    name, else the kernel's (Cyclone DDS names its threads: recv, tev, dq.builtins, ...)."""
    python_names = {t.native_id: t.name for t in threading.enumerate()}
    out: dict[str, float] = {}
    for task in Path("/proc/self/task").iterdir():
        try:
            name = python_names.get(int(task.name)) or (task / "comm").read_text().strip()
            fields = (task / "stat").read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        out[f"{name}:{task.name}"] = (int(fields[11]) + int(fields[12])) / CLOCK_TICKS
    return out


def quantiles_ms(values: list[float]) -> str:
    if not values:
        return "none"
    p50, p99 = np.quantile(np.asarray(values) * 1e3, (0.5, 0.99))
    return f"p50 {p50:.2f} ms, p99 {p99:.2f} ms ({len(values)} samples)"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=30.0)
    parser.add_argument("--no-compressed", action="store_true", help="publish image_raw and camera_info only")
    args = parser.parse_args(argv)
    domain = 200 + os.getpid() % 30
    with tempfile.TemporaryDirectory() as state:
        config = load_config().with_state_dir(Path(state)).with_api(enabled=False)
        config = dataclasses.replace(config, ros2=Ros2Config(
            enabled=True, domain_id=domain, localhost_only=True,
            images=Ros2Images(compressed=not args.no_compressed)))
        with serve(config) as daemon:
            front = daemon.front_end
            ros2 = next(p for p in getattr(front, "parts", ()) if isinstance(p, Ros2Interface))
            assert ros2.streams is not None
            peer = subprocess.Popen([sys.executable, "-c", PEER, str(domain), str(args.seconds + 4)],
                                    stdout=subprocess.PIPE, text=True, env={**os.environ, "PYTHONPATH": os.getcwd()})
            time.sleep(3.0)  # the peer discovered and matched
            for series in ros2.streams.latencies_s.values():
                series.clear()
            published0, cpu0, t0 = dict(ros2.streams.published), thread_cpu(), time.monotonic()
            time.sleep(args.seconds)
            published1, cpu1, t1 = dict(ros2.streams.published), thread_cpu(), time.monotonic()
            latencies = {k: list(v) for k, v in ros2.streams.latencies_s.items()}
            received = peer.communicate(timeout=60)[0].strip()
    span = t1 - t0
    print(f"ROS 2 interface on the simulated head, 320 x 240, two eyes, {span:.0f} s"
          f"{' (no compressed images)' if args.no_compressed else ''}")
    for name in sorted(published1):
        n = published1[name] - published0.get(name, 0)
        print(f"  published {name}: {n} ({n / span:.1f} /s)")
    print(f"  latency joint_states (read -> written): {quantiles_ms(latencies['joint_states'])}")
    print(f"  latency images (exposure -> all of one eye's topics written): {quantiles_ms(latencies['images'])}")
    print(f"  latency images (frame first seen -> written): {quantiles_ms(latencies['images_seen'])}")
    ours = {k: cpu1[k] - cpu0.get(k, 0.0) for k in cpu1 if not k.startswith(SERVICE_THREADS)}
    ros2_threads = sum(v for k, v in ours.items() if k.startswith("ros2-"))
    dds_threads = sum(v for k, v in ours.items() if not k.startswith("ros2-"))
    print(f"  CPU: interface threads {100 * ros2_threads / span:.1f} % of a core, "
          f"Cyclone DDS threads {100 * dds_threads / span:.1f} %, "
          f"together {100 * (ros2_threads + dds_threads) / span:.1f} %")
    busiest = sorted(ours.items(), key=lambda kv: -kv[1])[:6]
    print("  by thread: " + ", ".join(f"{k.split(':')[0]} {100 * v / span:.1f} %" for k, v in busiest))
    print(f"  the peer received: {received}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
