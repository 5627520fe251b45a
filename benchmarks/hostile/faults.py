"""A hostile run of servo faults: every fault kind the emulator offers, each several times,
injected into a `DynamixelBus` polled at 100 Hz by a thread, as the service's servo loop does.

`headctl emulate-servos --control SOCKET` runs in a child process (real time, its own
interpreter); faults go in through its control socket. The poller thread reads the state and
writes goals every 10 ms (a slow sine on every joint not faulted), counting failed cycles and
whom each failure blames. After each injection the script waits until the bus is back to
normal: a clean cycle after the injection, no hardware error read, every joint's torque on,
the bus up, no open episode in the bus's fault log, and nothing left pending in the emulator.
A joint that the recovery policy leaves to a person (3 automatic reboots in 10 minutes) is
rebooted by the script, as a person would (`ServoBus.reboot`), and counted as such.

It counts faults injected, hardware-error episodes recorded (`bus.fault_log`), failed reads
and whether each blamed the servo the fault was injected on, and faults survived. Bounded
(each wait at most `--wait-s`, the whole run at most `--max-s`); no network.

    .venv/bin/python -m benchmarks.hostile.faults [--repeat 5] [--json out.json]
"""
from __future__ import annotations

import argparse
import json
import logging
import math
import os
import shutil
import socket
import subprocess
import sys
import tempfile
import threading
import time
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from drivers.dynamixel.bus_v2 import DynamixelBus
from drivers.errors import BusDownError, DriverError
from drivers.servo.bus import JOINTS
from drivers.servo.config import ServoBusConfig
from drivers.servo.faults import LEFT_TO_A_PERSON

ROOT = Path(__file__).resolve().parents[2]
IDS = {"pan": 1, "tilt": 2, "left_eye": 3, "right_eye": 4}
JOINT_OF = {servo_id: joint for joint, servo_id in IDS.items()}
RATE_HZ = 100.0


@dataclass
class Poller:
    """The 100 Hz loop: one read and one write a cycle, errors counted, never stopping."""

    bus: DynamixelBus
    cycles: int = 0
    failed: int = 0
    down: int = 0
    errors: Counter[str] = field(default_factory=Counter)
    blamed: list[tuple[float, str]] = field(default_factory=list)  # (time, message) of failed reads
    last_ok_start_s: float = 0.0  # when the last cycle that read and wrote cleanly began
    last_state: Any = None
    max_gap_s: float = 0.0
    window_gap_s: float = 0.0  # the longest gap since the last injection
    seen_faulted: set[str] = field(default_factory=set)  # joints whose error a returned state showed
    late_cycles: int = 0
    stop: threading.Event = field(default_factory=threading.Event)

    def run(self) -> None:
        period = 1.0 / RATE_HZ
        next_s = time.monotonic()
        last_start = next_s
        while not self.stop.is_set():
            start = time.monotonic()
            self.max_gap_s = max(self.max_gap_s, start - last_start)
            self.window_gap_s = max(self.window_gap_s, start - last_start)
            last_start = start
            self.cycle(start)
            next_s += period
            delay = next_s - time.monotonic()
            if delay > 0:
                self.stop.wait(delay)
            else:
                self.late_cycles += 1
                next_s = time.monotonic()

    def cycle(self, now_s: float) -> None:
        self.cycles += 1
        try:
            state = self.bus.read_state()
        except BusDownError as err:
            self.down += 1
            self.failed += 1
            self.errors[type(err).__name__] += 1
            return
        except DriverError as err:
            self.failed += 1
            self.errors[type(err).__name__] += 1
            self.blamed.append((now_s, str(err)))
            return
        self.seen_faulted |= set(state.faults)
        goals = {j: 10.0 * math.sin(0.5 * now_s + i) for i, j in enumerate(JOINTS) if j not in state.faults}
        try:
            self.bus.write_goals(goals)
        except DriverError as err:
            self.errors["write " + type(err).__name__] += 1
            return
        self.last_state = state
        self.last_ok_start_s = now_s


