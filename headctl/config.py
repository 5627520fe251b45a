"""One YAML file per head, read into typed objects before anything is constructed.

Sections (docs/config.md): `servo_bus` and `cameras` (the drivers' `ServoBusConfig` and
`StereoCamerasConfig`), `gaze_map` (profile, seed, Table I parameters), `fixation`
(`calib_free.fixation.FixationParams` fields plus exploration on/off and rate), `service`
(servo loop rate, stale-input timeout, checkpoints, safe state), `api` (the HTTP control
API's address, token, TLS, streams), `state_dir` and `logging`.
Every section is read by the one reader, `drivers.config`; checks across sections and the
files the config names (token file, TLS certificate and key) are done here, at load time.
Unknown keys, wrong types and out-of-range values are `ConfigError`s naming the file, the
key path, the value and what was expected.
"""
from __future__ import annotations

import dataclasses
import importlib.resources
import ipaddress
import logging
import os
import ssl
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from calib_free.fixation import FixationParams
from calib_free.gaze_map import PROFILES, GazeMapParams
from drivers.camera import StereoCamerasConfig
from drivers.config import check_settings, config_error_from, config_meta, read_config, setting
from drivers.servo_bus import ServoBusConfig
from headctl.errors import ConfigError

log = logging.getLogger(__name__)

# Package data, so an installed wheel has it too (the checkout's configs/ links here).
DEFAULT_CONFIG = Path(str(importlib.resources.files("headctl") / "configs" / "sim.yaml"))
MAP_FILE = "gaze_map.npz"
API_URL_FILE = "api.url"  # the API's URL, written once it listens (port 0: the one the kernel chose)
LOCK_FILE = "headctl.lock"  # one daemon per state directory
LOG_LEVELS = ("DEBUG", "INFO", "WARNING", "ERROR")
SAFE_STATES = ("hold", "torque_off")


# --- the sections ---------------------------------------------------------------------------
@dataclass(frozen=True)
class GazeMapConfig:
    """The `gaze_map:` section: a profile, a seed for the random start, Table I overrides
    (any `GazeMapParams` field but image_size, which comes from the cameras)."""

    profile: str = setting("default", choices=PROFILES, expected=" or ".join(PROFILES))
    seed: int = 0
    overrides: Mapping[str, Any] = setting(default_factory=dict, inline=GazeMapParams,
                                           exclude=("image_size", "profile"))

    def params(self, image_size: tuple[int, int]) -> GazeMapParams:
        return GazeMapParams.profile_values(self.profile, image_size=image_size, **self.overrides)


@dataclass(frozen=True)
class FixationConfig:
    """The `fixation:` section: FixationParams (its fields are keys of the section itself),
    and whether and how often the daemon explores."""

    params: FixationParams = setting(default_factory=FixationParams, inline=FixationParams)
    explore: bool = True  # random exploratory fixations that teach the map
    rate_hz: float = setting(0.0, lo=0.0, expected="a rate >= 0 (0: back to back)")  # at most this many a second
    # deg; None: what the eye joints' limits allow
    vergence_range: tuple[float, float] | None = setting(None, check=lambda r: r[0] < r[1],
                                                         expected="[low, high] with low < high (deg)")

    def __post_init__(self) -> None:
        check_settings(self)


