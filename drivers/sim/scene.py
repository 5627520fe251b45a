"""The simulated head's world and its renderer: a textured room seen through fish-eye lenses.

This module owns the scene (a room and boxes in it, every face textured from a seed) and
the ray caster that renders what an eye sees from its pose. It is shared by both eyes, so a
stereo pair is rendered from one scene, and by `SimulatedCamera` and any synchronous user
(`StereoRenderer.render(joints)`: both images, no threads).

Geometry comes from a head model passed in (`HeadGeometry`; `calib_free.sim.head_model.HeadModel` is
one): its lenses' `unproject` gives each pixel's ray once, its `eye_frames_from_joints`
gives each eye's rotation and optical centre per frame. `drivers` never imports
`calib_free` (layers: drivers know nothing above them); the service hands the model in.

World frame: x forward, y left, z up, metres. Everything is an axis-aligned box, so each
ray meets a face through the slab test: one compiled pass over the pixels a frame
(`drivers.sim.ray_cast`), then one `cv2.remap` of a texture atlas.
"""
from __future__ import annotations

import dataclasses
import logging
import threading
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Literal, Protocol

import cv2
import numpy as np

from drivers.servo.joints import JOINTS
from drivers.sim.eye_pair import EyePair
from drivers.sim.ray_cast import atlas_maps
from drivers.sim.room_light import CONSTANT_LIGHT, Illumination
from drivers.sim.textures import PhotoSet, photo_set, photo_texture

log = logging.getLogger(__name__)

TextureKind = Literal["rich", "checker", "stripes", "uniform", "photo"]
ROOMS = ("generated", "photos")  # the rooms `shared_scene` builds: `default_boxes`, `photo_boxes`
_BORDER_PX = 2  # replicated texels around each face so bilinear sampling never bleeds
_ATLAS_WIDTH = 4096


class Lens(Protocol):
    @property
    def width(self) -> int: ...
    @property
    def height(self) -> int: ...

    def unproject(self, uv: np.ndarray) -> np.ndarray: ...
    def project(self, points_cam: np.ndarray) -> tuple[np.ndarray, np.ndarray]: ...


class SceneMotion(Protocol):
    """What moves in a scene (`drivers.sim.motion.SceneMotion`): each box's translation at a
    time of the clock (None: now)."""

    def box_offsets(self, time_s: float | None = None) -> np.ndarray | None:
        """(boxes, 3) metres each box is moved from where the scene placed it; None: none moves.
        A row of NaN: that box is out of the world (not drawn)."""


class HeadGeometry(Protocol):
    """What the renderer needs of a head model (`calib_free.sim.head_model.HeadModel` has it)."""

    @property
    def lens_left(self) -> Lens: ...
    @property
    def lens_right(self) -> Lens: ...

    def eye_frames_from_joints(self, pan: float, tilt: float, left_eye: float,
                               right_eye: float) -> list[tuple[np.ndarray, np.ndarray]]: ...


@dataclass(frozen=True)
class Box:
    """An axis-aligned box; `inside` for the room (seen from within)."""

    name: str
    lo: tuple[float, float, float]
    hi: tuple[float, float, float]
    texture: TextureKind = "rich"
    texels_per_m: float = 600.0
    inside: bool = False


@dataclass(frozen=True)
class Marker:
    """A disc painted on a face at a known world point (tests locate it in the images)."""

    point: tuple[float, float, float]
    radius_m: float
    colour_bgr: tuple[int, int, int] = (0, 0, 255)


def default_boxes() -> list[Box]:
    """The default room: walls from 0.5 m (a partition) to 3 m (the far wall), objects between.

    Rich and nearly uniform surfaces both, and a periodic one, so that correspondence can
    fail where the paper's figure 4 shows it does (uniform and repetitive areas).
    """
    return [
        Box("room", (-1.0, -1.0, -0.7), (3.0, 1.4, 1.1), "rich", 260.0, inside=True),
        Box("partition", (0.5, -1.0, -0.7), (0.52, -0.38, 0.45), "uniform", 500.0),
        Box("crate", (0.8, 0.18, -0.32), (1.0, 0.45, 0.0), "rich", 1000.0),
        Box("cabinet", (1.4, -0.55, -0.7), (1.7, -0.12, 0.2), "checker", 700.0),
        Box("cupboard", (2.0, 0.5, -0.7), (2.3, 0.95, 0.5), "uniform", 500.0),
        Box("pillar", (2.45, -0.25, -0.7), (2.55, -0.12, 1.1), "stripes", 600.0),
    ]


