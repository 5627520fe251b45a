"""Gaze map files: what a saved `GazeMap` holds on disk, and writing and reading it.

A map file is a numpy .npz archive (a zip of .npy arrays), read without pickles: `format`
(the file format's name and version), `params` (`GazeMapParams` as JSON), `grid`, the learning
state (`recent_errors`, `adaptations`, `long_run_error`, `memory`, `residual_scale`,
`surprised`), for a map with a polynomial part `polynomial_coef`, `polynomial_covariance` and
`polynomial_noise`, and for one that also fits it on the head's pose `pose_coef`,
`pose_covariance`, `pose_noise` and `fit_errors`. A map and its reloaded copy continue learning identically.
A file written before an entry existed still loads: its parameters take their profile's
values, the noise estimates their prior, and a pose-aware part absent from it starts from
the pose-free one (`GazeMap.derive_pose_polynomial`).

Writing is atomic (temp file, fsync, rename), so a crash leaves the old file or the new one,
never half of one; a crash can leave the temp file itself behind (`temporary_files` finds
them). Reading is in one place, `read_map`, which checks the whole file before it builds a
map, and before it allocates anything a header claims:

- the zip: a regular, non-empty file of bounded size, whose central directory is bounded
  (members, bytes; no ZIP64) before `zipfile` parses it; members stored or deflated, not
  encrypted, each no larger than its entry can be;
- the entries: exactly the expected names (no unknown, missing or duplicate one); each
  `.npy` header read on its own (version 1.0 or 2.0, bounded), its dtype and shape compared
  with what the parameters allow before its data is read, the data exactly as long as the
  header says; object dtypes (pickles) never;
- the values: parameters a `GazeMapParams` is made of, of the right types, finite and within
  what the map can run on; every array finite and of a bounded magnitude, counters
  non-negative integers.

Anything wrong raises `MapFileError` naming the file, the entry, what was found and what was
expected; no other exception leaves `read_map`.
"""
from __future__ import annotations

import dataclasses
import io
import json
import logging
import math
import os
import re
import stat
import struct
import tempfile
import zipfile
from pathlib import Path
from typing import IO, Any

import numpy as np

from calib_free.errors import MapFileError
from calib_free.map.gaze_map import GazeMap
from calib_free.map.params import GazeMapParams

log = logging.getLogger(__name__)

FILE_FORMAT = "calib_free.GazeMap/1"
# Entries every map file holds besides `format`; `surprised` may be absent (none pending).
REQUIRED_ENTRIES = frozenset({"params", "grid", "recent_errors", "adaptations", "long_run_error", "memory",
                              "residual_scale"})
OPTIONAL_ENTRIES = frozenset({"surprised"})
# ... those a map with a polynomial part (global_degree > 0) adds,
POLYNOMIAL_ENTRIES = frozenset({"polynomial_coef", "polynomial_covariance"})
POLYNOMIAL_OPTIONAL_ENTRIES = frozenset({"polynomial_noise"})  # absent: the prior noise
# ... and those of its pose-aware part (GazeMapParams.uses_pose): all, or none when it never
# learned (a sample with a pose derives it from the pose-free part).
POSE_ENTRIES = frozenset({"pose_coef", "pose_covariance", "pose_noise", "fit_errors"})
ALL_ENTRIES = (frozenset({"format"}) | REQUIRED_ENTRIES | OPTIONAL_ENTRIES | POLYNOMIAL_ENTRIES
               | POLYNOMIAL_OPTIONAL_ENTRIES | POSE_ENTRIES)

