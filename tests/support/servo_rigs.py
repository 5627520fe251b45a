"""Test rigs for the servo-bus contract suite: one servo bus plus the means to drive time
and inject faults, for each backend (simulated, Dynamixel through the real SDK against the
emulator, and a real bus for `-m hardware`).

Time: the sim and emulator rigs run on a ManualClock. A sync write has no reply, so the
emulator may not have handled it yet when a call returns: `advance()` first waits until
the emulator has handled every byte sent, then moves the clock.
"""
from __future__ import annotations

import copy
import os
import time
from typing import Any

try:
    import dynamixel_sdk  # noqa: F401  (imported here so a missing SDK fails loudly)
    import yaml
except ImportError as err:  # no silent skips: name the install step
    raise ImportError(f"{err}: run ./setup.sh (pip install -e '.[test]' installs dynamixel-sdk and pyyaml)") from err

from drivers.clock import ManualClock, MonotonicClock
from drivers.dxl_control_table import DEG_PER_TICK, XAddr, ticks_to_deg
from drivers.dxl_emulator import DxlEmulator
from drivers.dynamixel import DynamixelBus
from drivers.servo_bus import JOINTS
from drivers.servo_config import ServoBusConfig
from drivers.sim_servo import SimulatedServoBus

IDS = {"pan": 1, "tilt": 2, "left_eye": 3, "right_eye": 4}


def config_mapping(port: str = "/dev/null", backend: str = "sim", joints: dict[str, dict] | None = None,
                   **bus: Any) -> dict:
    """A plain servo_bus mapping, as YAML would give it, with per-joint overrides."""
    data: dict[str, Any] = {
        "backend": backend,
        "port": port,
        # Generous for a Python emulator on a loaded 2-core CI machine; real adapters with
        # the udev rule answer within 1 ms.
        "latency_timer_ms": 8,
        "retries": 2,
        "joints": {
            joint: {"id": servo_id, "min_angle": -90, "max_angle": 90, "profile_velocity": 100,
                    "profile_acceleration": 1000}
            for joint, servo_id in IDS.items()
        },
    }
    data.update(bus)
    for joint, overrides in (joints or {}).items():
        data["joints"][joint].update(overrides)
    return data


class SimRig:
    kind = "sim"
    injects_faults = True

    def __init__(self, **config: Any) -> None:
        self.clock = ManualClock(100.0)
        self.config = ServoBusConfig.from_mapping(config_mapping(**config))
        self.bus = SimulatedServoBus(self.config, clock=self.clock)

    def advance(self, seconds: float) -> None:
        self.clock.advance(seconds)

    def servo_angle(self, joint: str) -> float:
        return self.config.joints[joint].servo_angle(self.bus.true_position(joint))

    def torque_on(self, joint: str) -> bool:
        return self.bus._servos[joint].torque_on

    def set_stale_goal(self, joint: str, servo_deg: float) -> None:
        self.bus._servos[joint].goal_deg = servo_deg

    def hardware_error(self, joint: str, bits: int) -> None:
        self.bus.inject_hardware_error(joint, bits)

    def bus_down(self) -> None:
        self.bus.inject_bus_down()

    def bus_up(self) -> None:
        self.bus.restore_bus()

    def close(self) -> None:
        self.bus.close()


class EmulatorRig:
    kind = "dynamixel-emulator"
    injects_faults = True

    def __init__(self, tmp_path, *, model: str = "XM430-W350", **config: Any) -> None:
        self.clock = ManualClock(100.0)
        self.link = str(tmp_path / "head-servos")
        self.emulator = DxlEmulator(IDS.values(), model=model, clock=self.clock, link=self.link).start()
        self.config = ServoBusConfig.from_mapping(config_mapping(port=self.link, backend="dynamixel", **config))
        self.bus = DynamixelBus(self.config, clock=self.clock)

    def advance(self, seconds: float) -> None:
        self.emulator.wait_idle()
        self.clock.advance(seconds)

    def servo_angle(self, joint: str) -> float:
        self.emulator.wait_idle()
        return ticks_to_deg(self.emulator.servo(IDS[joint]).get(XAddr.PRESENT_POSITION, 4, signed=True))

    def torque_on(self, joint: str) -> bool:
        self.emulator.wait_idle()
        return self.emulator.servo(IDS[joint]).torque_on

    def set_stale_goal(self, joint: str, servo_deg: float) -> None:
        servo = self.emulator.servo(IDS[joint])
        servo.table[XAddr.GOAL_POSITION:XAddr.GOAL_POSITION + 4] = (2048 + round(servo_deg / DEG_PER_TICK)).to_bytes(4, "little")

    def hardware_error(self, joint: str, bits: int) -> None:
        self.emulator.set_hardware_error(IDS[joint], bits)

    def bus_down(self) -> None:
        self.emulator.vanish()

    def bus_up(self) -> None:
        self.emulator.reappear()

    def close(self) -> None:
        try:
            self.bus.close()
        finally:
            self.emulator.stop()


class HardwareRig:
    """A real head: the config file named by HEADCTL_HW_CONFIG (its `servo_bus` section)."""

    kind = "hardware"
    injects_faults = False

    def __init__(self, **overrides: Any) -> None:
        path = os.environ.get("HEADCTL_HW_CONFIG")
        if not path:
            raise RuntimeError("hardware tests need HEADCTL_HW_CONFIG=path/to/head.yaml (with a servo_bus section)")
        with open(path, encoding="utf-8") as f:
            data = yaml.safe_load(f)
        section = copy.deepcopy(data.get("servo_bus", data))
        joint_overrides = overrides.pop("joints", {})
        section.update(overrides)
        for joint, values in joint_overrides.items():
            section["joints"][joint].update(values)
        self.clock = MonotonicClock()
        self.config = ServoBusConfig.from_mapping(section)
        self.bus = DynamixelBus(self.config, clock=self.clock)

    def advance(self, seconds: float) -> None:
        time.sleep(seconds)

    def servo_angle(self, joint: str) -> float:
        return self.config.joints[joint].servo_angle(self.bus.read_state()[joint].position)

    def torque_on(self, joint: str) -> bool:
        return self.bus.read_state()[joint].torque_on

    def close(self) -> None:
        self.bus.close()


def make_rig(kind: str, tmp_path, **config: Any):
    if kind == "sim":
        return SimRig(**config)
    if kind == "dynamixel-emulator":
        return EmulatorRig(tmp_path, **config)
    if kind == "hardware":
        return HardwareRig(**config)
    raise ValueError(kind)


__all__ = ["IDS", "JOINTS", "EmulatorRig", "HardwareRig", "SimRig", "config_mapping", "make_rig"]
