"""One YAML file per head, read into typed objects before anything is constructed.

Sections (docs/config.md): `servo_bus` and `cameras` (the drivers' `ServoBusConfig` and
`StereoCamerasConfig`), `gaze_map` (profile, seed, Table I parameters), `fixation`
(`calib_free.gaze.fixation.FixationParams` fields plus exploration on/off and rate), `service`
(servo loop rate, stale-input timeout, checkpoints, safe state), `api` (the HTTP control
API's address, token, TLS, streams), `ros2` (the ROS 2 interface, `headctl.config.ros2`),
`foxglove` (the live view in Foxglove, `headctl.config.foxglove`),
`state_dir` and `logging`.
Every section is read by the one reader, `drivers.config.reader`; checks across sections and the
files the config names are done here, at load time (the `api` section's token file and TLS
certificate and key by `headctl.config.api`).
Unknown keys, wrong types and out-of-range values are `ConfigError`s naming the file, the
key path, the value and what was expected.

`load_config` checks what the file says, wherever it is read: types, bounds on everything
that sizes an allocation or a wait, the backends it names (resolved and imported), keys
those backends do not use, and the files it names. `check_runtime` checks what depends on
the machine and on command-line overrides (`--state-dir`): that the state directory can be
created and written, and that the log file's directory exists and is writable; `headctl
check` and `headctl run` call both, clients (`status`, `look`) only `load_config`.
"""
from __future__ import annotations

import dataclasses
import importlib.resources
import logging
import math
import os
import stat
import tempfile
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Unpack, cast

from calib_free.correspondence.search import CorrespondenceParams
from calib_free.gaze.exploration import EXPLORATION_KINDS
from calib_free.gaze.fixation import FixationParams
from calib_free.map.params import PROFILES, GazeMapParams
from calib_free.correspondence.alignment import ALIGNMENT_WARPS
from drivers.backends import camera_backend, check_camera_config, check_servo_bus_config, servo_bus_backend
from drivers.cameras.camera import Camera
from drivers.cameras.config import CameraConfig, MAX_IMAGE_SIDE, StereoCamerasConfig
from drivers.config.reader import check_settings, config_error_from, config_meta, declare_settings, read_config, setting
from drivers.config.file import read_yaml_file
from drivers.servo.bus import ServoBus
from drivers.servo.config import ServoBusConfig
from drivers.sim.motion import MovingObject
from headctl.config.foxglove import FoxgloveConfig
from headctl.config.api import ApiChanges, ApiConfig, beside, resolve_api, scrub, secrets_in
from headctl.config.ros2 import Ros2Config
from headctl.config.tracking import TrackingConfig
from headctl.errors import ConfigError
from headctl.json_types import JSON
from headctl.service.head import vergence_limits

log = logging.getLogger(__name__)

# Package data, so an installed wheel has it too (the checkout's configs/ links here).
DEFAULT_CONFIG = Path(str(importlib.resources.files("headctl") / "configs" / "sim.yaml"))
MAP_FILE = "gaze_map.npz"
MAGNIFICATION_FILE = "lens_magnification.json"  # the lens's magnification the looks learned
API_URL_FILE = "api.url"  # the API's URL, written once it listens (port 0: the one the kernel chose)
LOCK_FILE = "headctl.lock"  # one daemon per state directory
LOG_LEVELS = ("DEBUG", "INFO", "WARNING", "ERROR")
SAFE_STATES = ("hold", "torque_off")
SEED_MAX = 2**63 - 1  # numpy's generators take any seed >= 0; this one fits every integer type
MAX_GRID_NODES = 1 << 22  # the map's grid: 3 x 8 bytes a node, 100 MB; the default has 157500


def _each(lo: float, hi: float) -> Callable[[Iterable[float]], bool]:
    """A check that every number of a list lies in [lo, hi]."""
    return lambda values: all(lo <= v <= hi for v in values)