class Control:
    """The emulator's control socket: one command, one line back."""

    def __init__(self, path: str) -> None:
        self.sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        self.sock.settimeout(15.0)
        self.sock.connect(path)
        self.file = self.sock.makefile("rb")

    def __call__(self, command: str) -> str:
        self.sock.sendall(command.encode() + b"\n")
        answer = self.file.readline().decode().rstrip("\n")
        if not answer.startswith("ok"):
            raise RuntimeError(f"{command!r}: {answer}")
        return answer

    def status(self) -> dict[str, Any]:
        return json.loads(self("status")[3:])


# (kind, command template, what it should do): {id} is the servo the fault goes to.
COMM_FAULTS = [
    ("drop 1 reply", "drop {id} 1", "absorbed by a retry"),
    ("drop 3 replies", "drop {id} 3", "a failed read (3 attempts), blamed on the servo"),
    ("corrupt 1 reply", "corrupt {id} 1", "absorbed by a retry"),
    ("corrupt 3 replies", "corrupt {id} 3", "a failed read, blamed on the servo"),
    ("delay 2 ms", "delay {id} 0.002 3", "within the timeout: nothing"),
    ("delay 60 ms x3", "delay {id} 0.06 3", "beyond the timeout: a failed read, blamed, named late"),
    ("power cycle", "powercycle {id}", "torque lost, indirect map gone: reconfigured and re-torqued"),
    ("vanish 0.5 s", "vanish 0.5", "bus down, reopened with back-off"),
]
HW_FAULTS = [
    ("hwerror voltage", "voltage", 0x01),
    ("hwerror overheating", "overheating", 0x04),
    ("hwerror encoder", "encoder", 0x08),
    ("hwerror shock", "shock", 0x10),
    ("hwerror overload", "overload", 0x20),
]
# The faults that make a read fail (a power-cycled servo is silent while it boots): whom
# each failure names is checked.
FAILING = {"drop 3 replies", "corrupt 3 replies", "delay 60 ms x3", "power cycle"}


def quiet(bus: DynamixelBus, control: Control) -> bool:
    """Nothing left pending in the emulator, the bus up, no open hardware-error episode."""
    if bus.is_down or bus.fault_log.open_episodes():
        return False
    status = control.status()
    return not status["vanished"] and all(
        not (s["drop"] or s["corrupt"] or s["delay_count"] or s["hardware_error"] or s["booting"])
        for s in status["servos"].values())


