"""The Dynamixel backend on Protocol 1.0: AX, RX and MX servos through dynamixel-sdk 4.1.0.

`Protocol1Bus` is what the `dynamixel` backend builds for a config with `protocol: 1.0`
(`drivers.dynamixel.factory`); it shares the port, the transactions with retries and the
per-servo blame of failed group reads with the Protocol 2.0 bus (`drivers.dynamixel.bus_base`),
and drives the control table of `drivers.dynamixel.tables.v1`.

Protocol 1.0 has no Sync Read, so every cycle reads each servo's block (Torque Enable up
to Moving, 23 bytes) either with one Bulk Read, when every servo is an MX (which the SDK's
`GroupBulkRead` cannot send on Protocol 1.0: `drivers.dynamixel.sdk.BulkRead1`), or with one
Read per servo, each with its own retries. Goals go out in one Sync Write.

Hardware errors: a Protocol 1.0 servo reports input voltage, overheating and overload in
the error byte of every status packet, on the bits where the X-series Hardware Error
Status has them, so they reach the bus's fault flow (recovery, fault log) unchanged; the
other bits of the byte mean a refused instruction. An error in the servo's Alarm Shutdown
mask turns its torque off and its Torque Limit to 0; these servos have no Reboot
instruction, so "reboot" here writes Torque Limit back to Max Torque, which is how they
leave shutdown. A servo that lost power comes back with its RAM settings (Moving Speed,
Goal Acceleration) at their defaults: the bus sees Moving Speed differ from what it wrote
and configures the servo again. There is no bus watchdog.
"""
from __future__ import annotations

import dataclasses
import logging
import struct
from collections.abc import Iterable, Mapping
from typing import Any

from dynamixel_sdk import COMM_RX_CORRUPT, COMM_SUCCESS, GroupSyncWrite

from drivers.clock import SYSTEM_CLOCK, Clock
from drivers.dynamixel.tables.v1 import (
    DPS2_PER_ACCELERATION_UNIT,
    HARDWARE_ERROR_BITS,
    MAX_GOAL_ACCELERATION,
    P1_BAUD_CODES,
    P1_MODELS,
    READ_SIZE,
    READ_START,
    US_PER_RETURN_DELAY_UNIT,
    VOLTS_PER_VOLTAGE_UNIT,
    P1Addr,
    P1Block,
    P1Model,
)
from drivers.dynamixel.sdk import BlockingPortHandler, BulkRead1
from drivers.dynamixel.bus_base import DynamixelBusBase
from drivers.errors import ServoCommError, ServoConfigError, ServoHardwareError
from drivers.servo.bus import JointState, ServoBusConfig
from drivers.servo.joints import JOINTS

log = logging.getLogger(__name__)


def acceleration_units(dps2: float) -> int:
    """deg/s^2 -> Goal Acceleration (0 stays 0: no acceleration control)."""
    return 0 if dps2 <= 0 else min(max(round(dps2 / DPS2_PER_ACCELERATION_UNIT), 1), MAX_GOAL_ACCELERATION)


def check_protocol1_config(config: ServoBusConfig) -> None:
    """Refuse what Protocol 1.0 servos cannot do, naming the key: models of the other
    protocol, a bus watchdog, baud rates they do not offer, joint limits beyond the
    model's range, speeds and accelerations beyond its registers."""
    if config.watchdog_ms:
        raise ServoConfigError(f"{config.key_path}.watchdog_ms: got {config.watchdog_ms}, expected 0: Protocol 1.0 "
                               "servos have no bus watchdog")
    if config.baud not in P1_BAUD_CODES:
        raise ServoConfigError(f"{config.key_path}.baud: got {config.baud}, expected one of "
                               f"{', '.join(map(str, P1_BAUD_CODES))} on Protocol 1.0")
    for joint, jc in config.joints.items():
        path = config.joint_path(joint)
        model = P1_MODELS.get(jc.model)
        if model is None:
            raise ServoConfigError(f"{path}.model: got {jc.model!r}, expected one of {', '.join(P1_MODELS)} "
                                   "(Protocol 1.0; X-series servos need protocol: 2.0)")
        for key, angle in (("min_angle", jc.min_angle), ("max_angle", jc.max_angle)):
            servo_deg = jc.servo_angle(angle)
            if not -model.center_tick * model.deg_per_tick <= servo_deg <= model.half_range_deg:
                raise ServoConfigError(
                    f"{path}.{key}: got {angle:g}, expected an angle whose servo angle (zero_offset + direction "
                    f"* angle = {servo_deg:g}) lies within the {model.name}'s range "
                    f"[{-model.center_tick * model.deg_per_tick:g}, {model.half_range_deg:.4g}]")
        if jc.profile_velocity > model.max_speed_dps:
            raise ServoConfigError(f"{path}.profile_velocity: got {jc.profile_velocity:g}, expected at most "
                                   f"{model.max_speed_dps:.4g} deg/s (the {model.name}'s Moving Speed), or 0")
        if model.goal_acceleration:
            top = MAX_GOAL_ACCELERATION * DPS2_PER_ACCELERATION_UNIT
            if jc.profile_acceleration > top:
                raise ServoConfigError(f"{path}.profile_acceleration: got {jc.profile_acceleration:g}, expected at "
                                       f"most {top:.4g} deg/s^2 (the {model.name}'s Goal Acceleration), or 0")
        elif jc.profile_acceleration and "profile_acceleration" in jc.given_keys:
            raise ServoConfigError(f"{path}.profile_acceleration: got {jc.profile_acceleration:g}, expected 0 (or "
                                   f"no key): the {model.name} has no acceleration control")


