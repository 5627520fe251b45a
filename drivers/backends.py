"""Choosing a backend by name, and checking a config against it: the one place for both.

A config names a backend either by a short name from the table below, or as
`package.module:Class` for a user's own hardware (no fork needed); installed packages can
also add names through the entry-point groups `headctl.servo_buses` and `headctl.cameras`.
A name resolves to a backend class, or to a factory that picks the class for a config
(`dynamixel`: the Protocol 2.0 or 1.0 bus, by `servo_bus.protocol`). Modules are imported
only when selected. "Unknown backend" and "backend failed to import" are different errors.

`servo_bus_backend` and `camera_backend` give either as a `ConfigError` naming the config key
(`servo_bus.backend`), and refuse a class that is not of the device kind's base or is
abstract; `check_servo_bus_config` and `check_camera_config` refuse keys the backend does
not use and servo models it does not drive. headctl's config loader calls them, so a
config is refused when it is loaded, not when its devices are built. The device-kind
modules (`drivers.servo.bus`, `drivers.cameras.camera`) import this table to build
devices, so it takes their base class as an argument rather than importing them.
"""
from __future__ import annotations

import importlib
import inspect
import logging
import re
from importlib import metadata
from typing import Any, Literal, Protocol, cast

from drivers.cameras.config import CameraConfig
from drivers.errors import BackendImportError, BackendNotFoundError, CameraConfigError, ConfigError, ServoConfigError
from drivers.servo.config import ServoBusConfig, set_keys

log = logging.getLogger(__name__)

Kind = Literal["servo_bus", "camera", "servo_probe"]