# The bounds of calib_free's parameters, which cannot declare them (calib_free does not import
# drivers). Their own __post_init__ checks stay theirs; these add what sizes an allocation, a
# loop or a wait, and what is physically meaningless.
declare_settings(
    GazeMapParams,
    disparity_range=config_meta(check=_each(-MAX_IMAGE_SIDE, MAX_IMAGE_SIDE),
                                expected=f"[low, high] in px, within +-{MAX_IMAGE_SIDE}"),
    grid_shape=config_meta(check=_each(2, 1024),
                           expected=f"[nx, ny, nd], 2 to 1024 nodes each and {MAX_GRID_NODES} in all at most"),
    output_resolution=config_meta(check=_each(1, 100_000), expected="[n, n, n], 1 to 100000 each"),
    command_range=config_meta(check=lambda r: all(-360.0 <= v <= 360.0 for pair in r for v in pair),
                              expected="3 [low, high] pairs in deg, within +-360"),
    sigma_max_fraction=config_meta(above=0.0, hi=1.0),
    adaptation_slope=config_meta(above=0.0, hi=1000.0),
    adaptation_threshold=config_meta(lo=0.0, hi=1000.0),
    error_window=config_meta(lo=1, hi=10_000),
    retinal_error_max_fraction=config_meta(above=0.0, hi=1.0),
    gaussian_cutoff=config_meta(check=lambda c: 0.0 < c < 1.0, expected="a number in (0, 1)"),
    global_degree=config_meta(lo=0, hi=8),
    global_memory=config_meta(lo=1.0, hi=1e6),
    global_memory_min=config_meta(lo=1.0, hi=1e6),
    pose_degree=config_meta(lo=0, hi=4),
    pose_position_degree=config_meta(lo=0, hi=10),
    pose_cross_degree=config_meta(lo=0, hi=4),
    surprise_threshold=config_meta(above=0.0, hi=1000.0),
    robust_scale=config_meta(lo=0.0, hi=1000.0),
)
declare_settings(
    FixationParams,
    vergence_tolerance_px=config_meta(above=0.0, hi=100.0, expected="a positive disparity, at most 100 px"),
    max_vergence_steps=config_meta(lo=0, hi=100),
    vergence_gain_deg_per_px=config_meta(above=0.0, hi=10.0, expected="a positive gain, at most 10 deg/px, or null"),
    fallback_vergence_gain=config_meta(above=0.0, hi=10.0, expected="a positive gain, at most 10 deg/px"),
    vergence_patch_size=config_meta(check=_each(3, MAX_IMAGE_SIDE),
                                    expected="at least 3 x 3 pixels, and within the image"),
    vergence_search_px=config_meta(lo=1, hi=MAX_IMAGE_SIDE),
    min_vergence_ncc=config_meta(lo=-1.0, hi=1.0),
    vergence_band_px=config_meta(lo=0, hi=MAX_IMAGE_SIDE),
    settle_timeout_s=config_meta(above=0.0, hi=60.0, expected="a positive time, at most 60 s"),
    frame_timeout_s=config_meta(above=0.0, hi=60.0, expected="a positive time, at most 60 s"),
    exploration_step_deg=config_meta(check=lambda steps: all(0.0 < v <= 360.0 for v in steps),
                                     expected="[pan, tilt, vergence], each in (0, 360] deg"),
    exploration=config_meta(choices=EXPLORATION_KINDS, expected=" or ".join(EXPLORATION_KINDS)),
)
declare_settings(
    CorrespondenceParams,
    patch_size=config_meta(check=_each(3, MAX_IMAGE_SIDE), expected="at least 3 x 3 pixels, and within the image"),
    tolerance_radius=config_meta(above=0.0, hi=10.0),
    mean_scale=config_meta(above=0.0, hi=1000.0),
    max_gain=config_meta(lo=1.0, hi=16.0),
    max_offset=config_meta(lo=0.0, hi=255.0),
    pyramid_levels=config_meta(lo=0, hi=8),
    max_vertical_disparity_px=config_meta(lo=0.0, hi=float(MAX_IMAGE_SIDE)),
    stereo_tolerance_px=config_meta(lo=0.0, hi=float(MAX_IMAGE_SIDE)),
    refine_sigma_fraction=config_meta(lo=0.0, hi=10.0),
    alignment_warp=config_meta(choices=tuple(ALIGNMENT_WARPS), expected=" or ".join(ALIGNMENT_WARPS)),
)