def photo_boxes() -> list[Box]:
    """The photo room: the default room's geometry (walls from 0.5 m to 3 m, objects between),
    every surface papered with photographs (`drivers.sim.textures`)."""
    return [dataclasses.replace(box, texture="photo", texels_per_m=max(300.0, box.texels_per_m))
            for box in default_boxes()]


# --- textures ----------------------------------------------------------------------------
def _texture(kind: TextureKind, rng: np.random.Generator, height: int, width: int, texels_per_m: float) -> np.ndarray:
    """A float32 grey texture in 0..255: rich, periodic or nearly uniform."""
    if kind == "uniform":
        # Nearly uniform: one grey with a faint, smooth variation (a textureless wall).
        base = float(rng.uniform(120, 200))
        faint = cv2.resize(rng.standard_normal((4, 4)).astype(np.float32), (width, height),
                           interpolation=cv2.INTER_CUBIC)
        return base + 1.5 * faint
    if kind == "checker":
        cell = max(2, int(round(0.05 * texels_per_m)))
        yy, xx = np.indices((height, width))
        board = ((yy // cell + xx // cell) % 2).astype(np.float32)
        return 60 + 130 * board + rng.normal(0, 4, (height, width)).astype(np.float32)
    if kind == "stripes":
        period = max(3.0, 0.04 * texels_per_m)
        xx = np.arange(width, dtype=np.float32)
        row = 128 + 90 * np.sign(np.sin(2 * np.pi * xx / period))
        return np.repeat(row[None, :], height, axis=0) + rng.normal(0, 3, (height, width)).astype(np.float32)
    # Rich: value noise over several octaves plus random rectangles (edges and corners).
    out = np.zeros((height, width), np.float32)
    for cell_m, amplitude in ((0.4, 50.0), (0.15, 40.0), (0.05, 30.0), (0.015, 20.0)):
        cell_texels = max(1.0, cell_m * texels_per_m)
        small = rng.standard_normal((int(height / cell_texels) + 2, int(width / cell_texels) + 2)).astype(np.float32)
        out += amplitude * cv2.resize(small, (width, height), interpolation=cv2.INTER_CUBIC)
    for _ in range(max(4, int(height * width / (0.1 * texels_per_m) ** 2 / 4))):
        x0, y0 = int(rng.integers(0, width)), int(rng.integers(0, height))
        size = int(rng.integers(2, max(3, int(0.08 * texels_per_m))))
        cv2.rectangle(out, (x0, y0), (x0 + size, y0 + int(rng.integers(2, size + 2))),
                      float(rng.uniform(-90, 90)), thickness=-1)
    return 128 + out


@dataclass
class _Face:
    box: int
    axis: int  # normal axis
    side: int  # 0: the face at lo, 1: at hi
    u_axis: int
    v_axis: int
    lo_uv: tuple[float, float]
    hi_uv: tuple[float, float]
    size_px: tuple[int, int]  # (width, height) in texels
    origin_px: tuple[int, int] = (0, 0)  # where the face's texel (0, 0) sits in the atlas


class Scene:
    """Boxes with textured faces packed into one atlas, deterministic for a seed. `motion`, if
    set, moves boxes (their texture with them) at each frame rendered. `light` is the room's
    relative illumination over an exposure (`drivers.sim.room_light`), which a camera
    multiplies the rendered radiance by.

    Faces of texture "photo" are papered from `photos` (default: scikit-image's photographs,
    `drivers.sim.textures.bundled_photos`)."""

    def __init__(self, boxes: Sequence[Box] | None = None, seed: int = 0, colour: bool = True,
                 markers: Sequence[Marker] = (), photos: PhotoSet | None = None) -> None:
        self.boxes = list(boxes if boxes is not None else default_boxes())
        if not self.boxes or not self.boxes[0].inside or any(b.inside for b in self.boxes[1:]):
            raise ValueError("a scene needs exactly one room (inside=True), first in the list")
        if photos is None and any(b.texture == "photo" for b in self.boxes):
            photos = photo_set(None)
        self.photos = photos
        self.seed = seed
        self.colour = colour
        self.motion: SceneMotion | None = None  # what moves (drivers.sim.motion), if anything
        self.light: Illumination = CONSTANT_LIGHT  # how bright the room is (drivers.sim.room_light)
        self.lo = np.array([b.lo for b in self.boxes], dtype=np.float32)
        self.hi = np.array([b.hi for b in self.boxes], dtype=np.float32)
        self.faces = self._layout()
        self.atlas = self._paint(np.random.default_rng(seed))
        for marker in markers:
            self._paint_marker(marker)
        # What the renderer samples: OpenCV's remap has a much faster path for four
        # channels than for three, so colour is sampled from BGRA and the alpha dropped.
        self.sampling_atlas = cv2.cvtColor(self.atlas, cv2.COLOR_BGR2BGRA) if colour else self.atlas
        self._tables()

    # -- layout and painting ---------------------------------------------------------------
    def _layout(self) -> list[_Face]:
        faces = []
        for b, box in enumerate(self.boxes):
            for axis in range(3):
                u_axis, v_axis = [a for a in range(3) if a != axis]
                for side in range(2):
                    lo_uv = (box.lo[u_axis], box.lo[v_axis])
                    hi_uv = (box.hi[u_axis], box.hi[v_axis])
                    size = tuple(max(2, int(round((h - l) * box.texels_per_m))) for l, h in zip(lo_uv, hi_uv))
                    faces.append(_Face(b, axis, side, u_axis, v_axis, lo_uv, hi_uv, size))  # type: ignore[arg-type]
        # Shelf packing, tallest first.
        x = y = shelf = 0
        for face in sorted(faces, key=lambda f: -f.size_px[1]):
            w, h = face.size_px[0] + 2 * _BORDER_PX, face.size_px[1] + 2 * _BORDER_PX
            if w > _ATLAS_WIDTH:
                raise ValueError(f"box {self.boxes[face.box].name!r}: face too large for the atlas; lower texels_per_m")
            if x + w > _ATLAS_WIDTH:
                x, y, shelf = 0, y + shelf, 0
            face.origin_px = (x + _BORDER_PX, y + _BORDER_PX)
            x += w
            shelf = max(shelf, h)
        self._atlas_height = y + shelf
        if self._atlas_height >= 32767:  # cv2.remap's limit on source size
            raise ValueError("scene atlas too tall; lower texels_per_m")
        return faces

    def _paint(self, rng: np.random.Generator) -> np.ndarray:
        channels = 3 if self.colour else 1
        atlas = np.zeros((self._atlas_height, _ATLAS_WIDTH, channels), np.float32)
        # Shading by face orientation, so box edges show even between similar textures.
        shade = {(2, 0): 0.75, (2, 1): 0.9, (0, 0): 1.0, (0, 1): 1.0, (1, 0): 0.88, (1, 1): 0.82}
        for face in self.faces:
            box = self.boxes[face.box]
            w, h = face.size_px
            if box.texture == "photo":
                assert self.photos is not None  # set in __init__ when a box is papered with photos
                bgr = photo_texture(self.photos, rng, h, w, box.texels_per_m) * shade[(face.axis, face.side)]
                rgb = bgr if self.colour else cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY)
            else:
                grey = _texture(box.texture, rng, h, w, box.texels_per_m) * shade[(face.axis, face.side)]
                # A faint tint per box (saturation kept low: a pure red marker stays unique).
                tint = 1.0 + rng.uniform(-0.08, 0.08, channels) if self.colour else np.ones(1)
                rgb = np.clip(grey[:, :, None] * tint[None, None, :].astype(np.float32), 0, 255)
            padded = cv2.copyMakeBorder(rgb, _BORDER_PX, _BORDER_PX, _BORDER_PX, _BORDER_PX, cv2.BORDER_REPLICATE)
            if padded.ndim == 2:
                padded = padded[:, :, None]
            x0, y0 = face.origin_px
            atlas[y0 - _BORDER_PX:y0 + h + _BORDER_PX, x0 - _BORDER_PX:x0 + w + _BORDER_PX] = padded
        return np.ascontiguousarray(np.clip(atlas, 0, 255).astype(np.uint8).squeeze())

    def _face_at(self, point: np.ndarray) -> _Face:
        for face in self.faces:
            box = self.boxes[face.box]
            plane = (box.lo, box.hi)[face.side][face.axis]
            inside = all(box.lo[a] - 1e-9 <= point[a] <= box.hi[a] + 1e-9 for a in (face.u_axis, face.v_axis))
            if abs(point[face.axis] - plane) < 1e-6 and inside:
                return face
        raise ValueError(f"marker point {tuple(point)} lies on no face of the scene")

    def _texel(self, face: _Face, point: np.ndarray) -> tuple[float, float]:
        """Atlas (x, y) of a point on `face`: texel centres at integers, as cv2.remap samples."""
        (su, ou), (sv, ov) = self._face_coefficients(face)
        return float(point[face.u_axis] * su + ou), float(point[face.v_axis] * sv + ov)

    def _face_coefficients(self, face: _Face) -> tuple[tuple[float, float], tuple[float, float]]:
        """Atlas x = su * P[u_axis] + ou and y = sv * P[v_axis] + ov, for points on the face."""
        (lu, lv), (hu, hv) = face.lo_uv, face.hi_uv
        w, h = face.size_px
        su, sv = w / (hu - lu), h / (hv - lv)
        x0, y0 = face.origin_px
        ou = x0 - lu * su - 0.5
        if face.v_axis == 2:  # rows run down while z runs up: textures stand upright
            return (su, ou), (-sv, y0 + hv * sv - 0.5)
        return (su, ou), (sv, y0 - lv * sv - 0.5)

    def _paint_marker(self, marker: Marker) -> None:
        point = np.asarray(marker.point, dtype=float)
        face = self._face_at(point)
        cx, cy = self._texel(face, point)
        radius = marker.radius_m * self.boxes[face.box].texels_per_m
        x0, x1 = int(np.floor(cx - radius - 2)), int(np.ceil(cx + radius + 2))
        y0, y1 = int(np.floor(cy - radius - 2)), int(np.ceil(cy + radius + 2))
        yy, xx = np.mgrid[y0:y1 + 1, x0:x1 + 1]
        # Anti-aliased coverage: its centroid is the disc's centre to well under a texel.
        cover = np.clip(radius + 0.5 - np.hypot(xx - cx, yy - cy), 0.0, 1.0)
        patch = self.atlas[y0:y1 + 1, x0:x1 + 1].astype(np.float32)
        colour = np.array(marker.colour_bgr if self.colour else [np.mean(marker.colour_bgr)], np.float32)
        if patch.ndim == 2:
            patch = patch[:, :, None]
        mixed = patch * (1 - cover[:, :, None]) + colour[None, None, :] * cover[:, :, None]
        self.atlas[y0:y1 + 1, x0:x1 + 1] = np.round(mixed).astype(np.uint8).squeeze()

    def _tables(self) -> None:
        """Per-face lookup tables the renderer gathers from, indexed by face id."""
        n = len(self.faces)
        self.u_axis = np.array([f.u_axis for f in self.faces], np.intp)
        self.v_axis = np.array([f.v_axis for f in self.faces], np.intp)
        coefficients = np.array([self._face_coefficients(f) for f in self.faces], np.float32)  # (n, 2, 2)
        self.su, self.ou = coefficients[:, 0, 0].copy(), coefficients[:, 0, 1].copy()
        self.sv, self.ov = coefficients[:, 1, 0].copy(), coefficients[:, 1, 1].copy()
        assert n == 6 * len(self.boxes)


def face_id(box: int, axis: int, side: int) -> int:
    return 6 * box + 2 * axis + side


# --- rendering ---------------------------------------------------------------------------
class EyeRenderer:
    """Renders one lens's view of a scene from an eye pose (R camera-from-world, centre).

    Per frame: rotate the precomputed rays (cv2.transform), intersect the room (nearest exit
    plane) and each box (slab entry) pixel by pixel in float32 (`drivers.sim.ray_cast`), then
    sample the atlas with one cv2.remap. A box is only tested inside the image rectangle its
    edges project to (its silhouette is bounded by its projected edges), which keeps far
    objects cheap.
    """

    _EDGE_SAMPLES = 4  # points per box edge: a projected edge bends well under the margin between them
    _MARGIN_PX = 3

    def __init__(self, lens: Lens, scene: Scene) -> None:
        self.lens, self.scene = lens, scene
        self.width, self.height = int(lens.width), int(lens.height)
        vv, uu = np.mgrid[0:self.height, 0:self.width]
        uv = np.column_stack([uu.ravel(), vv.ravel()]).astype(float)
        rays = lens.unproject(uv)
        # Pixels outside the lens's image circle (beyond its maximum angle) stay black.
        back, seen = lens.project(rays)
        self.valid = (seen & (np.abs(back - uv).max(axis=1) < 0.05)).reshape(self.height, self.width)
        self.rays_cam = np.ascontiguousarray(rays.reshape(self.height, self.width, 3), dtype=np.float32)
        # Per-face tables, indexed by face id (6 per box, at most 256 faces).
        if len(scene.faces) > 256:
            raise ValueError(f"scene has {len(scene.boxes)} boxes; at most 42 are supported")
        self._lut = {name: np.zeros(256, np.float32) for name in ("su", "ou", "sv", "ov")}
        for name, table in self._lut.items():
            table[:len(scene.faces)] = getattr(scene, name)
        self._lut["normal"] = np.zeros(256, np.uint8)
        self._lut["normal"][:len(scene.faces)] = [f.axis for f in scene.faces]
        self._face_axes = np.array([(f.u_axis, f.v_axis) for f in scene.faces], np.intp)
        self._outside = np.ascontiguousarray(~self.valid)  # beyond the image circle: sampled off the atlas
        # Sample points along every box's edges, all boxes in one array (one projection a frame).
        self._edge_points = np.concatenate(
            [self._box_edge_points(b) for b in range(1, len(scene.boxes))] or [np.zeros((0, 3))])

    def _box_edge_points(self, b: int) -> np.ndarray:
        lo, hi = self.scene.lo[b].astype(float), self.scene.hi[b].astype(float)
        corners = np.array([[(lo, hi)[i >> k & 1][k] for k in range(3)] for i in range(8)])
        s = np.linspace(0.0, 1.0, self._EDGE_SAMPLES)[:, None]
        edges = [corners[i] + s * (corners[j] - corners[i])
                 for i in range(8) for j in range(8) if i < j and bin(i ^ j).count("1") == 1]
        return np.concatenate(edges)

    def _footprints(self, rotation: np.ndarray, centre: np.ndarray,
                    shift: np.ndarray | None = None) -> list[tuple[slice, slice] | None]:
        """For each box after the room: the image rows/columns it can cover, None if none
        (everything when a box comes near the camera or the lens's limit: no safe bound)."""
        n_boxes = len(self.scene.boxes) - 1
        if n_boxes == 0:
            return []
        points = self._edge_points
        if shift is not None:  # moving boxes: their edges where they are now
            points = points + np.repeat(shift[1:], len(points) // n_boxes, axis=0)
        cam = (points - centre) @ np.asarray(rotation, float).T
        uv = self.lens.project(cam)[0].reshape(n_boxes, -1, 2)
        cam = cam.reshape(n_boxes, -1, 3)
        unsure = ((cam[:, :, 2] < 0.05) | (np.hypot(cam[:, :, 0], cam[:, :, 1]) > 5.0 * cam[:, :, 2])).any(axis=1)
        lo = (np.floor(uv.min(axis=1)).astype(int) - self._MARGIN_PX).clip(0, None)
        hi = np.ceil(uv.max(axis=1)).astype(int) + self._MARGIN_PX + 1
        windows: list[tuple[slice, slice] | None] = []
        for box in range(n_boxes):
            if unsure[box]:
                windows.append((slice(0, self.height), slice(0, self.width)))
                continue
            (c0, r0), (c1, r1) = lo[box], (min(hi[box, 0], self.width), min(hi[box, 1], self.height))
            windows.append((slice(r0, r1), slice(c0, c1)) if c0 < c1 and r0 < r1 else None)
        return windows

    def render(self, rotation: np.ndarray, centre: np.ndarray, time_s: float | None = None) -> np.ndarray:
        """The image (H, W) grey or (H, W, 3) BGR seen from camera-from-world `rotation` at `centre`,
        the moving boxes where they are at `time_s` on the scene's clock (None: now)."""
        scene = self.scene
        world_from_cam = np.asarray(rotation, np.float32).T
        directions = cv2.transform(self.rays_cam, world_from_cam)  # (H, W, 3)
        o = np.asarray(centre, np.float32)
        # A box moved by s is met where the ray from o - s meets it unmoved.
        shift = scene.motion.box_offsets(time_s) if scene.motion is not None else None
        absent = None
        if shift is not None and np.isnan(shift).any():  # boxes out of the world: not drawn
            absent = np.isnan(shift).any(axis=1)
            shift = np.where(absent[:, None], np.float32(0.0), shift)
        windows = np.zeros((len(scene.boxes), 4), np.int64)  # rows and columns each box may cover
        for b, window in enumerate(self._footprints(rotation, centre, shift), start=1):
            if window is not None and (absent is None or not absent[b]):
                rows, columns = window
                windows[b] = rows.start, rows.stop, columns.start, columns.stop
        # Atlas coordinates. A face's in-plane axes are (y, z), (x, z) or (x, y) by its normal, and
        # atlas x = su * (o_u + t d_u) + ou = (su t) d_u + (su o_u + ou): the per-face constant
        # folds the eye's position in, so per pixel it is one product and one sum per map.
        faces = self._face_axes
        offset_x = np.zeros(256, np.float32)
        offset_y = np.zeros(256, np.float32)
        # Each face's eye position relative to its box (a moving box carries its texture).
        eye_in_box = np.broadcast_to(o, (len(scene.boxes), 3)) if shift is None else o - shift
        origin = np.repeat(eye_in_box, 6, axis=0)
        lut, n = self._lut, len(faces)
        offset_x[:n] = lut["su"][:n] * origin[np.arange(n), faces[:, 0]] + lut["ou"][:n]
        offset_y[:n] = lut["sv"][:n] * origin[np.arange(n), faces[:, 1]] + lut["ov"][:n]
        map_x = np.empty((self.height, self.width), np.float32)
        map_y = np.empty((self.height, self.width), np.float32)
        atlas_maps(directions, o, scene.lo, scene.hi, np.ascontiguousarray(eye_in_box, np.float32), windows,
                   lut["normal"], lut["su"], lut["sv"], offset_x, offset_y, self._outside, map_x, map_y)
        image = cv2.remap(scene.sampling_atlas, map_x, map_y, cv2.INTER_LINEAR,
                          borderMode=cv2.BORDER_CONSTANT, borderValue=0)
        return cv2.cvtColor(image, cv2.COLOR_BGRA2BGR) if image.ndim == 3 else image


def joints_tuple(joints: Mapping[str, float]) -> tuple[float, float, float, float]:
    """(pan, tilt, left_eye, right_eye) in degrees from a mapping, naming a missing joint."""
    try:
        return tuple(float(joints[k]) for k in JOINTS)  # type: ignore[return-value]
    except KeyError as err:
        raise ValueError(f"joint angles {dict(joints)!r} lack {err.args[0]!r}: expected {', '.join(JOINTS)}") from err


@dataclass
class StereoRenderer:
    """Both eyes of a head model in one scene: `render(joints)` gives (left, right) at once, on
    the caller's thread. With `parallel`, the right eye renders on one worker thread while
    the caller renders the left (numpy and OpenCV release the GIL): faster on an idle
    multi-core machine, slower on a busy one. The worker is this object's: close() it or
    use `with`."""

    head: HeadGeometry
    scene: Scene
    parallel: bool = False
    eyes: tuple[EyeRenderer, EyeRenderer] = field(init=False)

    def __post_init__(self) -> None:
        self.eyes = (EyeRenderer(self.head.lens_left, self.scene), EyeRenderer(self.head.lens_right, self.scene))
        self._pair: EyePair[np.ndarray] = EyePair(self.parallel, "sim-render")

    def render(self, joints: Mapping[str, float], time_s: float | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Both eyes at `joints`, the moving boxes where they are at `time_s` (None: now)."""
        (r_left, c_left), (r_right, c_right) = self.head.eye_frames_from_joints(*joints_tuple(joints))
        return self._pair.render(lambda: self.eyes[0].render(r_left, c_left, time_s),
                                 lambda: self.eyes[1].render(r_right, c_right, time_s))

    def close(self) -> None:
        self._pair.close()

    def __enter__(self) -> "StereoRenderer":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


_SCENES: dict[tuple[int, bool, str, str | None], Scene] = {}
_SCENES_LOCK = threading.Lock()


def shared_scene(seed: int, colour: bool, room: str = "generated", textures: str | None = None) -> Scene:
    """A room for a seed, built once per process: both eyes' cameras share it.

    `room`: "generated" (`default_boxes`) or "photos" (`photo_boxes`, papered with the
    photographs of the folder `textures`, or scikit-image's when None)."""
    if room not in ROOMS:
        raise ValueError(f"room {room!r}: expected one of {', '.join(ROOMS)}")
    if room == "generated" and textures is not None:
        raise ValueError(f"textures {textures!r} need the photo room (room 'photos')")
    with _SCENES_LOCK:
        key = (seed, colour, room, textures)
        if key not in _SCENES:
            if room == "photos":
                _SCENES[key] = Scene(photo_boxes(), seed=seed, colour=colour, photos=photo_set(textures))
            else:
                _SCENES[key] = Scene(seed=seed, colour=colour)
            log.debug("built the %s room for seed %d (%s)", room, seed, "colour" if colour else "grey")
        return _SCENES[key]
