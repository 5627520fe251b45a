"""Servo bus speed: read + goal-write cycles per second for 4 servos through the emulator.

Runs the emulator in a child process (so its CPU is not counted as the host's), then times
`create_dynamixel_bus(...).read_state()` + `write_goals()` cycles for each way the bus reads: Protocol
2.0 Fast Sync Read and Sync Read (X-series), Protocol 1.0 Bulk Read (MX-28) and per-servo
Reads (AX-12A); beside them the same cycle with the stock dynamixel-sdk `PortHandler`
(busy-waiting reads) as a baseline. Each is measured with the servos' Return Delay Time at
0 and at 500 us: wall time grows with the delay, and CPU time stays flat only if waiting
does not spin.

The wire bound of each read method comes from its packet sizes (10 bits a byte on the
wire) and the Return Delay Time, at 1, 3 and 4 Mbps (Protocol 1.0 servos stop at 1 Mbps).

    .venv/bin/python -m benchmarks.bench.servo_bus [--cycles 2000]
"""
from __future__ import annotations

import argparse
import math
import subprocess
import sys
import time
from pathlib import Path

import dynamixel_sdk as sdk

from drivers.dynamixel.tables.x_series import READ_BLOCK_SIZE, XAddr
from drivers.dynamixel.tables.v1 import READ_SIZE as P1_READ_SIZE
from drivers.dynamixel.factory import create_dynamixel_bus
from drivers.servo.bus import JOINTS
from drivers.servo.config import ServoBusConfig

IDS = (1, 2, 3, 4)
_CHILD = """
import sys, time
from drivers.dynamixel.emulator.server import DxlEmulator
with DxlEmulator({ids}, protocol={protocol}, model={model!r}) as emulator:
    print(emulator.pty_path, flush=True)
    sys.stdin.readline()
    print(time.process_time(), flush=True)
"""


def wire_bytes(n_servos: int, read_bytes: int, write_bytes: int = 4, method: str = "sync read") -> int:
    """Bytes of one cycle: the read (request and replies) and one sync write of the goals."""
    if method in ("bulk read", "per-servo reads"):  # Protocol 1.0: FF FF id len inst/error ... checksum
        sync_write = 8 + n_servos * (1 + write_bytes)
        statuses = n_servos * (6 + read_bytes)
        request = 7 + 3 * n_servos if method == "bulk read" else n_servos * 8
        return request + statuses + sync_write
    sync_read = 14 + n_servos                 # header 7, inst, addr 2, len 2, ids, crc 2
    if method == "fast sync read":            # one status: header 7, inst, then error, id, data, crc 2 each
        statuses = 8 + n_servos * (4 + read_bytes)
    else:
        statuses = n_servos * (11 + read_bytes)   # header 7, inst, error, data, crc 2
    sync_write = 14 + n_servos * (1 + write_bytes)
    return sync_read + statuses + sync_write


def bus_bound_hz(n_bytes: int, baud: int, n_servos: int, return_delay_us: float) -> float:
    return 1.0 / (n_bytes * 10.0 / baud + n_servos * return_delay_us * 1e-6)


