"""The typed settings of a camera and of a head's pair of cameras (the `cameras:` section).

`CameraConfig` is read from a plain mapping (what YAML gives) by `drivers.config.reader`: errors are
`CameraConfigError`s naming the key path, the value and what was expected. This is plain data:
whether the backend a config names uses the keys it gives (`CameraConfig.set_keys`) is
checked by the backend table (`drivers.backends.check_camera_config`): a key the backend does
not use is refused rather than ignored. Sizes are bounded before anything is allocated.
"""
from __future__ import annotations

import dataclasses
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar, Literal

from drivers.config.reader import check_settings, read_config, setting
from drivers.errors import CameraConfigError
from drivers.sim.passers_by import PassersByConfig
from drivers.sim.room_light import LightConfig
from drivers.sim.camera_effects.sensor_config import SensorConfig

ImageMode = Literal["grey", "colour"]

# What a config may ask of a camera, bounded before anything is allocated: an image side, an
# image (the gaze map, correspondence and the simulated renderer work on whole images; the
# simulated eye needs about 170 bytes a pixel while it starts), and the frames a camera holds,
# (history + buffers) x width x height x 3 bytes at most.
MAX_IMAGE_SIDE = 16384
MAX_IMAGE_PIXELS = 1 << 24  # 16.8 MP, 4096 x 4096
MAX_FRAME_BYTES = 1 << 30  # 1 GiB
MAX_FRAMES = 64  # history, buffers


TimingModel = Literal["ideal", "free_running"]


@dataclass(frozen=True)
class FrameTimingConfig:
    """When a simulated camera's frames are exposed, stamped and delivered (`timing:` of a
    simulated camera; `drivers.sim.camera_effects.frame_timing`). `model` names a preset of typical values
    (`ideal`: both eyes on one grid, as hardware-triggered cameras; `free_running`: two USB
    webcams, each on its own clock); a key given overrides the preset's value, None keeps it."""

    model: TimingModel = "ideal"
    phase_s: float | None = setting(None, lo=0.0, hi=10.0, expected="a time in [0, 10] s")
    drift_ppm: float | None = setting(None, lo=-10_000.0, hi=10_000.0, expected="a rate error in [-10000, 10000] ppm")
    timestamp_jitter_s: float | None = setting(None, lo=0.0, hi=0.1, expected="a time in [0, 0.1] s")
    drop_rate: float | None = setting(None, lo=0.0, hi=0.5, expected="a fraction of frames in [0, 0.5]")
    late_rate: float | None = setting(None, lo=0.0, hi=1.0, expected="a fraction of frames in [0, 1]")
    late_s: float | None = setting(None, lo=0.0, hi=1.0, expected="a time in [0, 1] s")

    CONFIG_ERROR: ClassVar[type[CameraConfigError]] = CameraConfigError

    def __post_init__(self) -> None:
        check_settings(self)