# --- the sections ---------------------------------------------------------------------------
@dataclass(frozen=True)
class GazeMapConfig:
    """The `gaze_map:` section: a profile, a seed for the random start, Table I overrides
    (any `GazeMapParams` field but image_size, which comes from the cameras)."""

    profile: str = setting("default", choices=PROFILES, expected=" or ".join(PROFILES))
    seed: int = setting(0, lo=0, hi=SEED_MAX, expected="a seed >= 0")
    overrides: Mapping[str, object] = setting(default_factory=dict, inline=GazeMapParams,
                                           exclude=("image_size", "profile"))

    def __post_init__(self) -> None:
        check_settings(self)
        # The reader has given each override its field's type.
        grid = cast("tuple[int, ...] | None", self.overrides.get("grid_shape"))
        if grid is not None and math.prod(grid) > MAX_GRID_NODES:
            raise ConfigError(key_path="grid_shape", value=grid,
                              expected=f"at most {MAX_GRID_NODES} nodes in all ({math.prod(grid)} asked): "
                                       "the grid is 3 x 8 bytes a node")

    def params(self, image_size: tuple[int, int]) -> GazeMapParams:
        return GazeMapParams.profile_values(self.profile, image_size=image_size, **self.overrides)


@dataclass(frozen=True)
class FixationConfig:
    """The `fixation:` section: FixationParams (its fields are keys of the section itself),
    and whether and how often the daemon explores."""

    params: FixationParams = setting(default_factory=FixationParams, inline=FixationParams)
    explore: bool = True  # random exploratory fixations that teach the map
    # at most this many a second
    rate_hz: float = setting(0.0, lo=0.0, hi=1000.0, expected="a rate >= 0 (0: back to back), at most 1000")
    # deg; None: what the eye joints' limits allow (checked against them by `load_config`)
    vergence_range: tuple[float, float] | None = setting(None, check=lambda r: -360.0 <= r[0] < r[1] <= 360.0,
                                                         expected="[low, high] with low < high (deg), within +-360")

    def __post_init__(self) -> None:
        check_settings(self)


@dataclass(frozen=True)
class ServiceConfig:
    """The `service:` section: the servo loop, checkpoints, the safe state at shutdown."""

    # servo I/O loop: one read and one write per cycle
    servo_rate_hz: float = setting(100.0, lo=1.0, hi=1000.0, expected="a rate in [1, 1000] Hz")
    # no word from the controller for this long: hold position
    input_timeout_s: float = setting(0.5, above=0.0, hi=60.0, expected="a positive time, at most 60 s")
    # adaptations between atomic map checkpoints
    checkpoint_every: int = setting(50, lo=1, hi=1_000_000, expected="at least 1, at most 1000000")
    # ... or this often, in seconds, if the map changed (0: by count only)
    checkpoint_interval_s: float = setting(30.0, lo=0.0, hi=86_400.0, expected="a time in [0, 86400] s (0: off)")
    # at shutdown: hold (goal = present; torque as servo_bus.torque_on_close) or torque_off
    safe_state: str = setting("hold", choices=SAFE_STATES, expected=" or ".join(SAFE_STATES))
    # SIGTERM to exit; systemd's stop timeout is larger
    shutdown_timeout_s: float = setting(4.0, above=0.0, hi=30.0, expected="a time in (0, 30] s")
    # a camera failed or silent this long: its stream is restarted
    camera_stall_s: float = setting(5.0, above=0.0, hi=3600.0, expected="a positive time, at most 3600 s")
    # the interpreter's GIL switch interval (CPython's default: 5 ms)
    switch_interval_ms: float = setting(0.2, lo=0.05, hi=10.0, expected="a time in [0.05, 10] ms")
    # > 0: SCHED_FIFO priority of the servo loop thread, when allowed
    realtime_priority: int = setting(0, lo=0, hi=99, expected="0 (off) to 99")
    # the servo loop in a process of its own (nothing in the service can stall it); false: a thread
    servo_process: bool = True
    # supervision (headctl.service.supervision.restarts): a part that died is restarted after a back-off
    # doubling from restart_backoff_s to restart_backoff_max_s; more than restart_limit
    # failures within restart_window_s and the service exits (3) for systemd to restart it
    restart_limit: int = setting(5, lo=1, hi=1000, expected="at least 1, at most 1000")
    restart_window_s: float = setting(300.0, above=0.0, hi=86_400.0, expected="a positive time, at most 86400 s")
    restart_backoff_s: float = setting(0.5, above=0.0, hi=60.0, expected="a positive time, at most 60 s")
    restart_backoff_max_s: float = setting(10.0, above=0.0, hi=600.0, expected="a positive time, at most 600 s")

    def __post_init__(self) -> None:
        check_settings(self)
        if self.restart_backoff_max_s < self.restart_backoff_s:
            raise ConfigError(key_path="restart_backoff_max_s", value=self.restart_backoff_max_s,
                              expected=f"at least service.restart_backoff_s ({self.restart_backoff_s:g} s)")


