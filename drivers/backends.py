"""Choosing a backend by name: a table of (module, class), imported only when selected.

A config names a backend either by a short name from the table below, or as
`package.module:Class` for a user's own hardware (no fork needed); installed packages can
also add names through the entry-point groups `headctl.servo_buses` and `headctl.cameras`.
"Unknown backend" and "backend failed to import" are different errors. `resolve_for_config`
gives either as a `ConfigError` naming the config key (`servo_bus.backend`), so that a
config is refused when it is loaded, not when its devices are built.
"""
from __future__ import annotations

import importlib
import inspect
import logging
import re
from importlib import metadata
from typing import Any, Literal

from drivers.errors import BackendImportError, BackendNotFoundError, ConfigError

log = logging.getLogger(__name__)

Kind = Literal["servo_bus", "camera", "servo_probe"]

# name -> (module, class, what to install when the import fails)
SERVO_BUS_BACKENDS: dict[str, tuple[str, str, str]] = {
    "dynamixel": ("drivers.dynamixel.bus_v2", "DynamixelBus", "pip install dynamixel-sdk pyserial"),
    "sim": ("drivers.sim.servos", "SimulatedServoBus", ""),
}
# Servos by id for `headctl setup` (`drivers.servo.probe`), by the same names as the buses.
SERVO_PROBE_BACKENDS: dict[str, tuple[str, str, str]] = {
    "dynamixel": ("drivers.dynamixel.probe", "DynamixelProbe", "pip install dynamixel-sdk pyserial"),
    "sim": ("drivers.sim.servos", "SimulatedServoProbe", ""),
}
CAMERA_BACKENDS: dict[str, tuple[str, str, str]] = {
    "aravis": (
        "drivers.cameras.aravis",
        "AravisCamera",
        "apt-get install gir1.2-aravis-0.8 && pip install 'PyGObject<3.51' (./setup.sh does both)",
    ),
    "opencv": ("drivers.cameras.opencv", "OpenCVCamera", "pip install opencv-python-headless"),
    "sim": ("drivers.sim.camera", "SimulatedCamera", ""),
}
_TABLES = {"servo_bus": SERVO_BUS_BACKENDS, "camera": CAMERA_BACKENDS, "servo_probe": SERVO_PROBE_BACKENDS}
_ENTRY_POINT_GROUPS = {"servo_bus": "headctl.servo_buses", "camera": "headctl.cameras",
                       "servo_probe": "headctl.servo_probes"}
# `package.module:Class`: dotted identifiers, so a name never becomes a relative or empty import.
_MODULE_CLASS = re.compile(r"[A-Za-z_]\w*(\.[A-Za-z_]\w*)*:[A-Za-z_]\w*")


def resolve(kind: Kind, name: str) -> type:
    """The class of backend `name` of device kind `kind` ("servo_bus" or "camera")."""
    table = _TABLES[kind]
    if name in table:
        module_name, class_name, install = table[name]
        return _import(kind, name, module_name, class_name, install)
    if ":" in name:
        if not _MODULE_CLASS.fullmatch(name):
            raise BackendNotFoundError(f"{kind} backend {name!r}: not of the form 'package.module:Class'")
        module_name, _, class_name = name.partition(":")
        return _import(kind, name, module_name, class_name, "")
    for ep in metadata.entry_points(group=_ENTRY_POINT_GROUPS[kind]):
        if ep.name == name:
            try:
                loaded: type = ep.load()
            except Exception as err:  # whatever the plugin's import raises, it did not import
                raise BackendImportError(f"{kind} backend {name!r} (entry point {ep.value}) failed to import: "
                                         f"{err!r}") from err
            return loaded
    known = ", ".join(sorted(table))
    raise BackendNotFoundError(
        f"unknown {kind} backend {name!r}: expected one of {known}, or 'package.module:Class'"
    )


def _import(kind: str, name: str, module_name: str, class_name: str, install: str) -> type:
    try:
        module = importlib.import_module(module_name)
    except ImportError as err:
        hint = f" (install: {install})" if install else ""
        raise BackendImportError(f"{kind} backend {name!r} failed to import {module_name}: {err}{hint}") from err
    except Exception as err:  # a module that raises while it is imported: it did not import
        raise BackendImportError(f"{kind} backend {name!r} failed to import {module_name}: {err!r}") from err
    try:
        cls: type = getattr(module, class_name)
    except AttributeError as err:
        raise BackendNotFoundError(f"{kind} backend {name!r}: module {module_name} has no class {class_name}") from err
    return cls


def resolve_for_config(kind: Kind, name: str, base: type, key_path: str,
                       error: type[ConfigError] = ConfigError) -> type:
    """The class of backend `name`, a subclass of `base`; else `error` naming `key_path`
    (`cameras.left.backend`) with what was wrong: an unknown name, a module that does not
    import, or something that is not a `base`."""
    known = ", ".join(sorted(_TABLES[kind]))
    try:
        cls: Any = resolve(kind, name)
    except BackendNotFoundError as err:
        if ":" in name:  # a module and class named, one of them wrong
            raise error(key_path=key_path, value=name,
                        expected=f"a 'package.module:Class' that exists ({err})") from None
        raise error(key_path=key_path, value=name,
                    expected=f"one of {known}, a name registered under the entry-point group "
                             f"{_ENTRY_POINT_GROUPS[kind]}, or 'package.module:Class'") from None
    except BackendImportError as err:
        raise error(key_path=key_path, value=name, expected=f"a {kind} backend that imports ({err})") from None
    if not (isinstance(cls, type) and issubclass(cls, base)):
        what = f"the class {cls.__module__}.{cls.__qualname__}" if isinstance(cls, type) else f"a {type(cls).__name__}"
        raise error(key_path=key_path, value=name,
                    expected=f"a {base.__name__} backend class ({name!r} is {what}, not a {base.__name__})")
    if inspect.isabstract(cls):
        missing = ", ".join(sorted(getattr(cls, "__abstractmethods__", ())))
        raise error(key_path=key_path, value=name,
                    expected=f"a {base.__name__} backend class that can be built ({cls.__name__} is abstract: "
                             f"{missing})")
    return cls
