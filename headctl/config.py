"""One YAML file per head, parsed into typed objects before anything is constructed.

Sections (README, "The service"): `servo_bus` and `cameras` (parsed by the drivers' own
`from_mapping`), `gaze_map` (grid, ranges, Table I parameters, profile), `fixation`
(`calib_free.fixation.FixationParams` fields plus exploration on/off and rate), `service`
(servo loop rate, stale-input timeout, checkpoints, safe state), `api` (the HTTP control
API's address, token, streams), `state_dir` and `logging`.
Unknown keys, wrong types and out-of-range values are `ConfigError`s naming the file, the
key path, the value and what was expected.
"""
from __future__ import annotations

import dataclasses
import ipaddress
import logging
import os
import ssl
import types
import typing
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

import yaml

from calib_free.fixation import FixationParams
from calib_free.gaze_map import PROFILES, GazeMapParams
from drivers.camera import StereoCamerasConfig
from drivers.camera import coerce_config_value as coerce_camera_value  # the scalar rules, kept in one place
from drivers.camera import config_type_name as camera_type_name
from drivers.errors import CameraConfigError, ServoConfigError
from drivers.servo_bus import ServoBusConfig
from headctl.errors import ConfigError

log = logging.getLogger(__name__)

DEFAULT_CONFIG = Path(__file__).resolve().parent.parent / "configs" / "sim.yaml"
MAP_FILE = "gaze_map.npz"
API_URL_FILE = "api.url"  # the API's URL, written once it listens (port 0: the one the kernel chose)
LOCK_FILE = "headctl.lock"  # one daemon per state directory
LOG_LEVELS = ("DEBUG", "INFO", "WARNING", "ERROR")
SAFE_STATES = ("hold", "torque_off")


class _Invalid(Exception):
    """A value that does not fit; `ConfigError` is built from it with the file name."""

    def __init__(self, key_path: str, value: Any, expected: str) -> None:
        super().__init__(f"{key_path}: got {value!r}, expected {expected}")


def _type_name(tp: Any) -> str:
    if typing.get_origin(tp) is tuple:
        args = typing.get_args(tp)
        if len(args) == 2 and args[1] is Ellipsis:
            return f"a list of ({_type_name(args[0])})"
        return f"a list of {len(args)} ({', '.join(_type_name(a) for a in args)})"
    if dataclasses.is_dataclass(tp):
        return f"a mapping of {tp.__name__} settings"
    return camera_type_name(tp)


def _coerce(value: Any, tp: Any, key_path: str) -> Any:
    """`value` as type `tp`, or raise _Invalid: the cameras' scalar rules (int, float, str, bool,
    Literal, Optional) plus what the fixation and map sections need (tuples, nested dataclasses)."""
    origin = typing.get_origin(tp)
    if origin in (typing.Union, types.UnionType) and any(typing.get_origin(a) is tuple for a in typing.get_args(tp)):
        if value is None and type(None) in typing.get_args(tp):
            return None
        for option in (a for a in typing.get_args(tp) if a is not type(None)):
            try:
                return _coerce(value, option, key_path)
            except _Invalid:
                continue
    elif origin is tuple:
        args = typing.get_args(tp)
        if isinstance(value, (list, tuple)):
            if len(args) == 2 and args[1] is Ellipsis:
                return tuple(_coerce(v, args[0], f"{key_path}[{i}]") for i, v in enumerate(value))
            if len(value) == len(args):
                return tuple(_coerce(v, a, f"{key_path}[{i}]") for i, (v, a) in enumerate(zip(value, args)))
    elif dataclasses.is_dataclass(tp):
        return _parse_dataclass(tp, value, key_path)
    else:
        try:
            return coerce_camera_value(value, tp, key_path)
        except CameraConfigError:
            pass
    raise _Invalid(key_path, value, _type_name(tp))