@dataclass(frozen=True)
class ServiceConfig:
    """The `service:` section: the servo loop, checkpoints, the safe state at shutdown."""

    # servo I/O loop: one read and one write per cycle
    servo_rate_hz: float = setting(100.0, lo=1.0, hi=1000.0, expected="a rate in [1, 1000] Hz")
    # no word from the controller for this long: hold position
    input_timeout_s: float = setting(0.5, above=0.0, expected="a positive time")
    checkpoint_every: int = setting(50, lo=1, expected="at least 1")  # adaptations between atomic map checkpoints
    # at shutdown: hold (goal = present; torque as servo_bus.torque_on_close) or torque_off
    safe_state: str = setting("hold", choices=SAFE_STATES, expected=" or ".join(SAFE_STATES))
    # SIGTERM to exit; systemd's stop timeout is larger
    shutdown_timeout_s: float = setting(4.0, above=0.0, hi=30.0, expected="a time in (0, 30] s")
    # a camera failed or silent this long: its stream is restarted
    camera_stall_s: float = setting(5.0, above=0.0, expected="a positive time")
    # the interpreter's GIL switch interval (CPython's default: 5 ms)
    switch_interval_ms: float = setting(0.2, lo=0.05, hi=10.0, expected="a time in [0.05, 10] ms")
    # > 0: SCHED_FIFO priority of the servo loop thread, when allowed
    realtime_priority: int = setting(0, lo=0, hi=99, expected="0 (off) to 99")

    def __post_init__(self) -> None:
        check_settings(self)


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
    # 0: an ephemeral port, written to <state_dir>/api.url
    port: int = setting(8765, lo=0, hi=65535, expected="a TCP port, 0 for an ephemeral one")
    # 'Authorization: Bearer <token>' (or ?token=); a secret: never in a message or a log line
    token: str | None = setting(None, secret=True, repr=False, check=lambda t: len(t) >= 16,
                                expected="at least 16 characters")
    token_file: str | None = None  # a file holding the token (mode 0600); relative to the config file
    tls_cert: str | None = None  # HTTPS: the certificate (PEM, with its chain); relative to the config file
    tls_key: str | None = None  # ... and its private key (PEM, mode 0600)
    max_queued_looks: int = setting(16, lo=1, hi=1000, expected="1 to 1000")
    # MJPEG frames a second per client
    stream_fps: float = setting(10.0, lo=0.1, hi=60.0, expected="0.1 to 60 frames a second")
    jpeg_quality: int = setting(80, lo=10, hi=100, expected="10 to 100")

    def __post_init__(self) -> None:
        check_settings(self)

    @property
    def url(self) -> str:
        host = "127.0.0.1" if self.host in ("0.0.0.0", "") else ("[::1]" if self.host == "::" else self.host)
        return f"{'https' if self.tls_cert else 'http'}://{host}:{self.port}"


@dataclass(frozen=True)
class LoggingConfig:
    level: str = setting("INFO", choices=LOG_LEVELS, expected=" or ".join(LOG_LEVELS))
    file: str | None = None  # also log to this file (besides stderr / the journal)

    def __post_init__(self) -> None:
        check_settings(self)


@dataclass(frozen=True)
class HeadConfig:
    """A head's whole configuration, typed. `path` is the file it was read from; `state_dir`
    is resolved against the file's directory by `load_config`."""

    path: Path = field(metadata=config_meta(source="file"))
    servo_bus: ServoBusConfig
    cameras: StereoCamerasConfig
    gaze_map: GazeMapConfig = field(default_factory=GazeMapConfig)
    fixation: FixationConfig = field(default_factory=FixationConfig)
    service: ServiceConfig = field(default_factory=ServiceConfig)
    state_dir: Path = Path("~/.local/state/headctl")
    logging: LoggingConfig = field(default_factory=LoggingConfig)
    api: ApiConfig = field(default_factory=ApiConfig)

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

    def with_state_dir(self, state_dir: str | os.PathLike[str]) -> "HeadConfig":
        return dataclasses.replace(self, state_dir=Path(state_dir).expanduser().resolve())


# --- loading ----------------------------------------------------------------------------------
def read_yaml(path: str | os.PathLike[str]) -> Any:
    """A YAML file's document; ConfigError naming the file if it cannot be read or parsed."""
    try:
        with open(path, encoding="utf-8") as f:
            return yaml.safe_load(f)
    except OSError as err:
        raise ConfigError(f"cannot read: {err.strerror}", file=path) from err
    except yaml.YAMLError as err:
        raise ConfigError(f"not valid YAML: {err}", file=path) from err


def load_config(path: str | os.PathLike[str] | None = None) -> HeadConfig:
    """Read and validate a head's YAML file (default: the packaged configs/sim.yaml, the simulated head)."""
    path = Path(path) if path is not None else DEFAULT_CONFIG
    return parse_config(read_yaml(path), path)


def parse_config(data: Any, path: Path) -> HeadConfig:
    """The typed config from a YAML document read from `path`; ConfigError naming `path`."""
    try:
        config = read_config(HeadConfig, data, file=path)
        check_cameras(config.cameras, config.servo_bus)
        try:
            config.map_params()
        except ValueError as err:
            given = {"profile": config.gaze_map.profile, **config.gaze_map.overrides}
            raise config_error_from(err, "gaze_map", given, cls=GazeMapParams) from err
        return dataclasses.replace(config, api=_resolve_api(config.api, path),
                                   state_dir=_beside(path, str(config.state_dir)))
    except ConfigError as err:
        if err.file is None:
            err.file = path
        raise