def back_to_normal(poller: Poller, quiet_since_s: float) -> bool:
    """A clean cycle that began once all was quiet (a cycle already under way then may still
    fail on what was pending), reading no hardware error and torque on everywhere."""
    state = poller.last_state
    return (poller.last_ok_start_s > quiet_since_s and state is not None and not state.faults
            and all(s.torque_on for s in state.joints.values()))


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=5, help="injections of each fault kind (default 5)")
    parser.add_argument("--wait-s", type=float, default=20.0, help="longest wait for normal after a fault")
    parser.add_argument("--max-s", type=float, default=600.0, help="longest run")
    parser.add_argument("--json", help="also write the figures to this file")
    args = parser.parse_args()
    log_counts = _count_log_records()

    tmp = tempfile.mkdtemp(prefix="hostile-")
    link, control_path = os.path.join(tmp, "servos"), os.path.join(tmp, "ctl")
    emulator = subprocess.Popen(
        [sys.executable, "-m", "headctl.cli.main", "--log-level", "WARNING", "emulate-servos", "--ids", "1,2,3,4",
         "--link", link, "--control", control_path], cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL,
        text=True)
    started = time.monotonic()
    rows: list[dict[str, Any]] = []
    try:
        assert emulator.stdout is not None
        emulator.stdout.readline()  # the pty: serving, the control socket listening
        control = Control(control_path)
        config = ServoBusConfig.from_mapping({
            "backend": "dynamixel", "port": link, "latency_timer_ms": 8, "retries": 2,
            "reboot_on_hardware_error": True,
            "joints": {j: {"id": i, "min_angle": -90, "max_angle": 90} for j, i in IDS.items()},
        })
        with DynamixelBus(config) as bus:
            bus.enable()
            poller = Poller(bus)
            thread = threading.Thread(target=poller.run, name="hostile-poller", daemon=True)
            thread.start()

            def inject(kind: str, command: str, joint: str | None, expect_blame: bool) -> None:
                if time.monotonic() - started > args.max_s:
                    raise TimeoutError(f"run longer than {args.max_s} s")
                seq0, failed0, blamed0 = bus.fault_log.last_seq, poller.failed, len(poller.blamed)
                poller.window_gap_s = 0.0
                poller.seen_faulted = set()
                by_hand = False
                t0 = time.monotonic()
                control(command)
                deadline = t0 + args.wait_s
                quiet_since_s: float | None = None
                while True:
                    if not quiet(bus, control):
                        quiet_since_s = None
                    elif quiet_since_s is None:
                        quiet_since_s = time.monotonic()
                    elif back_to_normal(poller, quiet_since_s):
                        break
                    given_up = [j for j, e in bus.fault_log.open_episodes().items() if e.recovery == LEFT_TO_A_PERSON]
                    for j in given_up:  # a person reboots it
                        try:
                            bus.reboot(j)
                            by_hand = True
                        except DriverError as err:  # the bus is busy failing: try again
                            poller.errors["reboot by hand " + type(err).__name__] += 1
                    if time.monotonic() > deadline:
                        break
                    time.sleep(0.01)  # the poller runs meanwhile; this only paces the checks
                back_s = time.monotonic() - t0
                survived = back_s <= args.wait_s
                new_blames = [m for _t, m in poller.blamed[blamed0:]]
                named = [m for m in new_blames if joint and f"joint {joint} (id {IDS[joint]})" in m]
                alone = [m for m in named if not any(f"joint {j} (" in m for j in JOINTS if j != joint)]
                records = bus.fault_log.since(seq0)
                episodes = {r.episode for r in records}
                rows.append({
                    "kind": kind, "joint": joint, "survived": survived, "back_s": round(back_s, 3),
                    "failed_reads": poller.failed - failed0, "blamed": len(new_blames),
                    "blamed_right": len(named) if expect_blame else None,
                    "blamed_alone": len(alone) if expect_blame else None, "episodes": len(episodes),
                    "recoveries": sorted({r.recovery for r in records}), "by_hand": by_hand,
                    "late_named": sum("came after the timeout" in m for m in named), "messages": new_blames,
                    "gap_max_ms": round(poller.window_gap_s * 1000, 1),
                    "in_state": joint in poller.seen_faulted,
                })

            time.sleep(0.5)  # a few clean cycles first
            order = list(JOINTS)
            n = 0
            for _ in range(args.repeat):
                for kind, template, _what in COMM_FAULTS:
                    joint = order[n % 4] if "{id}" in template else None
                    n += 1
                    inject(kind, template.format(id=IDS[joint] if joint else 0), joint, kind in FAILING)
                for kind, name, _bits in HW_FAULTS:
                    joint = order[n % 4]
                    n += 1
                    inject(kind, f"hwerror {IDS[joint]} {name}", joint, False)
            poller.stop.set()
            thread.join(5)
            figures = summarise(rows, poller, bus, time.monotonic() - started)
            figures["log_records"] = dict(log_counts)
    finally:
        emulator.terminate()
        try:
            emulator.wait(10)
        except subprocess.TimeoutExpired:
            emulator.kill()
        shutil.rmtree(tmp, ignore_errors=True)
    print_figures(figures)
    if args.json:
        Path(args.json).write_text(json.dumps({"figures": figures, "injections": rows}, indent=2))
    return 0 if figures["survived"] == figures["injected"] else 1


def _count_log_records() -> Counter[str]:
    """Count the drivers' log records by level instead of printing them."""
    counts: Counter[str] = Counter()

    class Counting(logging.Handler):
        def emit(self, record: logging.LogRecord) -> None:
            counts[record.levelname] += 1

    root = logging.getLogger()
    root.addHandler(Counting(logging.INFO))
    root.setLevel(logging.INFO)
    return counts


