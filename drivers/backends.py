"""Choosing a backend by name: a table of (module, class), imported only when selected.

A config names a backend either by a short name from the table below, or as
`package.module:Class` for a user's own hardware (no fork needed); installed packages can
also add names through the entry-point groups `headctl.servo_buses` and `headctl.cameras`.
"Unknown backend" and "backend failed to import" are different errors.
"""
from __future__ import annotations

import importlib
import logging
from importlib import metadata
from typing import Literal

from drivers.errors import BackendImportError, BackendNotFoundError

log = logging.getLogger(__name__)

Kind = Literal["servo_bus", "camera"]

# name -> (module, class, what to install when the import fails)
SERVO_BUS_BACKENDS: dict[str, tuple[str, str, str]] = {
    "dynamixel": ("drivers.dynamixel", "DynamixelBus", "pip install dynamixel-sdk pyserial"),
    "sim": ("drivers.sim_servo", "SimulatedServoBus", ""),
}
CAMERA_BACKENDS: dict[str, tuple[str, str, str]] = {
    "aravis": (
        "drivers.aravis_camera",
        "AravisCamera",
        "apt-get install gir1.2-aravis-0.8 && pip install 'PyGObject<3.51' (./setup.sh does both)",
    ),
    "opencv": ("drivers.opencv_camera", "OpenCVCamera", "pip install opencv-python-headless"),
    "sim": ("drivers.sim_camera", "SimulatedCamera", ""),
}
_TABLES = {"servo_bus": SERVO_BUS_BACKENDS, "camera": CAMERA_BACKENDS}
_ENTRY_POINT_GROUPS = {"servo_bus": "headctl.servo_buses", "camera": "headctl.cameras"}


def resolve(kind: Kind, name: str) -> type:
    """The class of backend `name` of device kind `kind` ("servo_bus" or "camera")."""
    table = _TABLES[kind]
    if name in table:
        module_name, class_name, install = table[name]
        return _import(kind, name, module_name, class_name, install)
    if ":" in name:
        module_name, _, class_name = name.partition(":")
        return _import(kind, name, module_name, class_name, "")
    for ep in metadata.entry_points(group=_ENTRY_POINT_GROUPS[kind]):
        if ep.name == name:
            try:
                loaded: type = ep.load()
            except ImportError as err:
                raise BackendImportError(f"{kind} backend {name!r} (entry point {ep.value}) failed to import: {err}") from err
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
    try:
        cls: type = getattr(module, class_name)
    except AttributeError as err:
        raise BackendNotFoundError(f"{kind} backend {name!r}: module {module_name} has no class {class_name}") from err
    return cls
