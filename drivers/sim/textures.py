"""Photographs for the simulated room: where they come from, and how a face is papered with them.

A real lab has posters, bookshelves, carpets, brick, text and windows: repeated structure at
every scale, which generated noise does not have. The photo room papers its walls and
objects with photographs: by default a set that scikit-image ships inside its wheel (no
download at run time), each chosen for a licence that allows redistribution (CC0 or public
domain, per `skimage.data`'s documentation of each image); or every JPEG and PNG of a folder
the user names (`cameras.scene.textures`).

A face is papered like a wall of a lab: a material (brick, gravel, grass: the user's photos
too) repeated as wallpaper at a physical scale, then posters of other photographs at random
places and sizes, some of them small and repeated in a row (a shelf of alike books).
Everything is drawn from the scene's random generator: deterministic for a seed.
"""
from __future__ import annotations

import functools
import logging
import os
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from drivers.errors import ConfigError

log = logging.getLogger(__name__)

# scikit-image's bundled images whose licence allows redistribution and use (skimage.data's
# docstrings): materials repeated as wallpaper, and pictures hung as posters.
BUNDLED_MATERIALS = ("brick", "gravel", "grass")  # CC0 (cc0textures.com, DeviantArt CC0)
BUNDLED_PICTURES = (
    "camera",     # CC0, Lav Varshney
    "chelsea",    # CC0, Stefan van der Walt
    "coffee",     # CC0, Rachel Michetti
    "astronaut",  # public domain, NASA
    "rocket",     # public domain, SpaceX
    "text",       # public domain (Wikipedia, File:Corner.png)
)
PHOTO_SUFFIXES = (".jpg", ".jpeg", ".png")
MAX_PHOTOS = 256  # a folder's photographs read at most (sorted by name)
MAX_PHOTO_SIDE = 2048  # larger photographs are shrunk on load: a face never needs more
# Colour photographs are desaturated to this fraction of their saturation, so that a pure
# red, green or blue marker stays unique in the room (the geometry tests find them by colour).
SATURATION = 0.5
FINEST_DETAIL_M = 0.004  # the Gaussian sigma a face is low-passed with, metres


@dataclass(frozen=True)
class PhotoSet:
    """Photographs as BGR float32 images in 0..255: `materials` papered as repeated wallpaper,
    `pictures` hung as posters (a user's folder gives both the same list)."""

    materials: tuple[np.ndarray, ...]
    pictures: tuple[np.ndarray, ...]
    source: str  # what the set is, for logs: "scikit-image" or the folder

    def __post_init__(self) -> None:
        if not self.materials or not self.pictures:
            raise ValueError(f"photo set {self.source}: needs at least one material and one picture")


def _as_bgr(image: np.ndarray) -> np.ndarray:
    """A BGR float32 image, shrunk to MAX_PHOTO_SIDE, desaturated to SATURATION."""
    img = np.asarray(image)
    if img.dtype == bool:
        img = img.astype(np.uint8) * 255
    if img.ndim == 2:
        img = cv2.cvtColor(img.astype(np.uint8), cv2.COLOR_GRAY2BGR)
    elif img.shape[2] == 4:
        img = cv2.cvtColor(img, cv2.COLOR_BGRA2BGR)
    scale = MAX_PHOTO_SIDE / max(img.shape[:2])
    if scale < 1.0:
        img = cv2.resize(img, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA)
    bgr = img.astype(np.float32)
    grey = cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY)[:, :, None]
    return np.ascontiguousarray(grey + SATURATION * (bgr - grey))


@functools.lru_cache(maxsize=1)
def bundled_photos() -> PhotoSet:
    """The photographs scikit-image ships (read from its wheel once per process)."""
    try:
        import skimage.data as data
    except ImportError as err:  # a declared dependency; missing only in a broken install
        raise ConfigError(key_path="cameras.scene.room", value="photos",
                          expected="scikit-image installed (pip install scikit-image): the photo room's "
                                   "default photographs come from it") from err

    def load(name: str) -> np.ndarray:
        image = np.asarray(getattr(data, name)())
        if image.ndim == 3:  # scikit-image gives RGB
            image = image[:, :, ::-1]
        return _as_bgr(image)

    return PhotoSet(tuple(load(n) for n in BUNDLED_MATERIALS), tuple(load(n) for n in BUNDLED_PICTURES),
                    "scikit-image")