@dataclass(frozen=True)
class LoggingConfig:
    level: str = setting("INFO", choices=LOG_LEVELS, expected=" or ".join(LOG_LEVELS))
    file: str | None = None  # also log to this file (besides stderr / the journal)
    # A message repeated by a fault: the first in full, then one summary line per this interval
    # (0: every one written); `headctl.log_limit`.
    repeat_summary_s: float = setting(10.0, lo=0.0, hi=3600.0, expected="a time in seconds from 0 (off) to 3600")

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
    tracking: TrackingConfig = field(default_factory=TrackingConfig)
    ros2: Ros2Config = field(default_factory=Ros2Config)  # the ROS 2 interface (headctl.ros2)
    foxglove: FoxgloveConfig = field(default_factory=FoxgloveConfig)  # the live view in Foxglove (headctl.foxglove)
    sim_objects: tuple[MovingObject, ...] = ()  # moving objects in the simulated room

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
    def magnification_path(self) -> Path:
        return self.state_dir / MAGNIFICATION_FILE

    @property
    def api_url_path(self) -> Path:
        return self.state_dir / API_URL_FILE

    @property
    def lock_path(self) -> Path:
        return self.state_dir / LOCK_FILE

    def with_api(self, **changes: Unpack[ApiChanges]) -> "HeadConfig":
        return dataclasses.replace(self, api=dataclasses.replace(self.api, **changes))

    def with_state_dir(self, state_dir: str | os.PathLike[str]) -> "HeadConfig":
        return dataclasses.replace(self, state_dir=Path(state_dir).expanduser().resolve())


# --- loading ----------------------------------------------------------------------------------
def read_yaml(path: str | os.PathLike[str]) -> JSON:
    """A YAML file's document, read strictly (`drivers.config.file.read_yaml_file`: at most 1 MiB,
    UTF-8, no duplicate keys, bounded nesting); ConfigError naming the file and the line or
    key path if it cannot be read or parsed."""
    return read_yaml_file(path)


def load_config(path: str | os.PathLike[str] | None = None) -> HeadConfig:
    """Read and validate a head's YAML file (default: the packaged configs/sim.yaml, the simulated head)."""
    path = Path(path) if path is not None else DEFAULT_CONFIG
    return parse_config(read_yaml(path), path)


def parse_config(data: JSON, path: Path) -> HeadConfig:
    """The typed config from a YAML document read from `path`; ConfigError naming `path`.

    Beyond the reader's checks: the backends (resolved, so imported, here), the cameras
    against each other and the servo bus, the keys the backends use, the fixation settings against
    the eye joints and the image (`check_fixation`), the map's parameters, and the files the
    api section names."""
    try:
        config = read_config(HeadConfig, _textures_beside(data, path), file=path)
        config = _correspondence_of_the_profile(config, data)
        backends = resolve_backends(config)
        check_cameras(config.cameras, config.servo_bus)
        check_backends(config, backends)
        check_fixation(config)
        try:
            config.map_params()
        except ValueError as err:
            given = {"profile": config.gaze_map.profile, **config.gaze_map.overrides}
            raise config_error_from(err, "gaze_map", given, cls=GazeMapParams) from err
        return dataclasses.replace(config, api=resolve_api(config.api, path),
                                   state_dir=beside(path, str(config.state_dir), "state_dir"))
    except ConfigError as err:
        if err.file is None:
            err.file = path
        scrub(err, secrets_in(data))
        raise


def _textures_beside(data: JSON, path: Path) -> JSON:
    """The raw config with a relative `cameras.scene.textures` made relative to the config
    file's directory, as every path a config names is."""
    cameras = data.get("cameras") if isinstance(data, dict) else None
    scene = cameras.get("scene") if isinstance(cameras, dict) else None
    textures = scene.get("textures") if isinstance(scene, dict) else None
    if not isinstance(cameras, dict) or not isinstance(scene, dict) or not isinstance(textures, str):
        return data
    resolved = str(beside(path, textures, "cameras.scene.textures"))
    return {**data, "cameras": {**cameras, "scene": {**scene, "textures": resolved}}}


