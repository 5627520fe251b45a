"""The servo process's state block: what the child writes after every cycle and the service
reads without waiting (`headctl.service.servo_io.process`), laid out as float64 values in shared
memory under a sequence lock.

Layout: the head's fields (`HEAD_FIELDS`), then per joint `JOINT_FIELDS`, then, on a simulated
bus, the trace of the servos' true motion (`drivers.sim.servos.JointTrace`'s rows), from which
the simulated cameras render a frame's exposure. A simulated joint's `true_position` is its
servo's output (what the cameras see) and `controller_position` where the servo's controller
holds, both in the joint frame: its `AxisState`, from which a restarted child rebuilds the servo
(`write_true_axis`, `read_true_axes`).
"""
from __future__ import annotations

import ctypes
import multiprocessing
import time

import numpy as np

from drivers.servo.joints import JOINTS
from drivers.sim.servo_motion import TRACE_SAMPLES, TRACE_WIDTH, AxisState

HEAD_FIELDS = ("seq", "state_seq", "time_s", "last_read_s", "last_cycle_s", "cycles", "overruns", "long_periods",
               "read_errors", "write_errors", "bus_down_count", "down", "torque_enabled", "alive", "has_state", "power_losses")
JOINT_FIELDS = ("position", "velocity", "moving", "torque_on", "hardware_error_bits", "temperature_c",
                "input_voltage_v", "goal", "true_position", "controller_position", "missing")
_H = {name: i for i, name in enumerate(HEAD_FIELDS)}
_J = {name: i for i, name in enumerate(JOINT_FIELDS)}
TRACE_BASE = len(HEAD_FIELDS) + len(JOINTS) * len(JOINT_FIELDS)
SIZE = TRACE_BASE + TRACE_SAMPLES * TRACE_WIDTH
# The loop's counters in the block, by their `ServoLoop` attribute names.
COUNTERS = ("cycles", "overruns", "long_periods", "read_errors", "write_errors", "bus_down_count", "power_losses")
HISTORY = 6000  # periods in the ring beside the block, for the quantiles (as ServoLoop keeps them)


# A block of shared doubles (multiprocessing RawArray("d", n)), as the child is handed it.
DoubleArray = ctypes.Array[ctypes.c_double]


def _joint_base(j: int) -> int:
    """Where joint `j`'s fields start in the block."""
    return len(HEAD_FIELDS) + j * len(JOINT_FIELDS)


def write_true_axis(values: np.ndarray, j: int, state: AxisState) -> None:
    """Joint `j`'s simulated servo into the block's `values` (joint frame)."""
    base = _joint_base(j)
    values[base + _J["true_position"]] = state.output
    values[base + _J["controller_position"]] = state.position


def read_true_axes(values: np.ndarray) -> dict[str, AxisState] | None:
    """Each joint's simulated servo as the block's `values` have it; None unless all are known
    (a child that never published them)."""
    axes = {}
    for j, joint in enumerate(JOINTS):
        base = _joint_base(j)
        output, position = values[base + _J["true_position"]], values[base + _J["controller_position"]]
        if not (np.isfinite(output) and np.isfinite(position)):
            return None
        axes[joint] = AxisState(float(position), float(output))
    return axes


class SharedState:
    """The state block: float64 values in shared memory under a sequence lock (the writer makes
    `seq` odd while it writes; a reader retries until it copied the block between two equal,
    even values of `seq`). One writer (the child), any number of readers."""

    def __init__(self, raw: ctypes.Array[ctypes.c_double]) -> None:
        self.raw = raw
        self.values = np.frombuffer(memoryview(raw), dtype=np.float64)

    @classmethod
    def create(cls, size: int = SIZE) -> "SharedState":
        raw = multiprocessing.get_context("spawn").RawArray("d", size)
        block = cls(raw)
        block.values[:] = np.nan
        block.values[_H["seq"]] = 0.0
        return block

    def write(self, values: np.ndarray) -> None:
        seq = self.values[0]
        self.values[0] = seq + 1.0
        self.values[1:] = values[1:]
        self.values[0] = seq + 2.0

    def read(self) -> np.ndarray:
        while True:
            before = self.values[0]
            copy = self.values.copy()
            if before % 2 == 0 and self.values[0] == before:
                return copy
            time.sleep(0)