class EmulatorProcess:
    """`DxlEmulator` in a child process; reports the child's CPU time when stopped."""

    def __init__(self, protocol: float = 2.0, model: str = "XM430-W350") -> None:
        root = str(Path(__file__).resolve().parents[2])
        child = _CHILD.format(ids=list(IDS), protocol=protocol, model=model)
        self.proc = subprocess.Popen([sys.executable, "-c", child], cwd=root,
                                     stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
        self.port = self.proc.stdout.readline().strip()
        if not self.port:
            raise RuntimeError("the emulator process did not start")

    def stop(self) -> float:
        self.proc.stdin.write("\n")
        self.proc.stdin.flush()
        cpu_s = float(self.proc.stdout.readline())
        self.proc.wait(timeout=10)
        return cpu_s


def set_return_delay(port_path: str, return_delay_us: int) -> None:
    port = sdk.PortHandler(port_path)
    port.openPort()
    packet = sdk.PacketHandler(2.0)
    for servo_id in IDS:
        packet.write1ByteTxRx(port, servo_id, XAddr.TORQUE_ENABLE, 0)
        packet.write1ByteTxRx(port, servo_id, XAddr.RETURN_DELAY_TIME, return_delay_us // 2)
    port.closePort()


def run_headctl(port: str, cycles: int, return_delay_us: int, *, protocol: float = 2.0,
                model: str = "XM430-W350", fast_sync_read: bool = True, method: str = "") -> tuple[float, float]:
    config = ServoBusConfig.from_mapping({
        "backend": "dynamixel", "port": port, "latency_timer_ms": 1, "return_delay_us": return_delay_us,
        "protocol": protocol,
        "joints": {j: {"id": i, "model": model, "profile_velocity": 0, "profile_acceleration": 0}
                   for j, i in zip(JOINTS, IDS)},
    })
    with create_dynamixel_bus(config, fast_sync_read=fast_sync_read) as bus:
        if bus.read_method != method:
            raise RuntimeError(f"the bus reads by {bus.read_method}, not {method}")
        bus.enable()
        goals = lambda k: {j: 10.0 * math.sin(0.01 * k + i) for i, j in enumerate(JOINTS)}  # noqa: E731
        for k in range(50):  # warm up
            bus.read_state()
            bus.write_goals(goals(k))
        wall, cpu = time.perf_counter(), time.process_time()
        for k in range(cycles):
            bus.read_state()
            bus.write_goals(goals(k))
        return time.perf_counter() - wall, time.process_time() - cpu


def run_stock_sdk(port_path: str, cycles: int) -> tuple[float, float]:
    """The plain SDK loop (GroupSyncRead of present position, GroupSyncWrite of goals)."""
    port = sdk.PortHandler(port_path)
    port.openPort()
    packet = sdk.PacketHandler(2.0)
    reader = sdk.GroupSyncRead(port, packet, XAddr.PRESENT_POSITION, 4)
    writer = sdk.GroupSyncWrite(port, packet, XAddr.GOAL_POSITION, 4)
    for servo_id in IDS:
        reader.addParam(servo_id)
        writer.addParam(servo_id, [0, 8, 0, 0])

    def cycle() -> None:
        if reader.txRxPacket() != sdk.COMM_SUCCESS:
            raise RuntimeError("stock SDK sync read failed")
        writer.txPacket()

    try:
        for _ in range(50):
            cycle()
        wall, cpu = time.perf_counter(), time.process_time()
        for _ in range(cycles):
            cycle()
        return time.perf_counter() - wall, time.process_time() - cpu
    finally:
        port.closePort()


# (label, protocol, model, Fast Sync Read allowed, read method, write bytes a servo)
CASES = (
    ("2.0 X fast sync read", 2.0, "XM430-W350", True, "fast sync read", 4),
    ("2.0 X sync read", 2.0, "XM430-W350", False, "sync read", 4),
    ("1.0 MX-28 bulk read", 1.0, "MX-28", True, "bulk read", 2),
    ("1.0 AX-12A per-servo", 1.0, "AX-12A", True, "per-servo reads", 2),
)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cycles", type=int, default=2000)
    args = parser.parse_args()
    n = len(IDS)

    print(f"servo bus benchmark: {n} servos, {args.cycles} cycles of a state read + a goal sync write\n")
    print("wire bound (10 bits a byte, replies queued behind the Return Delay Time; per-servo reads also pay "
          "the adapter's turnaround, not counted here):")
    for label, protocol, _model, _fast, method, write_bytes in CASES:
        read_bytes = READ_BLOCK_SIZE if protocol == 2.0 else P1_READ_SIZE
        n_bytes = wire_bytes(n, read_bytes, write_bytes, method)
        print(f"  {label:<22} {read_bytes:>2} data bytes/servo = {n_bytes} bytes a cycle")
        for baud in (1_000_000, 3_000_000, 4_000_000) if protocol == 2.0 else (1_000_000,):
            wire_us = n_bytes * 10.0 / baud * 1e6
            print(f"    {baud / 1e6:.0f} Mbps: wire {wire_us:7.1f} us -> {bus_bound_hz(n_bytes, baud, n, 0):7.0f} Hz "
                  f"at RDT 0, {bus_bound_hz(n_bytes, baud, n, 500):5.0f} Hz at RDT 500 us")

    print("\nmeasured through the emulator (host = this process; the emulator runs in its own):")
    print(f"  {'client':<30} {'RDT':>6} {'cycles/s':>9} {'wall/cycle':>11} {'host CPU/cycle':>15} {'CPU/wall':>9} "
          f"{'emulator CPU/cycle':>19} {'1 Mbps bound':>13}")
    results = {}
    runs = [(f"headctl {label}", protocol, model, fast, method, write_bytes)
            for label, protocol, model, fast, method, write_bytes in CASES]
    runs.append(("stock dynamixel-sdk sync read", 2.0, "XM430-W350", False, "stock", 4))
    for name, protocol, model, fast, method, write_bytes in runs:
        for rdt_us in (0, 500):
            emulator = EmulatorProcess(protocol, model)
            try:
                if method == "stock":
                    set_return_delay(emulator.port, rdt_us)
                    wall, cpu = run_stock_sdk(emulator.port, args.cycles)
                else:
                    wall, cpu = run_headctl(emulator.port, args.cycles, rdt_us, protocol=protocol, model=model,
                                            fast_sync_read=fast, method=method)
            finally:
                emulator_cpu = emulator.stop()
            per_wall, per_cpu = wall / args.cycles, cpu / args.cycles
            results[(name, rdt_us)] = (per_wall, per_cpu)
            read_bytes = READ_BLOCK_SIZE if protocol == 2.0 else P1_READ_SIZE
            bound = bus_bound_hz(wire_bytes(n, read_bytes if method != "stock" else 4, write_bytes,
                                            "sync read" if method == "stock" else method), 1_000_000, n, rdt_us)
            print(f"  {name:<30} {rdt_us:>4}us {1 / per_wall:>9.0f} {per_wall * 1e6:>9.0f}us {per_cpu * 1e6:>13.0f}us "
                  f"{cpu / wall:>9.2f} {emulator_cpu / args.cycles * 1e6:>17.0f}us {bound:>10.0f} Hz")

    wall0, cpu0 = results[("headctl 2.0 X fast sync read", 0)]
    wall500, cpu500 = results[("headctl 2.0 X fast sync read", 500)]
    wire_1m_s = wire_bytes(n, READ_BLOCK_SIZE, 4, "fast sync read") * 10.0 / 1_000_000
    print("\nconclusions:")
    print(f"  host CPU per cycle {cpu0 * 1e6:.0f} us vs wire time at 1 Mbps {wire_1m_s * 1e6:.0f} us: "
          + ("well under it" if cpu0 < 0.5 * wire_1m_s else "NOT well under it"))
    waited = wall500 - wall0
    print(f"  no busy-wait: RDT 500 us adds {waited * 1e6:.0f} us of wall time per cycle and "
          f"{(cpu500 - cpu0) * 1e6:.0f} us of CPU" + (" (waiting costs no CPU)" if cpu500 - cpu0 < 0.25 * waited
                                                     else " (waiting burns CPU!)"))
    stock_wall, stock_cpu = results[("stock dynamixel-sdk sync read", 500)]
    print(f"  stock SDK at RDT 500 us: CPU/wall {stock_cpu / stock_wall:.2f} (its timeout=0 reads spin)")
    print(f"  through the emulator a cycle takes {wall0 * 1e6:.0f} us: the two Python processes dominate; "
          f"on a real bus at 1 Mbps the wire ({wire_1m_s * 1e6:.0f} us + 4 x RDT) dominates, "
          "at 4 Mbps host CPU and the adapter's latency timer do")
    return 0


if __name__ == "__main__":
    sys.exit(main())