def _correspondence_of_the_profile(config: HeadConfig, data: JSON) -> HeadConfig:
    """The correspondence and the exploration follow `gaze_map.profile` (the `paper` profile:
    eqs. 1-7 and random exploration in motor space) unless `fixation.correspondence.profile`
    or `fixation.exploration` says otherwise."""
    fixation = data.get("fixation") if isinstance(data, dict) else None
    fixation = fixation if isinstance(fixation, dict) else {}
    given = fixation.get("correspondence")
    params = config.fixation.params
    profile_given = isinstance(given, dict) and "profile" in given
    random_exploration = "exploration" not in fixation and config.gaze_map.profile == "paper"
    if profile_given and not random_exploration:
        return config
    correspondence = (params.correspondence if profile_given
                      else dataclasses.replace(params.correspondence, profile=config.gaze_map.profile))
    changed = dataclasses.replace(params, correspondence=correspondence,
                                  exploration="random" if random_exploration else params.exploration)
    fixation_config = dataclasses.replace(config.fixation, params=changed)
    return dataclasses.replace(config, fixation=fixation_config)


def resolve_backends(config: HeadConfig) -> dict[str, type]:
    """The backend classes the config names (imported now), by key path (`servo_bus`,
    `cameras.left`, `cameras.right`): what `headctl run` would fail to build refused here."""
    classes: dict[str, type] = {"servo_bus": servo_bus_backend(config.servo_bus, ServoBus)}
    for side in ("left", "right"):
        camera: CameraConfig = getattr(config.cameras, side)
        key_path = f"cameras.{side}"
        camera_class: type[Camera] = camera_backend(camera, Camera, key_path)
        if camera_class.capabilities.simulated and camera.backend != "sim":
            # The service gives a camera the simulated head (and the servos it renders) by this name.
            raise ConfigError(key_path=f"{key_path}.backend", value=camera.backend,
                              expected=f"sim: {camera_class.__name__} is the simulated camera, named sim")
        classes[key_path] = camera_class
    return classes


def check_backends(config: HeadConfig, classes: Mapping[str, type]) -> None:
    """Refuse keys the backends (`resolve_backends`) do not use and servo models they do not
    drive, rather than ignore them."""
    check_servo_bus_config(config.servo_bus, classes["servo_bus"])
    for side in ("left", "right"):
        key_path = f"cameras.{side}"
        check_camera_config(getattr(config.cameras, side), classes[key_path], key_path)


def check_fixation(config: HeadConfig) -> None:
    """The fixation settings against the eye joints (vergence) and the image (patches)."""
    joints = config.servo_bus.joints
    try:
        v_low, v_high = vergence_limits(joints)
    except ValueError:
        left, right = joints["left_eye"], joints["right_eye"]
        raise ConfigError(key_path="servo_bus.joints.right_eye", value=(right.min_angle, right.max_angle),
                          expected=f"limits that with left_eye's ({left.min_angle:g}, {left.max_angle:g}) allow "
                                   "some vergence (symmetric eyes: left_eye = v/2, right_eye = -v/2)") from None
    wanted = config.fixation.vergence_range
    if wanted is not None and not (v_low <= wanted[0] and wanted[1] <= v_high):
        raise ConfigError(key_path="fixation.vergence_range", value=wanted,
                          expected=f"[low, high] within [{v_low:g}, {v_high:g}] deg, the vergence the eye joints' "
                                   "limits allow")
    width, height = config.image_size
    params = config.fixation.params
    for key_path, (w, h) in (("fixation.vergence_patch_size", params.vergence_patch_size),
                             ("fixation.correspondence.patch_size", params.correspondence.patch_size)):
        if w > width or h > height:
            raise ConfigError(key_path=key_path, value=(w, h),
                              expected=f"a patch within the {width} x {height} image")
    search = params.vergence_search_px
    if search is not None and search > width:
        raise ConfigError(key_path="fixation.vergence_search_px", value=search,
                          expected=f"at most the image width ({width} px)")


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
    for side in sim_cams:
        eye = getattr(cameras, side).eye
        if eye is None:
            raise ConfigError(key_path=f"cameras.{side}.eye", missing=True,
                              expected="left or right: which eye of the simulated head the camera is")
        if servo_bus is not None and eye != side:
            raise ConfigError(key_path=f"cameras.{side}.eye", value=eye,
                              expected=f"{side!r}: cameras.{side} is the head's {side} eye")
    if sim_cams:
        for key in ("width", "height", "lens", "seed", "image"):
            if getattr(cameras.left, key) != getattr(cameras.right, key):
                raise ConfigError(key_path=f"cameras.right.{key}", value=getattr(cameras.right, key),
                                  expected=f"{getattr(cameras.left, key)!r} like cameras.left: "
                                           "both eyes of the simulated head see one scene through one lens")


