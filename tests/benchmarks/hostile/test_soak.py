"""The soak (benchmarks/hostile/soak.py): its judgement of trends and faults on made-up runs,
and a few seconds of the real thing on the simulated head."""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import pytest

from benchmarks.hostile.soak import judge_trends, verdict
from benchmarks.hostile.soak_faults import Episode
from benchmarks.support.procfs import child_running, sample, trend

ROOT = Path(__file__).resolve().parents[3]


def test_a_trend_is_growing_only_beyond_its_tolerance_and_with_three_points():
    times = [0.0, 10.0, 20.0, 30.0]
    assert not trend(times, [100.0, 101.0, 99.0, 100.0], tolerance=5).growing
    assert trend(times, [100.0, 110.0, 120.0, 130.0], tolerance=5).growing
    assert trend(times, [130.0, 120.0, 110.0, 100.0], tolerance=5).growth < 0  # shrinking is not growing
    assert not trend(times[:2], [100.0, 200.0], tolerance=5).growing


def row(t_s: float, generation: int, rss_kb: int) -> dict:
    figures = dict.fromkeys(["threads", "open_files", "servo_rss_kb", "servo_threads", "servo_open_files",
                             "map_bytes", "log_bytes_per_interval"], 10)
    return {"t_s": t_s, "generation": generation, "rss_kb": rss_kb, **figures}


def test_trends_are_judged_per_generation_after_the_first_row():
    start_up = [row(0, 0, 10_000), row(10, 0, 300_000), row(20, 0, 300_100), row(30, 0, 300_000)]
    assert not any(t["growing"] for t in judge_trends(start_up).values())  # the first row is start-up
    leak = [row(10 * i, 1, 300_000 + 40_000 * i) for i in range(5)]
    judged = judge_trends(start_up + leak)
    assert judged["1:rss_kb"]["growing"] and not judged["0:rss_kb"]["growing"]


def run_of(*episodes: Episode, map_problems: list[str] | None = None) -> SimpleNamespace:
    rows = [row(10 * i, 0, 300_000) for i in range(4)]
    unsupported = {e.fault: e.unsupported for e in episodes if e.unsupported}
    return SimpleNamespace(rows=rows, episodes=list(episodes), unsupported=unsupported,
                           map_problems=map_problems or [], generation=0, final_map_adaptations=10)


def episode(fault: str, reported: bool = True, healed: bool = True, unsupported: str = "") -> Episode:
    e = Episode(fault, 0, 1.0, 0.0, heal_from_s=4.0, reported_s=2.0 if reported else None,
                healed_s=4.5 if healed else None, unsupported=unsupported)
    return e


def test_the_verdict_fails_on_a_fault_not_healed_or_not_reported_and_skips_unsupported_ones():
    good = verdict(run_of(episode("bus_down"), episode("brown_out", False, False, unsupported="none offered")))
    assert good["passed"] and good["faults"]["bus_down"]["heal_p50_s"] == 0.5
    assert good["faults"]["brown_out"]["unsupported"] == "none offered"
    assert not verdict(run_of(episode("servo_kill", healed=False)))["passed"]
    assert not verdict(run_of(episode("bus_down", reported=False)))["passed"]
    assert verdict(run_of(episode("api_burst", reported=False)))["passed"]  # load: nothing to report
    assert not verdict(run_of(episode("bus_down"), map_problems=["went back"]))["passed"]


def test_proc_figures_of_this_process_and_its_child():
    me = sample(os.getpid())
    assert me.rss_kb and me.threads and me.open_files and me.cpu_s is not None
    child = subprocess.Popen([sys.executable, "-c", "import time; print(flush=True); time.sleep(30)",
                              "soak-test-marker"], stdout=subprocess.PIPE)
    try:
        child.stdout.readline()  # it runs its own command line now, no longer the one it was forked with
        assert child_running(os.getpid(), "soak-test-marker") == child.pid
    finally:
        child.kill()
        child.wait()
    assert sample(child.pid).rss_kb is None


@pytest.mark.slow
@pytest.mark.timeout(240)
def test_a_short_soak_on_the_simulated_head(tmp_path):
    out = tmp_path / "soak.json"
    proc = subprocess.run([sys.executable, "-m", "benchmarks.hostile.soak", "--seconds", "20", "--report-every",
                           "5", "--fault-every", "2", "--faults", "bus_down,camera_stall,brown_out,api_burst",
                           "--burst", "10", "--json", str(out)], cwd=ROOT, capture_output=True, text=True,
                          timeout=220, env=dict(os.environ, PYTHONPATH=str(ROOT)))
    assert proc.returncode in (0, 1), proc.stdout + proc.stderr
    result = json.loads(out.read_text())
    assert proc.returncode == (0 if result["verdict"]["passed"] else 1)
    rows = result["rows"]
    assert len(rows) >= 4 and all(r["rss_kb"] and r["threads"] and r["open_files"] for r in rows)
    assert result["verdict"]["final_map_adaptations"] >= rows[-1]["adaptations"] > 0  # saved at SIGTERM
    faults = result["verdict"]["faults"]
    assert faults, proc.stdout
    for name, fault in faults.items():  # each injected fault is judged, or marked unsupported
        assert fault["unsupported"] or fault["injected"] >= 1, name
    if faults.get("bus_down", {}).get("injected"):  # the service heals a bus that comes back, today already
        assert faults["bus_down"]["healed"] == faults["bus_down"]["injected"], proc.stdout
        assert faults["bus_down"]["reported"] == faults["bus_down"]["injected"], proc.stdout
    assert result["verdict"]["map_kept"], result["verdict"]["map_problems"]
    assert "verdict:" in proc.stdout
