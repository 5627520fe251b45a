"""What the machine itself allows a 100 Hz loop: a bare sleep loop, no work, at SCHED_FIFO.

The servo loop's longest period and its periods over 12 ms (`bench_api.py`) cannot be better
than what an empty loop of the same kind gets from this machine's scheduler and timers; this
is that baseline. Run it alone, or beside `bench_api.py` to see the two on the same machine at
the same moment.

    .venv/bin/python -m benchmarks.bench.timer [--cycles 6000] [--priority 10]
"""
from __future__ import annotations

import argparse
import os
import time


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--cycles", type=int, default=6000, help="periods to measure (default 6000: 60 s)")
    parser.add_argument("--priority", type=int, default=10, help="SCHED_FIFO priority; 0 for normal")
    args = parser.parse_args()
    policy = "normal priority"
    if args.priority > 0:
        try:
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(args.priority))
            policy = f"SCHED_FIFO {args.priority}"
        except OSError as err:
            policy = f"normal priority (SCHED_FIFO refused: {err.strerror})"
    period_s = 0.01
    periods = []
    previous = next_s = time.monotonic()
    for _ in range(args.cycles):
        next_s += period_s
        time.sleep(max(0.0, next_s - time.monotonic()))
        now = time.monotonic()
        periods.append(now - previous)
        previous = now
    periods.sort()
    n = len(periods)
    over = sum(p > 1.2 * period_s for p in periods)
    print(f"{n} periods of 10 ms, an empty sleep loop at {policy}, load average {os.getloadavg()[0]:.2f}: "
          f"p50 {periods[n // 2] * 1e3:.2f} ms, p99 {periods[int(n * 0.99)] * 1e3:.2f} ms, "
          f"longest {periods[-1] * 1e3:.1f} ms, over 12 ms: {over} ({over * 10_000 / n:.1f} in 10,000)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