# --- what running needs of this machine --------------------------------------------------------
def check_runtime(config: HeadConfig) -> None:
    """What `headctl run` needs of this machine beyond the file, checked before anything starts
    (and by `headctl check`): a state directory that exists as a writable directory or can be
    created, and a log file (if any) whose directory exists and that can be written.
    ConfigError naming the file and the key; nothing is left behind."""
    try:
        _check_state_dir(config.state_dir)
        if config.logging.file is not None:
            _check_log_file(config.logging.file)
    except ConfigError as err:
        if err.file is None:
            err.file = config.path
        raise


def _existing_ancestor(path: Path) -> tuple[Path, os.stat_result]:
    """The nearest of `path` and its parents that exists, and its stat (OSError: it cannot be
    looked at)."""
    probe = path
    while True:
        try:
            return probe, os.stat(probe)
        except (FileNotFoundError, NotADirectoryError):
            if probe.parent == probe:
                raise
            probe = probe.parent


def _check_state_dir(state_dir: Path) -> None:
    def refused(why: str) -> ConfigError:
        return ConfigError(key_path="state_dir", value=str(state_dir),
                           expected=f"a writable directory, or one that can be created ({why})")

    try:
        found, st = _existing_ancestor(state_dir)
    except (OSError, ValueError) as err:
        raise refused(getattr(err, "strerror", None) or str(err)) from None
    if not stat.S_ISDIR(st.st_mode):
        raise refused(f"{found} is a file" if found == state_dir else f"{found} is a file, not a directory")
    why = _cannot_create_in(found)
    if why is not None:
        raise refused(f"cannot create anything in {found}: {why}")


def _check_log_file(file: str) -> None:
    path = Path(file)

    def refused(why: str) -> ConfigError:
        return ConfigError(key_path="logging.file", value=file,
                           expected=f"a file that can be written, in an existing directory ({why})")

    try:
        st = os.stat(path)
    except FileNotFoundError:
        st = None
    except (OSError, ValueError) as err:
        raise refused(getattr(err, "strerror", None) or str(err)) from None
    if st is not None:
        if stat.S_ISDIR(st.st_mode):
            raise refused(f"{path} is a directory")
        if stat.S_ISFIFO(st.st_mode):
            raise refused(f"{path} is a pipe: opening it would wait for a reader")
        try:
            with open(path, "ab"):  # appends nothing: what the log handler does first
                pass
        except OSError as err:
            raise refused(f"{path}: {err.strerror}") from None
        return
    folder = path.parent
    try:
        folder_st = os.stat(folder)
    except OSError as err:
        raise refused(f"{folder}: {err.strerror}") from None
    if not stat.S_ISDIR(folder_st.st_mode):
        raise refused(f"{folder} is not a directory")
    why = _cannot_create_in(folder)
    if why is not None:
        raise refused(f"cannot create {path.name} in {folder}: {why}")


def _cannot_create_in(folder: Path) -> str | None:
    """Why nothing can be created in `folder`, or None. Tried, not judged from the mode bits
    (root passes those everywhere, a read-only mount or /proc does not): a directory is made
    there and removed at once."""
    try:
        probe = tempfile.mkdtemp(prefix=".headctl-check-", dir=folder)
    except OSError as err:
        return err.strerror or str(err)
    try:
        os.rmdir(probe)
    except OSError:
        log.warning("could not remove %s after checking that %s is writable", probe, folder)
    return None