# What a map file may hold at most: far above any map a head uses (the default grid is
# 157,500 nodes, 3.8 MB), far below what would exhaust a machine's memory.
MAX_GRID_NODES = 1 << 24  # grid_shape's product: 400 MB of float64 for the three planes
MAX_IMAGE_SIDE = 1 << 16  # pixels
MAX_OUTPUT_RESOLUTION = 1 << 16  # cells per motor axis
MAX_ERROR_WINDOW = 10_000  # recent_errors' length at most
MAX_GLOBAL_DEGREE = 10  # 286 polynomial terms
MAX_POSE_TERMS = 286 + 14 * 35  # GazeMapParams' bounds: position degree 10, pose degree 4, cross degree 4
MAX_MAGNITUDE = 1e9  # no value a map holds comes near it; products of such values stay finite
MAX_ADAPTATIONS = 1 << 62
# residual_scale tracks the size of the map's residuals (output cells): never this small, and
# residuals divided by anything smaller could overflow a float when squared.
MIN_RESIDUAL_SCALE = 1e-100
MAX_FORMAT_CHARS = 64
MAX_PARAMS_CHARS = 8192
MAX_MEMBERS = 16  # a map file has at most 16
MAX_DIRECTORY_BYTES = 64 * 1024  # the zip's central directory (about 1 kB for a map file)
MAX_HEADER_BYTES = 1024  # an .npy header (128 bytes for each entry numpy writes)
_NPY_PREFIX_BYTES = 6 + 2 + 4  # magic string, version, header length (4 bytes in version 2.0)
_MEMBER_OVERHEAD = _NPY_PREFIX_BYTES + MAX_HEADER_BYTES


def _max_terms(degree: int) -> int:
    return (degree + 1) * (degree + 2) * (degree + 3) // 6


# The largest file those limits allow: the arrays, the texts (4 bytes a character), each
# member's headers, the directory.
MAX_FILE_BYTES = (8 * (3 * MAX_GRID_NODES + MAX_ERROR_WINDOW + 2 * _max_terms(MAX_GLOBAL_DEGREE) ** 2
                       + MAX_POSE_TERMS ** 2 + 3 * MAX_POSE_TERMS + 16)
                  + 4 * (MAX_FORMAT_CHARS + MAX_PARAMS_CHARS) + MAX_MEMBERS * (_MEMBER_OVERHEAD + 512)
                  + MAX_DIRECTORY_BYTES)

# write_map's temporary files: `<name>.<random>.tmp` (tempfile.mkstemp) and, while `.prev` is
# being replaced, `<name>.<random>.tmp.prev` (a hard link to the old file).
_TMP_PREFIX_SEPARATOR = "."
_TMP_SUFFIX = ".tmp"
_PREV_SUFFIX = ".prev"
_TEMPORARY = re.compile(r".+\.[a-z0-9_]+\.tmp(\.prev)?")

def map_entries(gaze_map: GazeMap) -> dict[str, np.ndarray]:
    """The arrays a map file holds for `gaze_map`, by entry name (call `settle()` first)."""
    arrays = {
        "format": np.array(FILE_FORMAT),
        "params": np.array(gaze_map.params.to_json()),
        "grid": gaze_map.grid,
        "recent_errors": np.array(list(gaze_map.recent_errors), dtype=np.float64),
        "adaptations": np.array(gaze_map.adaptations, dtype=np.int64),
        "long_run_error": np.array(gaze_map.long_run_error, dtype=np.float64),
        "memory": np.array(gaze_map.memory, dtype=np.float64),
        "residual_scale": np.array(gaze_map.residual_scale, dtype=np.float64),
        "surprised": np.array(gaze_map.surprised, dtype=np.float64),
    }
    if gaze_map.polynomial is not None:
        arrays["polynomial_coef"] = gaze_map.polynomial.coef
        arrays["polynomial_covariance"] = gaze_map.polynomial.covariance
        arrays["polynomial_noise"] = gaze_map.polynomial.noise_variance
    if gaze_map.pose_polynomial is not None and np.isfinite(gaze_map.fit_errors).all():  # else never learned
        arrays["pose_coef"] = gaze_map.pose_polynomial.coef
        arrays["pose_covariance"] = gaze_map.pose_polynomial.covariance
        arrays["pose_noise"] = gaze_map.pose_polynomial.noise_variance
        arrays["fit_errors"] = gaze_map.fit_errors
    return arrays