@dataclass(frozen=True)
class CameraConfig:
    """The settings of one camera. None means "leave the camera's own value".

    `device`: V4L2 path, index or udev symlink (opencv). `id`, `serial`: the GenICam device
    id or serial number (aravis; one of them, or neither for the first camera found).
    `eye`: which eye of the simulated head (sim). `pixel_format`: Mono8, BayerRG8, RGB8...
    (aravis) or a FourCC such as MJPG, YUYV (opencv). `image`: frames delivered grey or colour
    (BGR). `gain_db` is in the camera's own gain unit (dB on most GenICam cameras).
    `exposure_control`: `auto` leaves the exposure to the camera (fixed by `exposure_us` if
    given); `lock_per_fixation` holds the camera's auto exposure and gain over each fixation
    (the service locks them before its first image and unlocks them after it), so the images
    before and after a saccade share one exposure; `manual` fixes it at `exposure_us`.
    """

    backend: str = "sim"
    device: str | int | None = setting(None, check=lambda d: not isinstance(d, int) or 0 <= d <= 65535,
                                       expected="a device path, or an index from 0 to 65535")
    id: str | None = None
    serial: str | None = None
    eye: Literal["left", "right"] | None = None
    pixel_format: str | None = None
    # The upper bounds (MAX_IMAGE_SIDE, MAX_IMAGE_PIXELS) are checked in __post_init__.
    width: int | None = setting(None, lo=2, expected="at least 2")
    height: int | None = setting(None, lo=2, expected="at least 2")
    fps: float | None = setting(None, check=lambda f: 0.01 <= f <= 10_000.0,
                                expected="a positive rate, from 0.01 to 10000 frames a second")
    exposure_us: float | None = setting(None, above=0.0, hi=1e8, expected="a positive time, at most 1e8 us (100 s)")
    gain_db: float | None = setting(None, lo=-1000.0, hi=1000.0)
    exposure_control: Literal["auto", "lock_per_fixation", "manual"] = "auto"
    image: ImageMode = "grey"
    history: int = setting(8, lo=2, hi=MAX_FRAMES, expected=f"at least 2 frames, at most {MAX_FRAMES}")
    buffers: int = setting(8, lo=2, hi=MAX_FRAMES, expected=f"at least 2 buffers, at most {MAX_FRAMES}")
    seed: int = setting(0, lo=0, expected="a seed >= 0")
    # The simulated head's lens; the kinds of calib_free.lens.LENS_KINDS (drivers cannot import it).
    lens: Literal["foveated", "equidistant", "equisolid"] = "foveated"
    noise_std: float = setting(0.0, lo=0.0, hi=255.0, expected="not negative, at most 255 grey levels")
    # The simulated camera's sensor and lens effects (a model's preset and overrides).
    sensor: SensorConfig = setting(SensorConfig())
    grab_timeout_s: float = setting(1.0, above=0.0, hi=60.0, expected="a positive time, at most 60 s")
    reconnect_backoff_max_s: float = setting(2.0, above=0.0, hi=3600.0, expected="a positive time, at most 3600 s")
    reconnect_give_up_s: float = setting(600.0, above=0.0, hi=604_800.0,
                                         expected="a positive time, at most 604800 s (a week)")
    # The simulated camera's frame timing (phase, clock drift, timestamp jitter, drops, late frames).
    timing: FrameTimingConfig = setting(default_factory=FrameTimingConfig)
    # The keys a mapping gave (set by the reader): a key given at its default value is still
    # refused by a backend that does not use it.
    given_keys: frozenset[str] = setting(frozenset(), source="given_keys", init=False, compare=False, repr=False)

    CONFIG_ERROR: ClassVar[type[CameraConfigError]] = CameraConfigError

    def __post_init__(self) -> None:
        check_settings(self)
        if self.exposure_control == "manual" and self.exposure_us is None:
            raise CameraConfigError(key_path="exposure_us", missing=True,
                                    expected="an exposure time in us: exposure_control: manual fixes the exposure "
                                             "at exposure_us")
        if self.exposure_control == "lock_per_fixation" and self.exposure_us is not None:
            raise CameraConfigError(key_path="exposure_control", value=self.exposure_control,
                                    expected=f"manual (or no exposure_us): exposure_us {self.exposure_us:g} fixes the "
                                             "exposure, so there is no auto exposure to hold")
        if self.id is not None and self.serial is not None:
            raise CameraConfigError(
                key_path="serial", value=self.serial,
                expected=f"no serial when id is given (id {self.id!r}): one of them names the camera")
        for key in ("width", "height"):
            side = getattr(self, key)
            if side is not None and side > MAX_IMAGE_SIDE:
                raise CameraConfigError(key_path=key, value=side, expected=f"at most {MAX_IMAGE_SIDE} pixels")
        if self.width is not None and self.height is not None:
            pixels = self.width * self.height
            if pixels > MAX_IMAGE_PIXELS:
                raise CameraConfigError(key_path="height", value=self.height,
                                        expected=f"an image of at most {MAX_IMAGE_PIXELS} pixels (4096 x 4096); "
                                                 f"{self.width} x {self.height} is {pixels}")
            frames = MAX_FRAME_BYTES // (3 * pixels)
            if self.history + self.buffers > frames:
                raise CameraConfigError(
                    key_path="history", value=self.history,
                    expected=f"history + buffers ({self.history} + {self.buffers}) of at most {frames} frames of "
                             f"{self.width} x {self.height} (the frames a camera holds stay within "
                             f"{MAX_FRAME_BYTES >> 20} MiB)")

    @classmethod
    def from_mapping(cls, data: Any, key_path: str = "camera") -> "CameraConfig":
        return read_config(cls, data, key_path)

    def set_keys(self) -> set[str]:
        """Keys given in the mapping, or whose value differs from the default."""
        return set(self.given_keys) | {f.name for f in dataclasses.fields(self)
                                       if f.init and getattr(self, f.name) != _default_of(f)}