def folder_photos(folder: str | os.PathLike[str], key_path: str = "cameras.scene.textures") -> PhotoSet:
    """Every JPEG and PNG of `folder` (sorted by name, at most MAX_PHOTOS), as both materials and
    pictures. A folder that is missing, unreadable or holds no readable photograph is a
    ConfigError naming `key_path` and the path."""
    path = Path(folder).expanduser()
    if not path.is_dir():
        raise ConfigError(key_path=key_path, value=str(folder),
                          expected="a folder of photographs (.jpg, .jpeg, .png): no such folder")
    try:
        files = sorted(p for p in path.iterdir() if p.suffix.lower() in PHOTO_SUFFIXES and p.is_file())
    except OSError as err:
        raise ConfigError(key_path=key_path, value=str(folder),
                          expected=f"a readable folder of photographs ({err.strerror})") from err
    photos = []
    for file in files[:MAX_PHOTOS]:
        image = cv2.imread(str(file), cv2.IMREAD_COLOR)
        if image is None or min(image.shape[:2]) < 8:
            log.warning("%s: %s is not a readable photograph of at least 8 x 8 px; skipped", key_path, file)
            continue
        photos.append(_as_bgr(image))
    if not photos:
        raise ConfigError(key_path=key_path, value=str(folder),
                          expected="a folder holding at least one readable photograph (.jpg, .jpeg, .png)")
    if len(files) > MAX_PHOTOS:
        log.info("%s: %d photographs in %s, the first %d (by name) used", key_path, len(files), path, MAX_PHOTOS)
    return PhotoSet(tuple(photos), tuple(photos), str(path))


def photo_texture(photos: PhotoSet, rng: np.random.Generator, height: int, width: int,
                  texels_per_m: float) -> np.ndarray:
    """A face of `height` x `width` texels papered with photographs: BGR float32 in 0..255.

    Wallpaper: one material, a tile 0.4-1.2 m wide repeated across the face. Posters: about
    one per 0.3 m^2, each a picture 0.15-0.9 m wide at a random place, with its own
    brightness and contrast; one poster in four is a row of 2-6 small copies (books, tiles,
    labels: near repeats that correspondence must not confuse).
    """
    out = np.empty((height, width, 3), np.float32)
    material = photos.materials[int(rng.integers(len(photos.materials)))]
    tile_w = max(4, int(round(rng.uniform(0.4, 1.2) * texels_per_m)))
    tile = _resized(material, tile_w)
    reps = (-(-height // tile.shape[0]), -(-width // tile.shape[1]), 1)
    out[:] = np.tile(tile, reps)[:height, :width]
    area_m2 = height * width / texels_per_m**2
    for _ in range(int(rng.poisson(max(1.0, area_m2 / 0.3)))):
        picture = photos.pictures[int(rng.integers(len(photos.pictures)))]
        gain, offset = float(rng.uniform(0.7, 1.2)), float(rng.uniform(-30.0, 30.0))
        if rng.random() < 0.25:
            copies = int(rng.integers(2, 7))
            size = _resized(picture, max(4, int(round(rng.uniform(0.06, 0.2) * texels_per_m))))
            gap = int(rng.integers(0, max(1, size.shape[1] // 3)))
            x0, y0 = int(rng.integers(-size.shape[1], width)), int(rng.integers(-size.shape[0], height))
            for k in range(copies):
                _paste(out, size * gain + offset, x0 + k * (size.shape[1] + gap), y0)
        else:
            poster = _resized(picture, max(4, int(round(rng.uniform(0.15, 0.9) * texels_per_m))))
            x0 = int(rng.integers(-poster.shape[1] // 2, width))
            y0 = int(rng.integers(-poster.shape[0] // 2, height))
            _paste(out, poster * gain + offset, x0, y0)
    # The renderer samples texels at points (no mip-mapping), while a camera's pixel integrates
    # over its footprint: detail finer than a few millimetres (a pixel at 1-3 m) would alias
    # differently in every view, as no real image does, so the face is low-passed to that scale.
    blurred: np.ndarray = cv2.GaussianBlur(out, (0, 0), FINEST_DETAIL_M * texels_per_m)
    face: np.ndarray = np.clip(blurred, 0.0, 255.0)
    return face


def _resized(image: np.ndarray, width: int) -> np.ndarray:
    height = max(4, int(round(image.shape[0] * width / image.shape[1])))
    shrink = width < image.shape[1]
    return cv2.resize(image, (width, height), interpolation=cv2.INTER_AREA if shrink else cv2.INTER_CUBIC)


def _paste(canvas: np.ndarray, image: np.ndarray, x0: int, y0: int) -> None:
    """Paste `image` with its top-left at (x0, y0), clipped to the canvas."""
    h, w = image.shape[:2]
    cx0, cy0 = max(0, x0), max(0, y0)
    cx1, cy1 = min(canvas.shape[1], x0 + w), min(canvas.shape[0], y0 + h)
    if cx0 < cx1 and cy0 < cy1:
        canvas[cy0:cy1, cx0:cx1] = image[cy0 - y0:cy1 - y0, cx0 - x0:cx1 - x0]


def photo_set(textures: str | os.PathLike[str] | None, key_path: str = "cameras.scene.textures") -> PhotoSet:
    """The photographs of a photo room: a folder's (`textures`), else scikit-image's."""
    return bundled_photos() if textures is None else folder_photos(textures, key_path)