class Protocol1Bus(DynamixelBusBase):
    """Four Protocol 1.0 servos on one port; see the module docstring. `read_method` says
    how the state is read: "bulk read" or "per-servo reads"."""

    capabilities = frozenset({"reboot", "hardware_error", "temperature", "input_voltage"})
    PROTOCOL = 1.0
    FIRMWARE_ADDRESS = P1Addr.FIRMWARE_VERSION
    STATUS_HARDWARE_BITS = HARDWARE_ERROR_BITS

    def __init__(self, config: ServoBusConfig, *, clock: Clock = SYSTEM_CLOCK, name: str | None = None,
                 fast_sync_read: bool = False) -> None:
        super().__init__(config, clock=clock, name=name)
        self._models: dict[str, P1Model] = {j: P1_MODELS[config.joints[j].model] for j in JOINTS}
        self._bulk_read: BulkRead1 | None = None
        self.read_method = "bulk read" if self._all_bulk_read else "per-servo reads"

    @property
    def _all_bulk_read(self) -> bool:
        return all(model.bulk_read for model in self._models.values())

    @classmethod
    def _check_protocol_config(cls, config: ServoBusConfig) -> None:
        check_protocol1_config(config)

    def _model_number(self, name: str) -> int:
        return P1_MODELS[name].number

    def _setup_group_transactions(self, port: BlockingPortHandler) -> None:
        if self._all_bulk_read:
            self._bulk_read = BulkRead1(port, self._packet, [(servo_id, READ_START, READ_SIZE)
                                                             for servo_id in self._present_ids.values()])
        log.debug("%s: reading state by %s", self.name, self.read_method)
        self._sync_write = GroupSyncWrite(port, self._packet, P1Addr.GOAL_POSITION, 2)

    def _disconnect(self) -> None:
        self._bulk_read = None
        super()._disconnect()

    # -- state ---------------------------------------------------------------------------
    def _read_servos(self) -> dict[str, JointState]:
        blocks = self._read_blocks()
        stale = [j for j, (block, _error) in blocks.items() if block.moving_speed != self._moving_speed(j)]
        if stale:
            # RAM back at its defaults: the servo lost power. Configure it again, read again.
            for joint in stale:
                log.warning("%s: Moving Speed is not what was written (servo power cycled?); configuring it again",
                            self.describe(joint))
                self._configure_servo(joint)
            blocks = self._read_blocks()
            bad = [j for j, (block, _e) in blocks.items() if block.moving_speed != self._moving_speed(j)]
            if bad:
                raise ServoCommError(f"{self.describe(bad[0])}: Moving Speed still not as configured after "
                                     "configuring it again")
        # `ServoBus` initialises the stale ones again (goals := present, torque as its policy says).
        return {joint: dataclasses.replace(self._joint_state(joint, block, error), power_cycled=joint in stale)
                for joint, (block, error) in blocks.items()}

    def _read_blocks(self) -> dict[str, tuple[P1Block, int]]:
        """Every servo's read block and status error byte: one Bulk Read, or a Read each."""
        if self._bulk_read is not None:
            group = self._group_read(self._bulk_read, self._bulk_read, "bulk read")
            return {joint: (P1Block.unpack(bytes(group.data_dict[servo_id])), group.errors.get(servo_id, 0))
                    for joint, servo_id in self._present_ids.items()}
        blocks: dict[str, tuple[P1Block, int]] = {}
        for joint, servo_id in self._present_ids.items():
            def read(servo_id: int = servo_id) -> tuple[Any, int, int]:
                data, result, error = self._packet.readTxRx(self._port, servo_id, READ_START, READ_SIZE)
                if result == COMM_SUCCESS and len(data) != READ_SIZE:
                    result = COMM_RX_CORRUPT  # a stray reply of another request: try again
                return data, result, error

            data, error = self._transact(joint, f"state read ({READ_SIZE} bytes at address {READ_START})", read)
            blocks[joint] = (P1Block.unpack(bytes(data)), error)
        return blocks

    def _joint_state(self, joint: str, block: P1Block, error: int) -> JointState:
        model = self._models[joint]
        return JointState(
            position=model.ticks_to_deg(block.present_position),
            velocity=model.speed_dps(block.present_speed),
            moving=bool(block.moving),
            torque_on=bool(block.torque_enable) and block.torque_limit > 0,
            hardware_error_bits=error & HARDWARE_ERROR_BITS,
            temperature_c=float(block.temperature),
            input_voltage_v=block.voltage * VOLTS_PER_VOLTAGE_UNIT,
        )

    # -- commands ------------------------------------------------------------------------
    def _write_servo_goals(self, goals_deg: Mapping[str, float]) -> None:
        sync_write = self._require(self._sync_write)
        sync_write.clearParam()
        for joint, servo_deg in goals_deg.items():
            sync_write.addParam(self._ids[joint], list(struct.pack("<H", self._models[joint].deg_to_ticks(servo_deg))))
        self._send_sync_write(sync_write)

    def _set_torque(self, joints: Iterable[str], on: bool) -> None:
        for joint in joints:
            error = self._write(joint, P1Addr.TORQUE_ENABLE, 1, 1 if on else 0)
            if on and error & HARDWARE_ERROR_BITS:
                block = P1Block.unpack(self._read_bytes(joint, READ_START, READ_SIZE))
                if not (block.torque_enable and block.torque_limit):
                    # In shutdown: the servo took the write and stays limp.
                    bits = error & HARDWARE_ERROR_BITS
                    raise ServoHardwareError(f"{self.describe(joint)}: torque refused, hardware error 0x{bits:02x}: "
                                             + "; ".join(self.decode_hardware_error(bits)))

    def _reboot_servo(self, joint: str) -> None:
        """Take the servo out of shutdown: Torque Limit back to Max Torque (no Reboot on 1.0)."""
        max_torque = self._read(joint, P1Addr.MAX_TORQUE, 2)
        self._write(joint, P1Addr.TORQUE_LIMIT, 2, max_torque)

    # -- setup ---------------------------------------------------------------------------
    def _moving_speed(self, joint: str) -> int:
        return self._models[joint].speed_units(self.config.joints[joint].profile_velocity)

    def _configure_servo(self, joint: str) -> None:
        """Apply the joint's settings, writing EEPROM only where it differs."""
        jc, model = self.config.joints[joint], self._models[joint]
        cw, ccw = sorted(model.deg_to_ticks(jc.servo_angle(a)) for a in (jc.min_angle, jc.max_angle))
        wanted = [
            (P1Addr.RETURN_DELAY_TIME, 1, self.config.return_delay_us // US_PER_RETURN_DELAY_UNIT),
            (P1Addr.CW_ANGLE_LIMIT, 2, cw),
            (P1Addr.CCW_ANGLE_LIMIT, 2, ccw),
        ]
        eeprom = self._read_bytes(joint, 0, P1Addr.EEPROM_END)
        for addr, size, value in wanted:
            if int.from_bytes(eeprom[addr: addr + size], "little") != value:
                log.debug("%s: address %d := %d", self.describe(joint), addr, value)
                self._write(joint, addr, size, value)
        if model.goal_acceleration:
            self._write(joint, P1Addr.GOAL_ACCELERATION, 1, acceleration_units(jc.profile_acceleration))
        self._write(joint, P1Addr.MOVING_SPEED, 2, self._moving_speed(joint))
