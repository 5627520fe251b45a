"""The `dynamixel` backend of `drivers.servo.probe.ServoProbe`: servos by id through dynamixel-sdk.

A scan tries every baud rate dynamixel-sdk offers (`SUPPORTED_BAUDS`) in both protocols:
Protocol 2.0 with one broadcast ping per baud, Protocol 1.0 (which has no broadcast ping
reply) with a ping per id. Each servo found is then spoken to at its own baud rate and
protocol, one `PortHandler` per baud rate (`drivers.dynamixel.sdk.BlockingPortHandler`, which
blocks on the monotonic clock), one `PacketHandler` per protocol.

Control tables: X-series servos on Protocol 2.0 (`drivers.dynamixel.tables.x_series`) and, on
Protocol 1.0, the AX (1024 ticks over 300 deg) and MX (4096 ticks over 360 deg) series.
How each move is made safe (`MotionSafety`):

* torque: X-series Goal PWM (100, RAM: it caps the motor's PWM in every operating mode, as a
  fraction of the servo's own PWM Limit; no EEPROM write, so torque never goes off, and a
  neck under load never drops); AX/MX Torque Limit (34, RAM);
* velocity and acceleration: X-series Profile Velocity and Profile Acceleration; AX/MX
  Moving Speed (no acceleration limit on Protocol 1.0);
* timeout: the X-series Bus Watchdog, armed while the servo moves, disarmed at rest (a
  fired watchdog blocks goals until cleared); Protocol 1.0 servos have none, so only the
  host's deadline per move applies.
"""
from __future__ import annotations

import logging
from collections.abc import Callable, Iterable, Sequence
from typing import Any

from dynamixel_sdk import COMM_SUCCESS, PacketHandler

from drivers.clock import SYSTEM_CLOCK, Clock
from drivers.dynamixel.tables.v1 import P1_MODEL_NAMES, P1_MODELS, P1Addr, P1Model
from drivers.dynamixel.tables.x_series import (
    DEG_PER_TICK,
    DPS2_PER_ACCELERATION_UNIT,
    DPS_PER_VELOCITY_UNIT,
    KNOWN_MODEL_NAMES,
    MS_PER_WATCHDOG_UNIT,
    VOLTS_PER_VOLTAGE_UNIT,
    XAddr,
    ticks_to_deg,
)
from drivers.dynamixel.protocol.v2 import ERRBIT_ALERT
from drivers.dynamixel.scan import REPLY_SLACK_MS, ping_servos
from drivers.dynamixel.sdk import PORT_ERRORS, BlockingPortHandler, port_access_hint
from drivers.errors import JointLimitError, ServoCommError, ServoError, ServoTimeoutError
from drivers.servo.config import SUPPORTED_BAUDS, ServoBusConfig
from drivers.servo.probe import FoundServo, MotionSafety, ServoStatus

log = logging.getLogger(__name__)

PROTOCOLS = (2.0, 1.0)


# Protocol 1.0 status error bits that are hardware errors (input voltage, overheating, overload),
# mapped onto the X-series Hardware Error Status bits `drivers.servo.bus` decodes.
_ERR1_TO_X = {0x01: 0x01, 0x04: 0x04, 0x20: 0x20}