def _default_of(f: dataclasses.Field[Any]) -> Any:
    """A field's default value, made by its factory when it has one (a nested section)."""
    if f.default_factory is not dataclasses.MISSING:
        return f.default_factory()
    return f.default


_PHOTO_SUFFIXES = (".jpg", ".jpeg", ".png")  # as drivers.sim.textures reads them


@dataclass(frozen=True)
class SceneConfig:
    """The simulated head's room (`cameras.scene`, simulated cameras only): the generated room
    (noise, checkerboards, stripes) or the photo room, papered with scikit-image's
    photographs or with those of the folder `textures` (`drivers.sim.textures`); its light
    (`drivers.sim.room_light`) and the people walking through it (`drivers.sim.passers_by`)."""

    room: Literal["generated", "photos"] | None = None  # None: photos when textures is given
    textures: str | None = None  # a folder of .jpg/.png photographs (~ and $VARS expanded)
    light: LightConfig = setting(default_factory=LightConfig)  # default: constant
    passers_by: PassersByConfig = setting(default_factory=PassersByConfig)  # default: none

    CONFIG_ERROR: ClassVar[type[CameraConfigError]] = CameraConfigError

    def __post_init__(self) -> None:
        check_settings(self)
        if self.textures is None:
            return
        if self.room == "generated":
            raise CameraConfigError(key_path="room", value=self.room,
                                    expected=f"photos (or no room): textures {self.textures!r} papers the photo room")
        folder = self.folder
        assert folder is not None
        try:
            found = folder.is_dir() and any(p.suffix.lower() in _PHOTO_SUFFIXES for p in folder.iterdir())
        except OSError as err:
            raise CameraConfigError(key_path="textures", value=self.textures,
                                    expected=f"a readable folder of photographs ({err.strerror})") from err
        if not found:
            raise CameraConfigError(key_path="textures", value=self.textures,
                                    expected=f"a folder holding .jpg, .jpeg or .png photographs ({folder}: "
                                             f"{'none there' if folder.is_dir() else 'no such folder'})")

    @property
    def kind(self) -> str:
        """The room: "generated" or "photos"."""
        return self.room or ("photos" if self.textures is not None else "generated")

    @property
    def folder(self) -> Path | None:
        """The folder of photographs, ~ and $VARS expanded (None: scikit-image's)."""
        return None if self.textures is None else Path(os.path.expandvars(self.textures)).expanduser()


@dataclass(frozen=True)
class StereoCamerasConfig:
    """The `cameras:` section of a head's config: a left and a right camera, and the pair's
    timestamp tolerance (None: half a frame period of the slower camera) and, for simulated
    cameras, the room they see (`scene`)."""

    left: CameraConfig
    right: CameraConfig
    tolerance_s: float | None = setting(None, lo=0.0)  # at most 10 s, checked in __post_init__
    scene: SceneConfig = setting(default_factory=SceneConfig)  # the simulated room

    CONFIG_ERROR: ClassVar[type[CameraConfigError]] = CameraConfigError

    def __post_init__(self) -> None:
        check_settings(self)
        if self.scene != SceneConfig():
            for side in ("left", "right"):
                if getattr(self, side).backend != "sim":
                    raise CameraConfigError(key_path="scene", value=dataclasses.asdict(self.scene),
                                            expected=f"no scene: cameras.{side} is not simulated (backend: sim), "
                                                     "and the scene is the simulated head's room")
        if self.tolerance_s is not None and self.tolerance_s > 10.0:
            raise CameraConfigError(key_path="tolerance_s", value=self.tolerance_s,
                                    expected="at most 10 s (a stereo pair is taken at one moment)")

    @classmethod
    def from_mapping(cls, data: Any, key_path: str = "cameras") -> "StereoCamerasConfig":
        return read_config(cls, data, key_path)