def write_map(gaze_map: GazeMap, path: str | os.PathLike[str], keep_previous: bool = True) -> None:
    """Write `gaze_map` atomically: temp file, fsync, rename; the previous file kept as `<path>.prev`.

    At every instant `path` is either the old complete file or the new complete file.
    """
    path = Path(path)
    gaze_map.settle()
    buffer = io.BytesIO()
    arrays: dict[str, Any] = map_entries(gaze_map)  # Any: savez's own keyword allow_pickle is a bool
    np.savez(buffer, **arrays)
    fd, tmp = tempfile.mkstemp(prefix=path.name + _TMP_PREFIX_SEPARATOR, suffix=_TMP_SUFFIX, dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(buffer.getbuffer())
            f.flush()
            os.fsync(f.fileno())
        if keep_previous and path.exists():
            # Link, then rename over .prev: `path` itself is never missing.
            prev_tmp = f"{tmp}{_PREV_SUFFIX}"
            os.link(path, prev_tmp)
            os.replace(prev_tmp, f"{path}{_PREV_SUFFIX}")
        os.replace(tmp, path)
    except BaseException:
        for leftover in (tmp, f"{tmp}{_PREV_SUFFIX}"):
            try:
                os.unlink(leftover)
            except FileNotFoundError:
                pass
        raise
    dir_fd = os.open(path.parent, os.O_RDONLY)
    try:
        os.fsync(dir_fd)
    finally:
        os.close(dir_fd)
    log.debug("gaze map saved to %s (%d adaptations)", path, gaze_map.adaptations)


def temporary_files(directory: str | os.PathLike[str]) -> list[Path]:
    """The temporary files `write_map` leaves in `directory` when the process dies mid-save
    (none otherwise: a save that fails removes its own). Only regular files are listed."""
    found = []
    try:
        entries = list(os.scandir(directory))
    except FileNotFoundError:
        return []
    for entry in entries:
        if _TEMPORARY.fullmatch(entry.name) and entry.is_file(follow_symlinks=False):
            found.append(Path(entry.path))
    return sorted(found)


# --- reading -------------------------------------------------------------------------------------
@dataclasses.dataclass(frozen=True)
class _Spec:
    """What one entry may be: a dtype kind and its largest item, and its shape (`max_len`:
    a 1-d array of 0..max_len items instead of a fixed shape)."""

    kind: str  # "f": float64; "i": an integer of at most 8 bytes; "U": text
    shape: tuple[int, ...] = ()
    max_len: int | None = None
    max_chars: int = 0

    def expected(self) -> str:
        what = {"f": "float64", "i": "an integer dtype", "U": f"text of at most {self.max_chars} characters"}[self.kind]
        shape = f"(0..{self.max_len},)" if self.max_len is not None else str(self.shape)
        return f"{what} of shape {shape}"

    def max_bytes(self) -> int:
        if self.kind == "U":
            return 4 * self.max_chars
        count = self.max_len if self.max_len is not None else math.prod(self.shape)
        return 8 * count


_TEXT_SPECS = {"format": _Spec("U", max_chars=MAX_FORMAT_CHARS), "params": _Spec("U", max_chars=MAX_PARAMS_CHARS)}


def _specs(params: GazeMapParams) -> dict[str, _Spec]:
    """Every entry of a map file for `params` and what it must be."""
    specs = dict(_TEXT_SPECS)
    specs["grid"] = _Spec("f", (3, *params.grid_shape))
    specs["recent_errors"] = _Spec("f", max_len=params.error_window)
    specs["adaptations"] = _Spec("i")
    for name in ("long_run_error", "memory", "residual_scale", "surprised"):
        specs[name] = _Spec("f")
    if params.global_degree > 0:
        terms = _max_terms(params.global_degree)
        specs["polynomial_coef"] = _Spec("f", (terms, 3))
        specs["polynomial_covariance"] = _Spec("f", (terms, terms))
        specs["polynomial_noise"] = _Spec("f", (3,))
    if params.uses_pose:
        terms = pose_terms(params)
        specs["pose_coef"] = _Spec("f", (terms, 3))
        specs["pose_covariance"] = _Spec("f", (terms, terms))
        specs["pose_noise"] = _Spec("f", (3,))
        specs["fit_errors"] = _Spec("f", (2,))
    return specs


def pose_terms(params: GazeMapParams) -> int:
    """The number of terms of the pose-aware polynomial part of a map with `params`."""
    pose_monomials = (params.pose_degree + 1) * (params.pose_degree + 2) // 2 - 1  # of (tilt, vergence)
    return (_max_terms(max(params.pose_position_degree, params.global_degree))
            + pose_monomials * _max_terms(params.pose_cross_degree))


def read_map(path: str | os.PathLike[str]) -> GazeMap:
    """The map of a file `write_map` wrote, checked whole before use (the module
    docstring lists the checks). Raises MapFileError naming the file and what is wrong, and
    nothing else."""
    path = Path(path)
    try:
        return _read(path)
    except MapFileError:
        raise
    except Exception as err:  # a failure the checks did not foresee is still a bad file, never a crash
        raise MapFileError(f"{path}: not a readable gaze map file ({type(err).__name__}: {err})") from err


def _read(path: Path) -> GazeMap:
    try:
        info = path.stat()
    except FileNotFoundError as err:
        raise MapFileError(f"{path}: no such gaze map file") from err
    except OSError as err:
        raise MapFileError(f"{path}: not a readable gaze map file ({err})") from err
    if not stat.S_ISREG(info.st_mode):
        raise MapFileError(f"{path}: not a readable gaze map file (not a regular file)")
    if info.st_size == 0:
        raise MapFileError(f"{path}: not a readable gaze map file (an empty file)")
    if info.st_size > MAX_FILE_BYTES:
        raise MapFileError(f"{path}: not a readable gaze map file ({info.st_size} bytes; a map file has at most "
                           f"{MAX_FILE_BYTES})")
    try:
        f = open(path, "rb")
    except OSError as err:
        raise MapFileError(f"{path}: not a readable gaze map file ({err})") from err
    with f:
        _check_directory(f, info.st_size, path)
        try:
            archive = zipfile.ZipFile(f)
        except (zipfile.BadZipFile, OSError, EOFError, ValueError, struct.error) as err:
            raise MapFileError(f"{path}: not a readable gaze map file ({err})") from err
        with archive:
            members = _members(archive, path)
            fmt = _read_text(archive, members["format"], "format", path)
            if fmt != FILE_FORMAT:
                raise MapFileError(f"{path}: format {fmt!r}, expected {FILE_FORMAT!r}")
            params = _params(_read_text(archive, members["params"], "params", path), path)
            specs = _specs(params)
            required = (REQUIRED_ENTRIES | (POLYNOMIAL_ENTRIES if params.global_degree > 0 else set())
                        | {"format"})
            missing = sorted(required - members.keys())
            if missing:
                raise MapFileError(f"{path}: missing entries {missing}")
            unexpected = sorted(members.keys() - specs.keys())
            if unexpected:
                raise MapFileError(f"{path}: entries {unexpected} do not belong in a map file with "
                                   f"global_degree {params.global_degree} and pose_degree {params.pose_degree}")
            pose_found = sorted(POSE_ENTRIES & members.keys())
            if pose_found and len(pose_found) != len(POSE_ENTRIES):
                raise MapFileError(f"{path}: entries {pose_found} without {sorted(POSE_ENTRIES - members.keys())}; "
                                   f"a map file holds all of {sorted(POSE_ENTRIES)} or none")
            arrays = {name: _read_array(archive, members[name], specs[name], name, path)
                      for name in members if name not in _TEXT_SPECS}
    return _build(path, params, arrays)


_EOCD = struct.Struct("<4s4H2LH")  # end of central directory record
_EOCD_SIGNATURE = b"PK\x05\x06"
_ZIP64_LOCATOR = struct.Struct("<4sLQL")
_ZIP64_LOCATOR_SIGNATURE = b"PK\x06\x07"


def _check_directory(f: IO[bytes], size: int, path: Path) -> None:
    """Bound the zip's central directory before `zipfile` reads it (it holds every entry of
    it in memory). The end record is found as `zipfile` finds it."""
    tail_len = min(size, _EOCD.size + 0xFFFF)  # the record, and a comment of at most 64 kB
    f.seek(size - tail_len)
    tail = f.read(tail_len)
    if tail[-_EOCD.size:-_EOCD.size + 4] == _EOCD_SIGNATURE and tail[-2:] == b"\0\0":
        at = len(tail) - _EOCD.size
    else:
        at = tail.rfind(_EOCD_SIGNATURE)
    if at < 0 or len(tail) - at < _EOCD.size:
        raise MapFileError(f"{path}: not a readable gaze map file (not a zip archive)")
    _, _, _, on_disk, members, directory_bytes, _, _ = _EOCD.unpack_from(tail, at)
    locator_at = size - tail_len + at - _ZIP64_LOCATOR.size
    if locator_at >= 0:
        f.seek(locator_at)
        if f.read(4) == _ZIP64_LOCATOR_SIGNATURE:
            raise MapFileError(f"{path}: not a gaze map file (a ZIP64 archive; a map file never needs one)")
    if members > MAX_MEMBERS or on_disk != members:
        raise MapFileError(f"{path}: not a gaze map file (a zip of {members} members; a map file has at most "
                           f"{MAX_MEMBERS})")
    if directory_bytes > MAX_DIRECTORY_BYTES:
        raise MapFileError(f"{path}: not a gaze map file (a zip directory of {directory_bytes} bytes; a map "
                           f"file's has at most {MAX_DIRECTORY_BYTES})")


def _members(archive: zipfile.ZipFile, path: Path) -> dict[str, zipfile.ZipInfo]:
    """The archive's members by entry name, refusing unknown, duplicate and oversized ones."""
    infos = archive.infolist()
    if len(infos) > MAX_MEMBERS:
        raise MapFileError(f"{path}: not a gaze map file (a zip of {len(infos)} members; a map file has at most "
                           f"{MAX_MEMBERS})")
    if "format.npy" not in archive.namelist():
        raise MapFileError(f"{path}: no 'format' entry: not a gaze map file (expected format {FILE_FORMAT!r})")
    members: dict[str, zipfile.ZipInfo] = {}
    for info in infos:
        name = info.filename.removesuffix(".npy")
        if not info.filename.endswith(".npy") or name not in ALL_ENTRIES:
            raise MapFileError(f"{path}: unknown entry {info.filename!r}; a map file holds only "
                               f"{sorted(ALL_ENTRIES)} (as .npy)")
        if name in members:
            raise MapFileError(f"{path}: entry {name!r} appears twice")
        members[name] = info
    if "params" not in members:
        raise MapFileError(f"{path}: missing entries ['params']")
    return members


def _open_member(archive: zipfile.ZipFile, info: zipfile.ZipInfo, spec: _Spec, name: str,
                 path: Path) -> IO[bytes]:
    if info.flag_bits & 0x1:
        raise MapFileError(f"{path}: entry {name!r} is encrypted")
    if info.compress_type not in (zipfile.ZIP_STORED, zipfile.ZIP_DEFLATED):
        raise MapFileError(f"{path}: entry {name!r}: compression method {info.compress_type}, expected stored "
                           "or deflated")
    limit = _MEMBER_OVERHEAD + spec.max_bytes()
    if info.file_size > limit:
        raise MapFileError(f"{path}: entry {name!r} is {info.file_size} bytes uncompressed; "
                           f"{spec.expected()} takes at most {limit}")
    return archive.open(info)


def _read_member(archive: zipfile.ZipFile, info: zipfile.ZipInfo, spec: _Spec, name: str,
                 path: Path) -> np.ndarray:
    """One entry's array, its header checked against `spec` before its data is read."""
    try:
        with _open_member(archive, info, spec, name, path) as member:
            head = member.read(min(info.file_size, _MEMBER_OVERHEAD))
            header = io.BytesIO(head)
            try:
                version = np.lib.format.read_magic(header)
                if version == (1, 0):
                    shape, fortran_order, dtype = np.lib.format.read_array_header_1_0(header, MAX_HEADER_BYTES)
                elif version == (2, 0):
                    shape, fortran_order, dtype = np.lib.format.read_array_header_2_0(header, MAX_HEADER_BYTES)
                else:
                    raise MapFileError(f"{path}: entry {name!r}: .npy format version {version}, expected 1.0 or 2.0")
            except MapFileError:
                raise
            except Exception as err:  # numpy's header parser: ValueError, SyntaxError, TypeError...
                raise MapFileError(f"{path}: entry {name!r}: not a readable .npy header ({err})") from err
            _check_header(shape, dtype, spec, name, path)
            count = math.prod(shape)
            nbytes = count * dtype.itemsize
            offset = header.tell()
            if info.file_size != offset + nbytes:
                raise MapFileError(f"{path}: entry {name!r} holds {info.file_size - offset} bytes of data, its "
                                   f"header (shape {shape}, {dtype}) says {nbytes}")
            data = head[offset:]
            data += member.read(nbytes - len(data))
            if len(data) != nbytes or member.read(1):
                raise MapFileError(f"{path}: entry {name!r} is truncated")
    except MapFileError:
        raise
    except (zipfile.BadZipFile, OSError, EOFError, ValueError, RuntimeError, NotImplementedError,
            struct.error) as err:  # zlib.error is an Exception, caught by read_map
        raise MapFileError(f"{path}: entry {name!r}: unreadable ({err})") from err
    array = np.frombuffer(data, dtype=dtype, count=count)
    return array.reshape(shape, order="F" if fortran_order else "C")


def _check_header(shape: tuple[int, ...], dtype: np.dtype[Any], spec: _Spec, name: str, path: Path) -> None:
    found = f"{dtype.str} of shape {shape}"
    if dtype.hasobject:
        raise MapFileError(f"{path}: entry {name!r} holds Python objects ({found}); pickles are never loaded, "
                           f"expected {spec.expected()}")
    plain = dtype.fields is None and dtype.subdtype is None and dtype.itemsize > 0
    if spec.kind == "f":
        good_dtype = plain and dtype.kind == "f" and dtype.itemsize == 8
    elif spec.kind == "i":
        good_dtype = plain and dtype.kind in "iu" and dtype.itemsize <= 8
    else:
        good_dtype = plain and dtype.kind == "U" and dtype.itemsize <= 4 * spec.max_chars
    if spec.max_len is not None:
        good_shape = len(shape) == 1 and 0 <= shape[0] <= spec.max_len
    else:
        good_shape = tuple(shape) == spec.shape
    if not (good_dtype and good_shape):
        raise MapFileError(f"{path}: entry {name!r} is {found}, expected {spec.expected()}")


def _read_text(archive: zipfile.ZipFile, info: zipfile.ZipInfo, name: str, path: Path) -> str:
    return str(_read_member(archive, info, _TEXT_SPECS[name], name, path)[()])


def _read_array(archive: zipfile.ZipFile, info: zipfile.ZipInfo, spec: _Spec, name: str, path: Path) -> np.ndarray:
    """One numeric entry as a native, writable array, its values finite and bounded."""
    raw = _read_member(archive, info, spec, name, path)
    if spec.kind == "i":
        value = int(raw[()])  # exact for every integer dtype
        if not 0 <= value <= MAX_ADAPTATIONS:
            raise MapFileError(f"{path}: entry {name!r} is {value}, expected an integer in [0, {MAX_ADAPTATIONS}]")
        return np.array(value, dtype=np.int64)
    array = np.array(raw, dtype=np.float64, order="C")
    finite = np.isfinite(array)
    if name == "long_run_error" and np.isnan(array).all():
        return array  # a map that never adapted has no long-run error yet (checked in _build)
    if not finite.all():
        bad = np.argwhere(~finite)[0]
        where = f" at {tuple(int(i) for i in bad)}" if array.ndim else ""
        raise MapFileError(f"{path}: entry {name!r} holds {float(array[tuple(bad)])}{where}; every value must be "
                           "finite")
    if array.size and float(np.max(np.abs(array))) > MAX_MAGNITUDE:
        raise MapFileError(f"{path}: entry {name!r} holds {float(np.max(np.abs(array))):g}; no value of a map "
                           f"exceeds {MAX_MAGNITUDE:g} in magnitude")
    return array


def _params(text: str, path: Path) -> GazeMapParams:
    """The map parameters of a file: JSON of a `GazeMapParams`, every field of its type, and
    values the map can run on."""
    try:
        data = json.loads(text)
    except (ValueError, RecursionError) as err:
        raise MapFileError(f"{path}: entry 'params' is not JSON ({err})") from err
    if not isinstance(data, dict):
        raise MapFileError(f"{path}: entry 'params' is a JSON {type(data).__name__}, expected an object")
    try:
        params = GazeMapParams.from_json(text)
    except (ValueError, TypeError, KeyError) as err:
        raise MapFileError(f"{path}: entry 'params': invalid map parameters ({err})") from err
    default = GazeMapParams()
    for field in dataclasses.fields(GazeMapParams):
        value = getattr(params, field.name)
        if not _same_kind(value, getattr(default, field.name)):
            raise MapFileError(f"{path}: entry 'params': {field.name} is {value!r}, expected a value like "
                               f"{getattr(default, field.name)!r} (finite numbers)")
    problem = _params_problem(params)
    if problem:
        raise MapFileError(f"{path}: entry 'params': {problem}")
    return params


def _same_kind(value: Any, default: Any) -> bool:
    """`value` has the type of `default` (an int for an int, any finite number for a float,
    tuples of the same length item by item)."""
    if isinstance(default, bool):
        return isinstance(value, bool)
    if isinstance(default, int):
        return isinstance(value, int) and not isinstance(value, bool)
    if isinstance(default, float):
        return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)
    if isinstance(default, str):
        return isinstance(value, str)
    if isinstance(default, tuple):
        return (isinstance(value, tuple) and len(value) == len(default)
                and all(_same_kind(v, d) for v, d in zip(value, default)))
    return False