class DynamixelProbe:
    """Servos by id on one port; see the module docstring. `bauds` and `protocols` narrow
    what a scan tries (default: all), `ids` the ids a Protocol 1.0 scan pings."""

    def __init__(self, config: ServoBusConfig, *, clock: Clock = SYSTEM_CLOCK, ids: Sequence[int] | None = None,
                 bauds: Iterable[int] | None = None, protocols: Iterable[float] | None = None) -> None:
        self.config = config
        self.clock = clock
        self.name = config.port
        self.ids = list(ids) if ids is not None else list(range(253))
        self.bauds = list(bauds) if bauds is not None else list(SUPPORTED_BAUDS)
        self.protocols = list(protocols) if protocols is not None else list(PROTOCOLS)
        self._port: BlockingPortHandler | None = None
        self._packets = {p: PacketHandler(p) for p in PROTOCOLS}
        self._found: dict[int, FoundServo] = {}
        self._saved: dict[int, dict[int, tuple[int, int]]] = {}  # id -> address -> (size, value)
        self._watchdog_units: dict[int, int] = {}  # id -> Bus Watchdog (20 ms units) armed by each move

    # -- the port ------------------------------------------------------------------------
    def _at(self, baud: int) -> BlockingPortHandler:
        port = self._port
        if port is None:
            port = self._port = BlockingPortHandler(self.config.port, self.config.latency_timer_ms, REPLY_SLACK_MS)
        if port.ser is None or port.getBaudRate() != baud:
            try:
                opened = port.setBaudRate(baud)
            except PORT_ERRORS as err:
                raise ServoCommError(port_access_hint(self.config.port, err)) from err
            if not opened:
                raise ServoCommError(f"{self.name}: dynamixel-sdk refused {baud} baud")
        return port

    def close(self) -> None:
        port, self._port = self._port, None
        if port is not None and port.ser is not None:
            try:
                port.closePort()
            except PORT_ERRORS as err:
                log.debug("%s: closing the port failed: %s", self.name, err)

    def __enter__(self) -> "DynamixelProbe":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- scanning --------------------------------------------------------------------------
    def scan(self) -> list[FoundServo]:
        found: dict[int, FoundServo] = {}
        for protocol in self.protocols:
            packet = self._packets[protocol]
            for baud in self.bauds:
                port = self._at(baud)
                log.info("%s: scanning at %d baud, protocol %.1f", self.name, baud, protocol)
                try:
                    hits = [(r.servo_id, r.model_number, r.firmware)
                            for r in ping_servos(port, packet, protocol, self.ids, baud)]
                except PORT_ERRORS as err:
                    raise ServoCommError(f"{self.name}: the port failed during the scan: {err}") from err
                for servo_id, model, fw in hits:
                    if servo_id in found:
                        log.warning("%s: id %d answers at %d baud protocol %.1f too; keeping the first",
                                    self.name, servo_id, baud, protocol)
                        continue
                    name = (P1_MODEL_NAMES if protocol == 1.0 else KNOWN_MODEL_NAMES).get(model, f"model {model}")
                    found[servo_id] = FoundServo(servo_id, model, name, fw, protocol, baud)
        self._found = found
        return [found[i] for i in sorted(found)]

    # -- one servo -------------------------------------------------------------------------
    def _servo(self, servo_id: int) -> FoundServo:
        found = self._found.get(servo_id)
        if found is None:
            raise ServoError(f"id {servo_id} on {self.name}: not found by the scan")
        return found

    def _table1(self, servo: FoundServo) -> P1Model:
        table = P1_MODELS.get(P1_MODEL_NAMES.get(servo.model_number, ""))
        if table is None:
            raise ServoError(f"id {servo.servo_id} on {self.name}: Protocol 1.0 model {servo.model_number} is not "
                             f"one headctl setup knows ({', '.join(P1_MODELS)})")
        return table

    def _transact(self, servo_id: int, what: str, call: Callable[[Any, Any], tuple[Any, int, int]]) -> tuple[Any, int]:
        servo = self._servo(servo_id)
        port, packet = self._at(servo.baud), self._packets[servo.protocol]
        result = COMM_SUCCESS
        for _attempt in range(self.config.retries + 1):
            try:
                value, result, error = call(port, packet)
            except PORT_ERRORS as err:
                raise ServoCommError(f"id {servo_id} on {self.name}: port failed during {what}: {err}") from err
            if result != COMM_SUCCESS:
                port.drain_late_replies()
                continue
            refusal = error & ~ERRBIT_ALERT if servo.protocol == 2.0 else error & 0x5A  # angle, range, checksum, instr.
            if refusal:
                raise ServoError(f"id {servo_id} on {self.name}: {what} refused: {packet.getRxPacketError(error)}")
            return value, error
        message = f"id {servo_id} on {self.name}: {what} failed: {self._packets[servo.protocol].getTxRxResult(result)}"
        raise ServoTimeoutError(message)

    def _read(self, servo_id: int, address: int, size: int, signed: bool = False) -> int:
        def call(port: Any, packet: Any) -> tuple[Any, int, int]:
            data, result, error = packet.readTxRx(port, servo_id, address, size)
            return data, result, error

        data, _error = self._transact(servo_id, f"read of {size} byte(s) at {address}", call)
        return int.from_bytes(bytes(data), "little", signed=signed)

    def _write(self, servo_id: int, address: int, size: int, value: int) -> None:
        data = list(int(value).to_bytes(size, "little", signed=value < 0))
        self._transact(servo_id, f"write of {value} to {address}",
                       lambda port, packet: (None, *packet.writeTxRx(port, servo_id, address, size, data)))

    def status(self, servo_id: int) -> ServoStatus:
        servo = self._servo(servo_id)
        if servo.protocol == 1.0:
            table = self._table1(servo)
            _value, error = self._transact(servo_id, "ping", lambda port, packet: packet.ping(port, servo_id))
            bits = sum(x for e, x in _ERR1_TO_X.items() if error & e)
            cw, ccw = self._read(servo_id, P1Addr.CW_ANGLE_LIMIT, 2), self._read(servo_id, P1Addr.CCW_ANGLE_LIMIT, 2)
            return ServoStatus(
                position_deg=table.ticks_to_deg(self._read(servo_id, P1Addr.PRESENT_POSITION, 2)),
                goal_deg=table.ticks_to_deg(self._read(servo_id, P1Addr.GOAL_POSITION, 2)),
                moving=bool(self._read(servo_id, P1Addr.MOVING, 1)), torque_on=bool(self._read(servo_id, P1Addr.TORQUE_ENABLE, 1)),
                hardware_error_bits=bits, temperature_c=float(self._read(servo_id, P1Addr.PRESENT_TEMPERATURE, 1)),
                input_voltage_v=self._read(servo_id, P1Addr.PRESENT_VOLTAGE, 1) * 0.1,
                min_deg=table.ticks_to_deg(cw), max_deg=table.ticks_to_deg(ccw if ccw > cw else table.ticks - 1))
        return ServoStatus(
            position_deg=ticks_to_deg(self._read(servo_id, XAddr.PRESENT_POSITION, 4, signed=True)),
            goal_deg=ticks_to_deg(self._read(servo_id, XAddr.GOAL_POSITION, 4, signed=True)),
            moving=bool(self._read(servo_id, XAddr.MOVING, 1)),
            torque_on=bool(self._read(servo_id, XAddr.TORQUE_ENABLE, 1)),
            hardware_error_bits=self._read(servo_id, XAddr.HARDWARE_ERROR_STATUS, 1),
            temperature_c=float(self._read(servo_id, XAddr.PRESENT_TEMPERATURE, 1)),
            input_voltage_v=self._read(servo_id, XAddr.PRESENT_INPUT_VOLTAGE, 2) * VOLTS_PER_VOLTAGE_UNIT,
            min_deg=ticks_to_deg(self._read(servo_id, XAddr.MIN_POSITION_LIMIT, 4, signed=True)),
            max_deg=ticks_to_deg(self._read(servo_id, XAddr.MAX_POSITION_LIMIT, 4, signed=True)))

    def _set(self, servo_id: int, address: int, size: int, value: int) -> None:
        """Write a setting, remembering its value before the first change (`restore_motion`)."""
        saved = self._saved.setdefault(servo_id, {})
        if address not in saved:
            saved[address] = (size, self._read(servo_id, address, size))
        self._write(servo_id, address, size, value)

    def limit_motion(self, servo_id: int, safety: MotionSafety) -> None:
        servo = self._servo(servo_id)
        if servo.protocol == 1.0:
            table = self._table1(servo)
            self._set(servo_id, P1Addr.TORQUE_LIMIT, 2, max(1, round(safety.torque_fraction * 1023)))
            self._set(servo_id, P1Addr.MOVING_SPEED, 2, max(1, table.speed_units(safety.velocity_dps)))
            return
        pwm_limit = self._read(servo_id, XAddr.PWM_LIMIT, 2)
        self._set(servo_id, XAddr.GOAL_PWM, 2, max(1, round(safety.torque_fraction * pwm_limit)))
        self._set(servo_id, XAddr.PROFILE_VELOCITY, 4, max(1, round(safety.velocity_dps / DPS_PER_VELOCITY_UNIT)))
        self._set(servo_id, XAddr.PROFILE_ACCELERATION, 4,
                  max(1, round(safety.acceleration_dps2 / DPS2_PER_ACCELERATION_UNIT)))
        # Armed by each move (`write_goal`), disarmed at rest (`keep_alive`).
        self._set(servo_id, XAddr.BUS_WATCHDOG, 1, 0)
        self._watchdog_units[servo_id] = max(1, min(127, round(safety.watchdog_s * 1000 / MS_PER_WATCHDOG_UNIT)))

    def restore_motion(self, servo_id: int) -> None:
        self._watchdog_units.pop(servo_id, None)
        saved = self._saved.pop(servo_id, {})
        for address, (size, value) in saved.items():
            if address == XAddr.BUS_WATCHDOG:
                self._write(servo_id, address, size, 0)  # clears a fired watchdog too
            self._write(servo_id, address, size, value)

    def set_torque(self, servo_id: int, on: bool) -> None:
        address = P1Addr.TORQUE_ENABLE if self._servo(servo_id).protocol == 1.0 else XAddr.TORQUE_ENABLE
        self._write(servo_id, address, 1, int(on))

    def write_goal(self, servo_id: int, servo_deg: float) -> None:
        status = self.status(servo_id)
        if not status.min_deg <= servo_deg <= status.max_deg:
            raise JointLimitError(f"id {servo_id} on {self.name}: goal {servo_deg:g} deg outside the servo's own "
                                  f"limits [{status.min_deg:g}, {status.max_deg:g}]; nothing sent")
        servo = self._servo(servo_id)
        if servo.protocol == 1.0:
            self._write(servo_id, P1Addr.GOAL_POSITION, 2, self._table1(servo).deg_to_ticks(servo_deg))
            return
        units = self._watchdog_units.get(servo_id)
        if units:
            self._write(servo_id, XAddr.BUS_WATCHDOG, 1, units)
        self._write(servo_id, XAddr.GOAL_POSITION, 4, round(servo_deg / DEG_PER_TICK) + 2048)

    def keep_alive(self, servo_id: int) -> None:
        if self._watchdog_units.get(servo_id):
            self._write(servo_id, XAddr.BUS_WATCHDOG, 1, 0)