def _check_keys(data: Any, key_path: str, allowed: typing.Iterable[str]) -> Mapping[str, Any]:
    allowed = sorted(allowed)
    if data is None:
        return {}
    if not isinstance(data, Mapping):
        raise _Invalid(key_path, data, f"a mapping with keys {', '.join(allowed)}")
    for key in data:
        if key not in allowed:
            raise _Invalid(f"{key_path}.{key}", data[key], f"no such key: {key_path} takes {', '.join(allowed)}")
    return data


def _parse_fields(cls: type, data: Mapping[str, Any], key_path: str, skip: typing.Iterable[str] = ()) -> dict:
    """Typed values for those of `cls`'s fields that `data` gives (unknown keys checked by the caller)."""
    hints = typing.get_type_hints(cls)
    names = {f.name for f in dataclasses.fields(cls) if f.init} - set(skip)
    return {k: _coerce(v, hints[k], f"{key_path}.{k}") for k, v in data.items() if k in names}


def _parse_dataclass(cls: type, data: Any, key_path: str) -> Any:
    names = [f.name for f in dataclasses.fields(cls) if f.init]
    values = _parse_fields(cls, _check_keys(data, key_path, names), key_path)
    return _construct(cls, values, key_path)


def _construct(cls: type, values: dict, key_path: str) -> Any:
    try:
        return cls(**values)
    except ValueError as err:  # the dataclass's own checks name the field
        raise _Invalid(key_path, values, f"valid settings ({err})") from err


# --- the sections ---------------------------------------------------------------------------
@dataclass(frozen=True)
class GazeMapConfig:
    """The `gaze_map:` section: a profile, a seed for the random start, Table I overrides."""

    profile: str = "default"
    seed: int = 0
    overrides: Mapping[str, Any] = field(default_factory=dict)  # GazeMapParams fields, typed

    KEYS: typing.ClassVar[tuple[str, ...]] = ("profile", "seed")

    def params(self, image_size: tuple[int, int]) -> GazeMapParams:
        return GazeMapParams.profile_values(self.profile, image_size=image_size, **self.overrides)


@dataclass(frozen=True)
class FixationConfig:
    """The `fixation:` section: FixationParams, and whether/how often the daemon explores."""

    params: FixationParams = field(default_factory=FixationParams)
    explore: bool = True  # random exploratory fixations that teach the map
    rate_hz: float = 0.0  # at most this many fixations a second; 0: back to back
    vergence_range: tuple[float, float] | None = None  # deg; None: what the eye joints' limits allow

    KEYS: typing.ClassVar[tuple[str, ...]] = ("explore", "rate_hz", "vergence_range")


@dataclass(frozen=True)
class ServiceConfig:
    """The `service:` section: the servo loop, checkpoints, the safe state at shutdown."""

    servo_rate_hz: float = 100.0  # servo I/O loop: one read and one write per cycle
    input_timeout_s: float = 0.5  # no word from the controller for this long: hold position
    checkpoint_every: int = 50  # adaptations between atomic map checkpoints
    safe_state: str = "hold"  # at shutdown: hold (goal = present; torque as servo_bus.torque_on_close) or torque_off
    shutdown_timeout_s: float = 4.0  # SIGTERM to exit; systemd's stop timeout is larger
    camera_stall_s: float = 5.0  # a camera failed or silent this long: its stream is restarted
    switch_interval_ms: float = 0.2  # the interpreter's GIL switch interval (CPython's default: 5 ms)
    realtime_priority: int = 0  # > 0: SCHED_FIFO priority of the servo loop thread, when allowed

    def __post_init__(self) -> None:
        checks = (("servo_rate_hz", 1.0 <= self.servo_rate_hz <= 1000.0, "a rate in [1, 1000] Hz"),
                  ("input_timeout_s", self.input_timeout_s > 0, "a positive time"),
                  ("checkpoint_every", self.checkpoint_every >= 1, "at least 1"),
                  ("safe_state", self.safe_state in SAFE_STATES, " or ".join(SAFE_STATES)),
                  ("shutdown_timeout_s", 0 < self.shutdown_timeout_s <= 30, "a time in (0, 30] s"),
                  ("realtime_priority", 0 <= self.realtime_priority <= 99, "0 (off) to 99"),
                  ("camera_stall_s", self.camera_stall_s > 0, "a positive time"),
                  ("switch_interval_ms", 0.05 <= self.switch_interval_ms <= 10, "a time in [0.05, 10] ms"))
        for key, ok, expected in checks:
            if not ok:
                raise ValueError(f"{key}: got {getattr(self, key)!r}, expected {expected}")


