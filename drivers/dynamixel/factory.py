"""The `dynamixel` backend: the Protocol 2.0 or the Protocol 1.0 bus, by `servo_bus.protocol`.

The backend table (`drivers.backends`) names `dynamixel_bus_class` for `dynamixel`: it picks
the class a config is checked against and built with. `create_dynamixel_bus` builds one
directly. A config may also name either class as `package.module:Class`
(`drivers.dynamixel.bus_v2:DynamixelBus`, `drivers.dynamixel.bus_v1:Protocol1Bus`); each
drives its own protocol only.
"""
from __future__ import annotations

from drivers.clock import SYSTEM_CLOCK, Clock
from drivers.dynamixel.bus_base import DynamixelBusBase
from drivers.dynamixel.bus_v1 import Protocol1Bus
from drivers.dynamixel.bus_v2 import DynamixelBus
from drivers.servo.config import ServoBusConfig

BUS_CLASSES: dict[float, type[DynamixelBusBase]] = {DynamixelBus.PROTOCOL: DynamixelBus,
                                                    Protocol1Bus.PROTOCOL: Protocol1Bus}


def dynamixel_bus_class(config: ServoBusConfig) -> type[DynamixelBusBase]:
    """The bus class for `config.protocol` (the config reader allows 2.0 and 1.0 only)."""
    return BUS_CLASSES[config.protocol]


def create_dynamixel_bus(config: ServoBusConfig, *, clock: Clock = SYSTEM_CLOCK, name: str | None = None,
                         fast_sync_read: bool = True) -> DynamixelBusBase:
    """The bus for `config.protocol`, not yet opened; `fast_sync_read` as `DynamixelBus` takes it
    (Protocol 1.0 has no Sync Read)."""
    bus_class = dynamixel_bus_class(config)
    if issubclass(bus_class, DynamixelBus):
        return bus_class(config, clock=clock, name=name, fast_sync_read=fast_sync_read)
    return bus_class(config, clock=clock, name=name)
