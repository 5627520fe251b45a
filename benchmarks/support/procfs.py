"""What a process holds, read from /proc: resident memory, threads, open files, CPU time; its
children by command line; and a linear trend over a series of samples, to call it flat or
growing."""
from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

CLOCK_TICKS = os.sysconf("SC_CLK_TCK")


@dataclass(frozen=True)
class ProcSample:
    """One process at one moment; `None` fields: the process was gone."""

    pid: int
    rss_kb: int | None
    threads: int | None
    open_files: int | None
    cpu_s: float | None  # user + system time so far


def sample(pid: int) -> ProcSample:
    """`pid`'s figures now (all `None` once it has exited)."""
    base = Path(f"/proc/{pid}")
    try:
        status = dict(line.split(":", 1) for line in (base / "status").read_text().splitlines() if ":" in line)
        stat = (base / "stat").read_text()
        fds = sum(1 for _ in (base / "fd").iterdir())
    except (FileNotFoundError, ProcessLookupError, PermissionError):
        return ProcSample(pid, None, None, None, None)
    fields = stat[stat.rindex(")") + 2:].split()  # after the command name, which may hold spaces
    cpu_s = (int(fields[11]) + int(fields[12])) / CLOCK_TICKS  # utime, stime (fields 14, 15 of stat)
    return ProcSample(pid, int(status["VmRSS"].split()[0]) if "VmRSS" in status else 0,
                      int(status["Threads"]), fds, cpu_s)


def children(pid: int) -> list[int]:
    """The live children of `pid` (every thread's list: a child belongs to the thread that made it)."""
    found: list[int] = []
    try:
        for task in Path(f"/proc/{pid}/task").iterdir():
            try:
                found += [int(c) for c in (task / "children").read_text().split()]
            except FileNotFoundError:
                continue
    except FileNotFoundError:
        return []
    return sorted(set(found))


def command_line(pid: int) -> str:
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
    except (FileNotFoundError, ProcessLookupError):
        return ""


def alive(pid: int) -> bool:
    """Whether process `pid` exists and has not exited (a zombie waiting to be reaped has)."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except (FileNotFoundError, ProcessLookupError):
        return False
    return stat.rsplit(")", 1)[1].split()[0] not in ("Z", "X")


def child_running(pid: int, marker: str) -> int | None:
    """The child of `pid` whose command line holds `marker` (the first, by pid), if any."""
    for child in children(pid):
        if marker in command_line(child):
            return child
    return None


@dataclass(frozen=True)
class Trend:
    """A least-squares line through (t, value): its growth over the span judged, and the verdict."""

    slope_per_s: float
    growth: float  # slope times the span of the samples judged
    tolerance: float
    points: int

    @property
    def growing(self) -> bool:
        return self.points >= 3 and self.growth > self.tolerance


def trend(times_s: list[float], values: list[float], tolerance: float) -> Trend:
    """The trend of `values`; fewer than 3 points judge nothing (never growing)."""
    n = len(values)
    if n < 2:
        return Trend(0.0, 0.0, tolerance, n)
    mean_t, mean_v = sum(times_s) / n, sum(values) / n
    spread = sum((t - mean_t) ** 2 for t in times_s)
    slope = sum((t - mean_t) * (v - mean_v) for t, v in zip(times_s, values)) / spread if spread > 0 else 0.0
    return Trend(slope, slope * (max(times_s) - min(times_s)), tolerance, n)