def summarise(rows: list[dict[str, Any]], poller: Poller, bus: DynamixelBus, run_s: float) -> dict[str, Any]:
    kinds: dict[str, dict[str, Any]] = {}
    for row in rows:
        k = kinds.setdefault(row["kind"], {"injected": 0, "survived": 0, "episodes": 0, "failed_reads": 0,
                                           "blamed": 0, "blamed_right": 0, "blamed_alone": 0, "late_named": 0,
                                           "by_hand": 0,
                                           "back_max_s": 0.0, "gap_max_ms": 0.0, "in_state": 0,
                                           "recoveries": set()})
        k["injected"] += 1
        k["survived"] += row["survived"]
        k["episodes"] += row["episodes"]
        k["failed_reads"] += row["failed_reads"]
        k["blamed"] += row["blamed"]
        k["blamed_right"] += row["blamed_right"] or 0
        k["blamed_alone"] += row["blamed_alone"] or 0
        k["late_named"] += row["late_named"]
        k["by_hand"] += row["by_hand"]
        k["back_max_s"] = max(k["back_max_s"], row["back_s"])
        k["gap_max_ms"] = max(k["gap_max_ms"], row["gap_max_ms"])
        k["in_state"] += row["in_state"] and row["kind"].startswith("hwerror")
        k["recoveries"] |= set(row["recoveries"])
    for k in kinds.values():
        k["recoveries"] = sorted(k["recoveries"])
    hw = [r for r in rows if r["kind"].startswith("hwerror")]
    return {
        "run_s": round(run_s, 1), "injected": len(rows), "survived": sum(r["survived"] for r in rows),
        "hw_injected": len(hw), "hw_episodes": len({r.episode for r in bus.fault_log.since(0)}),
        "hw_reboots": sum(bus.recovery.reboots.values()), "by_hand": sum(r["by_hand"] for r in rows),
        "hw_in_state": sum(r["in_state"] for r in hw),
        "failed_reads": sum(r["failed_reads"] for r in rows),
        "blamed": sum(r["blamed"] for r in rows if r["kind"] in FAILING),
        "blamed_right": sum(r["blamed_right"] or 0 for r in rows),
        "blamed_alone": sum(r["blamed_alone"] or 0 for r in rows),
        "cycles": poller.cycles, "failed_cycles": poller.failed, "down_cycles": poller.down,
        "late_cycles": poller.late_cycles, "max_gap_ms": round(poller.max_gap_s * 1000, 1),
        "errors": dict(poller.errors), "log_missed": bus.fault_log.missed(0), "kinds": kinds,
    }


def print_figures(f: dict[str, Any]) -> None:
    print(f"hostile servo faults: {f['injected']} injected, {f['survived']} survived, run {f['run_s']} s")
    print(f"  hardware errors: {f['hw_injected']} injected, {f['hw_episodes']} episodes recorded, "
          f"{f['hw_in_state']} ever shown by a state read_state() returned, "
          f"{f['hw_reboots']} automatic reboots, {f['by_hand']} left to a person and rebooted by hand")
    print(f"  failed reads: {f['failed_reads']}; from the read-failing faults {f['blamed']}, "
          f"naming the servo the fault was on {f['blamed_right']}, naming it alone {f['blamed_alone']}")
    print(f"  log records of the bus: {f['log_records']}")
    print(f"  poller: {f['cycles']} cycles, {f['failed_cycles']} failed ({f['down_cycles']} bus down), "
          f"{f['late_cycles']} late, longest gap {f['max_gap_ms']} ms; errors {f['errors']}")
    print()
    print("| fault | injected | survived | episodes | in a state | failed reads | blamed right (alone) "
          "| back to normal, max | longest cycle gap | recovery |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |")
    for kind, k in f["kinds"].items():
        blamed = f"{k['blamed_right']}/{k['blamed']} ({k['blamed_alone']})" if kind in FAILING else "–"
        recovery = ", ".join(k["recoveries"]) or "–"
        if k["by_hand"]:
            recovery += f"; {k['by_hand']} by hand"
        in_state = str(k["in_state"]) if kind.startswith("hwerror") else "–"
        print(f"| {kind} | {k['injected']} | {k['survived']} | {k['episodes']} | {in_state} | {k['failed_reads']} | "
              f"{blamed} | "
              f"{k['back_max_s']:.2f} s | {k['gap_max_ms']:.0f} ms | {recovery} |")


if __name__ == "__main__":
    sys.exit(main())