def is_loopback(host: str) -> bool:
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


@dataclass(frozen=True)
class ApiConfig:
    """The `api:` section: the HTTP control API and dashboard (`headctl.api`)."""

    enabled: bool = True
    host: str = "127.0.0.1"  # any other address needs a token
    port: int = 8765  # 0: an ephemeral port, written to <state_dir>/api.url
    token: str | None = field(default=None, repr=False)  # 'Authorization: Bearer <token>' (or ?token=)
    token_file: str | None = None  # a file holding the token (mode 0600); relative to the config file
    tls_cert: str | None = None  # HTTPS: the certificate (PEM, with its chain); relative to the config file
    tls_key: str | None = None  # ... and its private key (PEM, mode 0600)
    max_queued_looks: int = 16
    stream_fps: float = 10.0  # MJPEG frames a second per client
    jpeg_quality: int = 80

    def __post_init__(self) -> None:
        checks = (("port", 0 <= self.port <= 65535, "a TCP port, 0 for an ephemeral one"),
                  ("max_queued_looks", 1 <= self.max_queued_looks <= 1000, "1 to 1000"),
                  ("stream_fps", 0.1 <= self.stream_fps <= 60, "0.1 to 60 frames a second"),
                  ("jpeg_quality", 10 <= self.jpeg_quality <= 100, "10 to 100"),
                  ("token", self.token is None or len(self.token) >= 16, "at least 16 characters"))
        for key, ok, expected in checks:
            if not ok:
                raise ValueError(f"{key}: got {getattr(self, key)!r}, expected {expected}")

    @property
    def url(self) -> str:
        host = "127.0.0.1" if self.host in ("0.0.0.0", "") else ("[::1]" if self.host == "::" else self.host)
        return f"{'https' if self.tls_cert else 'http'}://{host}:{self.port}"


@dataclass(frozen=True)
class LoggingConfig:
    level: str = "INFO"
    file: str | None = None  # also log to this file (besides stderr / the journal)


@dataclass(frozen=True)
class HeadConfig:
    """A head's whole configuration, typed."""

    path: Path
    servo_bus: ServoBusConfig
    cameras: StereoCamerasConfig
    gaze_map: GazeMapConfig
    fixation: FixationConfig
    service: ServiceConfig
    state_dir: Path
    logging: LoggingConfig
    api: ApiConfig = field(default_factory=ApiConfig)

    TOP_KEYS: typing.ClassVar[tuple[str, ...]] = (
        "servo_bus", "cameras", "gaze_map", "fixation", "service", "api", "state_dir", "logging")

    @property
    def image_size(self) -> tuple[int, int]:
        left = self.cameras.left
        return int(left.width or 0), int(left.height or 0)

    @property
    def simulated(self) -> bool:
        return self.servo_bus.backend == "sim"

    def map_params(self) -> GazeMapParams:
        return self.gaze_map.params(self.image_size)

    @property
    def map_path(self) -> Path:
        return self.state_dir / MAP_FILE

    @property
    def api_url_path(self) -> Path:
        return self.state_dir / API_URL_FILE

    @property
    def lock_path(self) -> Path:
        return self.state_dir / LOCK_FILE

    def with_api(self, **changes: Any) -> "HeadConfig":
        return dataclasses.replace(self, api=dataclasses.replace(self.api, **changes))

    def with_state_dir(self, state_dir: str | os.PathLike) -> "HeadConfig":
        return dataclasses.replace(self, state_dir=Path(state_dir).expanduser().resolve())


def read_yaml(path: str | Path) -> Any:
    """A YAML file's document; ConfigError naming the file if it cannot be read or parsed."""
    try:
        with open(path, encoding="utf-8") as f:
            return yaml.safe_load(f)
    except OSError as err:
        raise ConfigError(f"{path}: cannot read: {err.strerror}") from err
    except yaml.YAMLError as err:
        raise ConfigError(f"{path}: not valid YAML: {err}") from err


