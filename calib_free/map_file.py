"""Gaze map files: what a saved `GazeMap` holds on disk, and writing and reading it.

A map file is a numpy .npz archive of named arrays, read without pickles: `format` (the
file format's name and version), `params` (`GazeMapParams` as JSON), `grid`, the learning
state (`recent_errors`, `adaptations`, `long_run_error`, `memory`, `residual_scale`,
`surprised`) and, for a map with a polynomial part, `polynomial_coef` and
`polynomial_covariance`. A map and its reloaded copy continue learning identically.

Writing is atomic (temp file, fsync, rename), so a crash leaves the old file or the new one,
never half of one. Reading is in one place, `read_map`, which raises `MapFileError` naming
the file and what is wrong with it. `GazeMap.save()` and `GazeMap.load()` call these.
"""
from __future__ import annotations

import io
import logging
import os
import tempfile
import zipfile
from pathlib import Path
from typing import Any, TypeVar

import numpy as np

from calib_free.errors import MapFileError
from calib_free.gaze_map import GazeMap, GazeMapParams

log = logging.getLogger(__name__)

FILE_FORMAT = "calib_free.GazeMap/1"
# Entries every map file holds besides `format`; `surprised` may be absent (none pending).
REQUIRED_ENTRIES = frozenset({"params", "grid", "recent_errors", "adaptations", "long_run_error", "memory",
                              "residual_scale"})
# ... and those a map with a polynomial part (global_degree > 0) adds.
POLYNOMIAL_ENTRIES = frozenset({"polynomial_coef", "polynomial_covariance"})

_Map = TypeVar("_Map", bound=GazeMap)


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
    fd, tmp = tempfile.mkstemp(prefix=path.name + ".", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(buffer.getbuffer())
            f.flush()
            os.fsync(f.fileno())
        if keep_previous and path.exists():
            # Link, then rename over .prev: `path` itself is never missing.
            prev_tmp = f"{tmp}.prev"
            os.link(path, prev_tmp)
            os.replace(prev_tmp, f"{path}.prev")
        os.replace(tmp, path)
    except BaseException:
        for leftover in (tmp, f"{tmp}.prev"):
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


def read_map(path: str | os.PathLike[str], map_class: type[_Map]) -> _Map:
    """A `map_class` map from a file `write_map` wrote. Raises MapFileError naming the file
    and what is wrong."""
    path = Path(path)
    try:
        with np.load(path, allow_pickle=False) as data:
            arrays = {k: data[k] for k in data.files}
    except FileNotFoundError as err:
        raise MapFileError(f"{path}: no such gaze map file") from err
    except (OSError, ValueError, EOFError, zipfile.BadZipFile) as err:
        raise MapFileError(f"{path}: not a readable gaze map file ({err})") from err
    fmt = str(arrays.get("format", ""))
    if fmt != FILE_FORMAT:
        raise MapFileError(f"{path}: format {fmt!r}, expected {FILE_FORMAT!r}")
    missing = REQUIRED_ENTRIES - set(arrays)
    try:
        params = GazeMapParams.from_json(str(arrays["params"])) if "params" in arrays else None
        if params is not None and params.global_degree > 0:
            missing |= POLYNOMIAL_ENTRIES - set(arrays)
        if missing or params is None:
            raise MapFileError(f"{path}: missing {sorted(missing)}")
        gm = map_class(params, grid=arrays["grid"])
        if gm.polynomial is not None:
            for name in ("coef", "covariance"):
                saved = arrays[f"polynomial_{name}"]
                current = getattr(gm.polynomial, name)
                if saved.shape != current.shape:
                    raise ValueError(f"polynomial_{name} has shape {saved.shape}, expected {current.shape}")
                setattr(gm.polynomial, name, np.array(saved, dtype=np.float64))
            gm.polynomial.coefficients_changed()
    except (ValueError, TypeError, KeyError) as err:
        if isinstance(err, MapFileError):
            raise
        raise MapFileError(f"{path}: invalid map ({err})") from err
    gm.recent_errors.extend(float(e) for e in arrays["recent_errors"])
    gm.adaptations = int(arrays["adaptations"])
    gm.long_run_error = float(arrays["long_run_error"])
    gm.memory = float(arrays["memory"])
    gm.residual_scale = float(arrays["residual_scale"])
    gm.surprised = float(arrays.get("surprised", 0.0))  # files saved before it was kept: none pending
    return gm