def _params_problem(p: GazeMapParams) -> str:
    """'' if a map with parameters `p` is within what a file may allocate, else what is wrong
    (GazeMapParams checks that the values make a map at all)."""
    if max(p.image_size) > MAX_IMAGE_SIDE:
        return f"image_size {p.image_size}: at most {MAX_IMAGE_SIDE} pixels a side"
    if math.prod(p.grid_shape) > MAX_GRID_NODES:
        return f"grid_shape {p.grid_shape}: at most {MAX_GRID_NODES} nodes"
    if not all(1 <= r <= MAX_OUTPUT_RESOLUTION for r in p.output_resolution):
        return f"output_resolution {p.output_resolution}: 1 to {MAX_OUTPUT_RESOLUTION} cells an axis"
    if p.error_window > MAX_ERROR_WINDOW:
        return f"error_window {p.error_window}: at most {MAX_ERROR_WINDOW}"
    if p.global_degree > MAX_GLOBAL_DEGREE:
        return f"global_degree {p.global_degree}: at most {MAX_GLOBAL_DEGREE}"
    return ""


def _build(path: Path, params: GazeMapParams, arrays: dict[str, np.ndarray]) -> GazeMap:
    """The map of checked entries, after the checks that relate one entry to another."""
    adaptations = int(arrays["adaptations"])
    long_run_error = float(arrays["long_run_error"])
    memory = float(arrays["memory"])
    residual_scale = float(arrays["residual_scale"])
    surprised = float(arrays["surprised"]) if "surprised" in arrays else 0.0  # absent: none pending
    recent_errors = arrays["recent_errors"]
    problems = []
    if math.isnan(long_run_error) and adaptations > 0:
        problems.append(f"long_run_error is nan after {adaptations} adaptations; expected a finite value")
    if long_run_error < 0 or (recent_errors < 0).any():
        problems.append("long_run_error and recent_errors are retinal errors: never negative")
    top = max(params.global_memory, params.global_memory_min)
    if not 1 <= memory <= top:
        problems.append(f"memory is {memory:g}, expected 1 to {top:g} fixations (global_memory)")
    if not residual_scale >= MIN_RESIDUAL_SCALE:
        problems.append(f"residual_scale is {residual_scale:g}, expected at least {MIN_RESIDUAL_SCALE:g}")
    if surprised < 0:
        problems.append(f"surprised is {surprised:g}, expected at least 0")
    for name in ("polynomial_noise", "pose_noise", "fit_errors"):
        if name in arrays and (arrays[name] < 0).any():
            problems.append(f"{name} is {arrays[name].tolist()}, expected variances (at least 0)")
    if problems:
        raise MapFileError(f"{path}: {'; '.join(problems)}")
    gm = GazeMap(params, grid=arrays["grid"])
    if gm.polynomial is not None:
        gm.polynomial.coef = arrays["polynomial_coef"]
        gm.polynomial.covariance = arrays["polynomial_covariance"]
        if "polynomial_noise" in arrays:
            gm.polynomial.noise_variance = arrays["polynomial_noise"]
        gm.polynomial.coefficients_changed()
        gm.derive_pose_polynomial()  # a file without the pose-aware part: it starts from this one
    if gm.pose_polynomial is not None and "pose_coef" in arrays:
        gm.pose_polynomial.coef = arrays["pose_coef"]
        gm.pose_polynomial.covariance = arrays["pose_covariance"]
        gm.pose_polynomial.noise_variance = arrays["pose_noise"]
        gm.fit_errors = arrays["fit_errors"]
        gm.pose_polynomial.coefficients_changed()
    gm.recent_errors.extend(float(e) for e in recent_errors)
    gm.adaptations = adaptations
    gm.long_run_error = long_run_error
    gm.memory = memory
    gm.residual_scale = residual_scale
    gm.surprised = surprised
    return gm