# name -> (module, class or factory (`backend_class`), what to install when the import fails)
SERVO_BUS_BACKENDS: dict[str, tuple[str, str, str]] = {
    "dynamixel": ("drivers.dynamixel.factory", "dynamixel_bus_class", "pip install dynamixel-sdk pyserial"),
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

# The keys every backend uses: the device-kind base classes implement what they say.
SERVO_BUS_COMMON_KEYS = frozenset({"backend", "port", "joints", "limit_policy", "reboot_on_hardware_error",
                                   "torque_on_close", "power_loss_torque"})
# (`backlash_deg` is the head's, whatever drives the servos: headctl.service.play.)
SERVO_JOINT_COMMON_KEYS = frozenset({"id", "direction", "zero_offset", "min_angle", "max_angle", "backlash_deg"})
CAMERA_COMMON_KEYS = frozenset({"backend", "image", "history", "grab_timeout_s", "exposure_control"})


class ServoBusBackend(Protocol):
    """What the config check reads of a servo-bus backend class (`drivers.servo.bus.ServoBus`)."""

    CONFIG_KEYS: frozenset[str]
    JOINT_CONFIG_KEYS: frozenset[str]
    MODELS: frozenset[str] | None


class CameraBackend(Protocol):
    """What the config check reads of a camera backend class (`drivers.cameras.camera.Camera`)."""

    CONFIG_KEYS: frozenset[str]


def resolve(kind: Kind, name: str) -> Any:
    """Backend `name` of device kind `kind` ("servo_bus", "camera" or "servo_probe"): its
    class, or a factory picking the class for a config (`backend_class`)."""
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
                loaded: Any = ep.load()
            except Exception as err:  # whatever the plugin's import raises, it did not import
                raise BackendImportError(f"{kind} backend {name!r} (entry point {ep.value}) failed to import: "
                                         f"{err!r}") from err
            return loaded
    known = ", ".join(sorted(table))
    raise BackendNotFoundError(
        f"unknown {kind} backend {name!r}: expected one of {known}, or 'package.module:Class'"
    )


def backend_class(kind: Kind, name: str, config: Any) -> Any:
    """What backend `name` builds `config` with: the class named, or the class its factory picks."""
    found = resolve(kind, name)
    if not isinstance(found, type) and callable(found):
        return found(config)
    return found


def _import(kind: str, name: str, module_name: str, class_name: str, install: str) -> Any:
    try:
        module = importlib.import_module(module_name)
    except ImportError as err:
        hint = f" (install: {install})" if install else ""
        raise BackendImportError(f"{kind} backend {name!r} failed to import {module_name}: {err}{hint}") from err
    except Exception as err:  # a module that raises while it is imported: it did not import
        raise BackendImportError(f"{kind} backend {name!r} failed to import {module_name}: {err!r}") from err
    try:
        cls: Any = getattr(module, class_name)
    except AttributeError as err:
        raise BackendNotFoundError(f"{kind} backend {name!r}: module {module_name} has no class {class_name}") from err
    return cls


def resolve_for_config(kind: Kind, name: str, base: type, key_path: str, config: Any,
                       error: type[ConfigError] = ConfigError) -> type:
    """The class backend `name` builds `config` with, a subclass of `base` that can be built;
    else `error` naming `key_path` (`cameras.left.backend`) with what was wrong: an unknown
    name, a module that does not import, or something that is not a `base`."""
    known = ", ".join(sorted(_TABLES[kind]))
    try:
        cls: Any = backend_class(kind, name, config)
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
    found: type = cls
    return found


def servo_bus_backend(config: ServoBusConfig, base: type) -> type:
    """The servo-bus class (a subclass of `base`, `drivers.servo.bus.ServoBus`) `config.backend`
    names, imported now; a `ServoConfigError` naming `<key_path>.backend` otherwise."""
    return resolve_for_config("servo_bus", config.backend, base, f"{config.key_path}.backend", config,
                              ServoConfigError)


def camera_backend(config: CameraConfig, base: type, key_path: str = "camera") -> type:
    """The camera class (a subclass of `base`, `drivers.cameras.camera.Camera`) `config.backend`
    names, imported now; a `CameraConfigError` naming `<key_path>.backend` otherwise."""
    return resolve_for_config("camera", config.backend, base, f"{key_path}.backend", config, CameraConfigError)


def check_servo_bus_config(config: ServoBusConfig, backend_class: type) -> None:
    """Refuse keys the backend (a `ServoBus` class: `servo_bus_backend`) does not use, rather
    than ignore them silently, servo models it does not drive, and what only the backend can
    judge (its `check_config`: the models and settings of the protocol in use)."""
    backend = cast(ServoBusBackend, backend_class)
    used = backend.CONFIG_KEYS | SERVO_BUS_COMMON_KEYS
    unused = sorted(set_keys(config) - used)
    if unused:
        raise ServoConfigError(
            key_path=f"{config.key_path}.{unused[0]}", value=getattr(config, unused[0]),
            expected=f"nothing: {unused[0]} is not used by the {config.backend!r} backend, which uses "
                     f"{', '.join(sorted(used))}")
    joint_used = backend.JOINT_CONFIG_KEYS | SERVO_JOINT_COMMON_KEYS
    for joint, jc in config.joints.items():
        joint_unused = sorted(set_keys(jc) - joint_used)
        if joint_unused:
            key = joint_unused[0]
            raise ServoConfigError(
                key_path=f"{config.joint_path(joint)}.{key}", value=getattr(jc, "servo_id" if key == "id" else key),
                expected=f"nothing: {key} is not used by the {config.backend!r} backend, which uses "
                         f"{', '.join(sorted(joint_used))} for a joint")
        models = backend.MODELS
        if models is not None and jc.model not in models:
            raise ServoConfigError(
                key_path=f"{config.joint_path(joint)}.model", value=jc.model,
                expected=f"one of {', '.join(sorted(models))} (the models the {config.backend!r} backend drives)")
    check_config = getattr(backend, "check_config", None)
    if check_config is not None:
        check_config(config)


def check_camera_config(config: CameraConfig, backend_class: type, key_path: str = "camera") -> None:
    """Refuse keys the backend (a `Camera` class: `camera_backend`) does not use, rather than
    ignore them silently."""
    backend = cast(CameraBackend, backend_class)
    used = backend.CONFIG_KEYS | CAMERA_COMMON_KEYS
    unused = sorted(config.set_keys() - used)
    if unused:
        raise CameraConfigError(
            key_path=f"{key_path}.{unused[0]}", value=getattr(config, unused[0]),
            expected=f"nothing: {unused[0]} is not used by the {config.backend!r} backend, which uses "
                     f"{', '.join(sorted(used))}",
        )