def load_config(path: str | os.PathLike | None = None) -> HeadConfig:
    """Read and validate a head's YAML file (default: configs/sim.yaml, the simulated head)."""
    path = Path(path) if path is not None else DEFAULT_CONFIG
    data = read_yaml(path)
    try:
        return parse_config(data, path)
    except (_Invalid, ServoConfigError, CameraConfigError) as err:
        raise ConfigError(f"{path}: {err}") from err


def parse_config(data: Any, path: Path) -> HeadConfig:
    """The typed config from a parsed YAML document; raises _Invalid or a driver's config error."""
    top = _check_keys(data, "(top level)", HeadConfig.TOP_KEYS)
    for required in ("servo_bus", "cameras"):
        if required not in top:
            raise _Invalid(required, None, f"a {required}: section")
    servo_bus = ServoBusConfig.from_mapping(top["servo_bus"], "servo_bus")
    cameras = StereoCamerasConfig.from_mapping(top["cameras"], "cameras")
    for side in ("left", "right"):
        cam = getattr(cameras, side)
        for key in ("width", "height"):
            if getattr(cam, key) is None:
                raise _Invalid(f"cameras.{side}.{key}", None, "the image size in pixels (the gaze map is built for it)")
    if (cameras.left.width, cameras.left.height) != (cameras.right.width, cameras.right.height):
        raise _Invalid("cameras.right.width", (cameras.right.width, cameras.right.height),
                       f"the left camera's size {cameras.left.width} x {cameras.left.height}")
    sim_cams = [s for s in ("left", "right") if getattr(cameras, s).backend == "sim"]
    if sim_cams and servo_bus.backend != "sim":
        raise _Invalid(f"cameras.{sim_cams[0]}.backend", "sim",
                       "a real camera backend: simulated cameras render the simulated head (servo_bus.backend: sim)")
    if len(sim_cams) == 1:
        other = "right" if sim_cams == ["left"] else "left"
        raise _Invalid(f"cameras.{other}.backend", getattr(cameras, other).backend,
                       "sim: both eyes of the simulated head are simulated, or neither")
    if sim_cams:
        for key in ("lens", "seed", "image"):
            if getattr(cameras.left, key) != getattr(cameras.right, key):
                raise _Invalid(f"cameras.right.{key}", getattr(cameras.right, key),
                               f"{getattr(cameras.left, key)!r} like cameras.left: both eyes see one scene")

    gm_data = _check_keys(top.get("gaze_map"), "gaze_map",
                          GazeMapConfig.KEYS + tuple(f.name for f in dataclasses.fields(GazeMapParams)
                                                     if f.name not in ("image_size", "profile")))
    profile = gm_data.get("profile", "default")
    if profile not in PROFILES:
        raise _Invalid("gaze_map.profile", profile, " or ".join(PROFILES))
    seed = _coerce(gm_data.get("seed", 0), int, "gaze_map.seed")
    overrides = _parse_fields(GazeMapParams, {k: v for k, v in gm_data.items() if k not in GazeMapConfig.KEYS},
                              "gaze_map", skip=("image_size", "profile"))
    gaze_map = GazeMapConfig(profile=profile, seed=seed, overrides=overrides)
    try:
        gaze_map.params(cameras_size := (int(cameras.left.width), int(cameras.left.height)))
    except ValueError as err:
        raise _Invalid("gaze_map", gm_data, f"valid map parameters for {cameras_size} images ({err})") from err

    fix_data = _check_keys(top.get("fixation"), "fixation",
                           FixationConfig.KEYS + tuple(f.name for f in dataclasses.fields(FixationParams)))
    params = _construct(FixationParams, _parse_fields(FixationParams, {
        k: v for k, v in fix_data.items() if k not in FixationConfig.KEYS}, "fixation"), "fixation")
    explore = _coerce(fix_data.get("explore", True), bool, "fixation.explore")
    rate_hz = _coerce(fix_data.get("rate_hz", 0.0), float, "fixation.rate_hz")
    if rate_hz < 0:
        raise _Invalid("fixation.rate_hz", rate_hz, "a rate >= 0 (0: back to back)")
    vergence_range = _coerce(fix_data.get("vergence_range"), tuple[float, float] | None, "fixation.vergence_range")
    if vergence_range is not None and not vergence_range[0] < vergence_range[1]:
        raise _Invalid("fixation.vergence_range", list(vergence_range), "[low, high] with low < high (deg)")
    fixation = FixationConfig(params=params, explore=explore, rate_hz=rate_hz, vergence_range=vergence_range)

    service = _parse_dataclass(ServiceConfig, top.get("service"), "service")
    log_cfg = _parse_dataclass(LoggingConfig, top.get("logging"), "logging")
    if log_cfg.level not in LOG_LEVELS:
        raise _Invalid("logging.level", log_cfg.level, " or ".join(LOG_LEVELS))

    api = _parse_api(top.get("api"), Path(path))

    raw_state = top.get("state_dir", "~/.local/state/headctl")
    state_str = _coerce(raw_state, str, "state_dir")
    state_dir = _beside(Path(path), state_str)
    return HeadConfig(path=Path(path), servo_bus=servo_bus, cameras=cameras, gaze_map=gaze_map, fixation=fixation,
                      service=service, state_dir=state_dir, logging=log_cfg, api=api)