def check_cameras(cameras: StereoCamerasConfig, servo_bus: ServoBusConfig | None = None) -> None:
    """The checks across the cameras (and, given it, the servo bus) a head needs.

    With the servo bus (a whole head): both image sizes given and equal, since the gaze map is
    built for one; simulated cameras only on the simulated servo bus, since they render it.
    Always: both eyes simulated or neither, and simulated eyes that agree on what they see.
    """
    if servo_bus is not None:
        for side in ("left", "right"):
            for key in ("width", "height"):
                if getattr(getattr(cameras, side), key) is None:
                    raise ConfigError(key_path=f"cameras.{side}.{key}", value=None,
                                      expected="the image size in pixels (the gaze map is built for it)")
        left, right = cameras.left, cameras.right
        if (left.width, left.height) != (right.width, right.height):
            raise ConfigError(key_path="cameras.right.width", value=(right.width, right.height),
                              expected=f"the left camera's size {left.width} x {left.height}")
    sim_cams = [s for s in ("left", "right") if getattr(cameras, s).backend == "sim"]
    if sim_cams and servo_bus is not None and servo_bus.backend != "sim":
        raise ConfigError(key_path=f"cameras.{sim_cams[0]}.backend", value="sim",
                          expected="a real camera backend: simulated cameras render the simulated head "
                                   "(servo_bus.backend: sim)")
    if len(sim_cams) == 1:
        other = "right" if sim_cams == ["left"] else "left"
        raise ConfigError(key_path=f"cameras.{other}.backend", value=getattr(cameras, other).backend,
                          expected="sim: both eyes of the simulated head are simulated, or neither")
    if sim_cams:
        for key in ("width", "height", "lens", "seed", "image"):
            if getattr(cameras.left, key) != getattr(cameras.right, key):
                raise ConfigError(key_path=f"cameras.right.{key}", value=getattr(cameras.right, key),
                                  expected=f"{getattr(cameras.left, key)!r} like cameras.left: "
                                           "both eyes of the simulated head see one scene through one lens")


def _resolve_api(api: ApiConfig, path: Path) -> ApiConfig:
    """The api section with its token file read and its TLS files found and checked."""
    if api.token is not None and api.token_file is not None:
        raise ConfigError(key_path="api.token_file", value=api.token_file,
                          expected="either api.token or api.token_file, not both")
    if api.token_file is not None:
        token_path = _beside(path, api.token_file)
        try:
            token = token_path.read_text(encoding="utf-8").strip()
        except OSError as err:
            raise ConfigError(key_path="api.token_file", value=api.token_file,
                              expected=f"a readable file holding the token ({err.strerror})") from None
        if len(token) < 16:
            raise ConfigError(key_path="api.token_file", value=api.token_file,
                              expected="a file holding a token of at least 16 characters")
        api = dataclasses.replace(api, token=token, token_file=str(token_path))
    if api.enabled and not is_loopback(api.host) and api.token is None:
        raise ConfigError(key_path="api.token", value=None,
                          expected=f"a token (api.token or api.token_file): api.host {api.host!r} is not "
                                   "a loopback address, and the API moves the head")
    if (api.tls_cert is None) != (api.tls_key is None):
        missing = "api.tls_key" if api.tls_key is None else "api.tls_cert"
        raise ConfigError(key_path=missing, value=None,
                          expected="both api.tls_cert and api.tls_key (HTTPS needs the certificate and its key)")
    if api.tls_cert is not None and api.tls_key is not None:
        cert, key = _beside(path, api.tls_cert), _beside(path, api.tls_key)
        for name, file, given in (("api.tls_cert", cert, api.tls_cert), ("api.tls_key", key, api.tls_key)):
            if not os.access(file, os.R_OK):
                raise ConfigError(key_path=name, value=given,
                                  expected=f"a readable PEM file ({file} is missing or unreadable)")
        # Here, not when the daemon starts: `headctl check` and the CLI see a bad pair too.
        context = ssl.create_default_context(ssl.Purpose.CLIENT_AUTH)
        try:
            context.load_verify_locations(cafile=cert)
        except ssl.SSLError as err:
            raise ConfigError(key_path="api.tls_cert", value=api.tls_cert,
                              expected=f"a PEM certificate ({err.reason or err})") from None
        try:
            context.load_cert_chain(cert, key)
        except ssl.SSLError as err:
            raise ConfigError(key_path="api.tls_key", value=api.tls_key,
                              expected=f"the PEM private key of the certificate in api.tls_cert "
                                       f"({err.reason or err})") from None
        api = dataclasses.replace(api, tls_cert=str(cert), tls_key=str(key))
    return api


def _beside(config_path: Path, value: str) -> Path:
    """A path from the config: ~ and $VARS expanded, relative to the config file's directory."""
    file = Path(os.path.expandvars(value)).expanduser()
    return file if file.is_absolute() else config_path.resolve().parent / file
