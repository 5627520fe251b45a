"""Test rigs for the servo-bus contract suite: one servo bus plus the means to drive time
and inject faults, for each backend (simulated, Dynamixel through the real SDK against the
emulator in Protocol 2.0 and in Protocol 1.0 with MX-28s (Bulk Read) or AX-12As (per-servo
reads), and a real bus for `-m hardware`).

A rig says its servos' resolution (`tick_deg`), so that one contract holds for all of them.

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
from drivers.dynamixel.tables.x_series import DEG_PER_TICK, XAddr, ticks_to_deg
from drivers.dynamixel.tables.v1 import P1_MODELS, P1Addr
from drivers.dynamixel.emulator.server import DEFAULT_MODELS, DxlEmulator
from drivers.dynamixel.factory import create_dynamixel_bus
from drivers.servo.bus import JOINTS
from drivers.servo.config import ServoBusConfig
from drivers.sim.servos import SimulatedServoBus

IDS = {"pan": 1, "tilt": 2, "left_eye": 3, "right_eye": 4}


def config_mapping(port: str = "/dev/null", backend: str = "sim", joints: dict[str, dict] | None = None,
                   joint_defaults: dict[str, Any] | None = None, **bus: Any) -> dict:
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
    for joint_data in data["joints"].values():
        joint_data.update(joint_defaults or {})
    for joint, overrides in (joints or {}).items():
        data["joints"][joint].update(overrides)
    return data


class SimRig:
    kind = "sim"
    injects_faults = True
    tick_deg = DEG_PER_TICK

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

    def remove_servo(self, joint: str) -> None:
        self.bus.remove_servo(joint)

    def add_servo(self, joint: str) -> None:
        self.bus.add_servo(joint)

    def bus_down(self) -> None:
        self.bus.inject_bus_down()

    def bus_up(self) -> None:
        self.bus.restore_bus()

    def close(self) -> None:
        self.bus.close()


class EmulatorRig:
    """The Dynamixel backend through the real SDK against the emulator: Protocol 2.0
    X-series servos (`model` the emulated one; the config says XM430-W350), or with
    `protocol=1.0` servos of `model` (AX-12A by default; the config names it too)."""

    injects_faults = True

    def __init__(self, tmp_path, *, model: str | None = None, protocol: float = 2.0,
                 firmware: int | dict[int, int] | None = None, fast_sync_read: bool = True, **config: Any) -> None:
        self.protocol = protocol
        self.clock = ManualClock(100.0)
        self.link = str(tmp_path / "head-servos")
        model = model or DEFAULT_MODELS[protocol]
        self.kind = "dynamixel-emulator" if protocol == 2.0 else f"dynamixel-1.0-emulator ({model})"
        self.p1_model = P1_MODELS.get(model) if protocol == 1.0 else None
        self.emulator = DxlEmulator(IDS.values(), protocol=protocol, model=model, firmware=firmware,
                                    clock=self.clock, link=self.link).start()
        defaults: dict[str, Any] = {}
        if self.p1_model is not None:
            config["protocol"] = 1.0
            defaults["model"] = model
            if not self.p1_model.goal_acceleration:
                defaults["profile_acceleration"] = 0
        self.tick_deg = self.p1_model.deg_per_tick if self.p1_model else DEG_PER_TICK
        self.config = ServoBusConfig.from_mapping(config_mapping(port=self.link, backend="dynamixel",
                                                                 joint_defaults=defaults, **config))
        self.bus = create_dynamixel_bus(self.config, clock=self.clock, fast_sync_read=fast_sync_read)

    def advance(self, seconds: float) -> None:
        self.emulator.wait_idle()
        self.clock.advance(seconds)

    def servo_angle(self, joint: str) -> float:
        self.emulator.wait_idle()
        servo = self.emulator.servo(IDS[joint])
        if self.p1_model is not None:
            return self.p1_model.ticks_to_deg(servo.get(P1Addr.PRESENT_POSITION, 2))
        return ticks_to_deg(servo.get(XAddr.PRESENT_POSITION, 4, signed=True))

    def torque_on(self, joint: str) -> bool:
        self.emulator.wait_idle()
        return bool(self.emulator.servo(IDS[joint]).torque_on)

    def set_stale_goal(self, joint: str, servo_deg: float) -> None:
        servo = self.emulator.servo(IDS[joint])
        if self.p1_model is not None:
            servo.table[P1Addr.GOAL_POSITION:P1Addr.GOAL_POSITION + 2] = \
                self.p1_model.deg_to_ticks(servo_deg).to_bytes(2, "little")
            return
        servo.table[XAddr.GOAL_POSITION:XAddr.GOAL_POSITION + 4] = (2048 + round(servo_deg / DEG_PER_TICK)).to_bytes(4, "little")

    def hardware_error(self, joint: str, bits: int) -> None:
        self.emulator.set_hardware_error(IDS[joint], bits)

    def remove_servo(self, joint: str) -> None:
        self.emulator.remove_servo(IDS[joint])

    def add_servo(self, joint: str) -> None:
        self.emulator.add_servo(IDS[joint])

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
        self.bus = create_dynamixel_bus(self.config, clock=self.clock)
        model = P1_MODELS.get(self.config.joints["pan"].model)
        self.tick_deg = model.deg_per_tick if model else DEG_PER_TICK

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
    if kind == "dynamixel-1.0-mx28-emulator":
        return EmulatorRig(tmp_path, protocol=1.0, model="MX-28", **config)
    if kind == "dynamixel-1.0-ax12a-emulator":
        return EmulatorRig(tmp_path, protocol=1.0, model="AX-12A", **config)
    if kind == "hardware":
        return HardwareRig(**config)
    raise ValueError(kind)


__all__ = ["IDS", "JOINTS", "EmulatorRig", "HardwareRig", "SimRig", "config_mapping", "make_rig"]