def _parse_api(data: Any, path: Path) -> ApiConfig:
    api = _parse_dataclass(ApiConfig, data, "api")
    if api.token is not None and api.token_file is not None:
        raise _Invalid("api.token_file", api.token_file, "either api.token or api.token_file, not both")
    if api.token_file is not None:
        token_path = _beside(path, api.token_file)
        try:
            token = token_path.read_text(encoding="utf-8").strip()
        except OSError as err:
            raise _Invalid("api.token_file", api.token_file, f"a readable file holding the token ({err.strerror})")
        if len(token) < 16:
            raise _Invalid("api.token_file", api.token_file, "a file holding a token of at least 16 characters")
        api = dataclasses.replace(api, token=token, token_file=str(token_path))
    if api.enabled and not is_loopback(api.host) and api.token is None:
        raise _Invalid("api.token", None, f"a token (api.token or api.token_file): api.host {api.host!r} is not "
                       "a loopback address, and the API moves the head")
    if (api.tls_cert is None) != (api.tls_key is None):
        missing = "api.tls_key" if api.tls_key is None else "api.tls_cert"
        raise _Invalid(missing, None, "both api.tls_cert and api.tls_key (HTTPS needs the certificate and its key)")
    if api.tls_cert is not None and api.tls_key is not None:
        cert, key = _beside(path, api.tls_cert), _beside(path, api.tls_key)
        for name, file, given in (("api.tls_cert", cert, api.tls_cert), ("api.tls_key", key, api.tls_key)):
            if not os.access(file, os.R_OK):
                raise _Invalid(name, given, f"a readable PEM file ({file} is missing or unreadable)")
        # Here, not when the daemon starts: `headctl check` and the CLI see a bad pair too.
        context = ssl.create_default_context(ssl.Purpose.CLIENT_AUTH)
        try:
            context.load_verify_locations(cafile=cert)
        except ssl.SSLError as err:
            raise _Invalid("api.tls_cert", api.tls_cert, f"a PEM certificate ({err.reason or err})") from None
        try:
            context.load_cert_chain(cert, key)
        except ssl.SSLError as err:
            raise _Invalid("api.tls_key", api.tls_key,
                           f"the PEM private key of the certificate in api.tls_cert ({err.reason or err})") from None
        api = dataclasses.replace(api, tls_cert=str(cert), tls_key=str(key))
    return api


def _beside(config_path: Path, value: str) -> Path:
    """A path from the config: ~ and $VARS expanded, relative to the config file's directory."""
    file = Path(os.path.expandvars(value)).expanduser()
    return file if file.is_absolute() else config_path.resolve().parent / file
