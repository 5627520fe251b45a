"""Map files read with every check (calib_free.map.file): a malformed file of any kind is a
MapFileError naming the file, the entry and the problem, found before anything is allocated;
files the code writes keep loading."""
from __future__ import annotations

import io
import json
import os
import time
import tracemalloc
import zipfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st

from calib_free.errors import MapFileError

from calib_free.map.gaze_map import GazeMap
from calib_free.map.params import GazeMapParams
from calib_free.map.file import MAX_MEMBERS, read_map, temporary_files, write_map


def _small_map(profile: str = "default", adaptations: int = 12, pose: bool = False) -> GazeMap:
    gm = GazeMap.for_image(32, 24, disparity_range=(-6.0, 6.0), seed=3, profile=profile, grid_shape=(6, 5, 4))
    rng = np.random.default_rng(0)
    for _ in range(adaptations):
        seen_at = (rng.uniform(-40, 40), rng.uniform(-25, 25), rng.uniform(3, 20)) if pose else None
        gm.adapt((rng.uniform(0, 31), rng.uniform(0, 23), rng.uniform(-5, 5)), rng.uniform(-5, 5, size=3),
                 pose=seen_at)
    return gm


def _saved(tmp_path: Path, profile: str = "default", adaptations: int = 12) -> Path:
    path = tmp_path / f"{profile}.npz"
    write_map(_small_map(profile, adaptations), path)
    return path


def _members(path: Path) -> dict[str, bytes]:
    with zipfile.ZipFile(path) as archive:
        return {info.filename: archive.read(info) for info in archive.infolist()}


def _write_members(path: Path, members: dict[str, bytes] | list[tuple[str, bytes]]) -> Path:
    items = members.items() if isinstance(members, dict) else members
    with zipfile.ZipFile(path, "w") as archive:
        for name, data in items:
            archive.writestr(name, data)
    return path


def _npy(array: np.ndarray) -> bytes:
    buffer = io.BytesIO()
    np.lib.format.write_array(buffer, np.asanyarray(array), allow_pickle=True)
    return buffer.getvalue()


def _npy_claiming(descr: str, shape: tuple[int, ...], data: bytes = b"") -> bytes:
    """An .npy whose header claims `descr` and `shape`, followed by `data` only."""
    header = f"{{'descr': '{descr}', 'fortran_order': False, 'shape': {shape!r}, }}"
    header += " " * (63 - (10 + len(header)) % 64) + "\n"
    return b"\x93NUMPY\x01\x00" + len(header).to_bytes(2, "little") + header.encode("latin1") + data


def _replaced(tmp_path: Path, entry: str, data: bytes, profile: str = "default") -> Path:
    members = _members(_saved(tmp_path, profile))
    members[f"{entry}.npy"] = data
    return _write_members(tmp_path / "bad.npz", members)


def _refused(path: Path, *fragments: str) -> str:
    with pytest.raises(MapFileError) as caught:
        read_map(path)
    message = str(caught.value)
    assert message.startswith(str(path)), message
    for fragment in fragments:
        assert fragment in message, message
    return message


# --- what keeps loading ---------------------------------------------------------------------------
@pytest.mark.parametrize("profile", ["default", "paper"])
def test_files_the_code_writes_load_and_continue_identically(tmp_path, profile):
    gm = _small_map(profile)
    write_map(gm, tmp_path / "m.npz")
    loaded = read_map(tmp_path / "m.npz")
    assert loaded.adaptations == gm.adaptations and list(loaded.recent_errors) == list(gm.recent_errors)
    assert np.array_equal(loaded.grid, gm.grid)
    for m in (gm, loaded):
        m.adapt((10.0, 10.0, 1.0), (1.0, -1.0, 0.5))
    assert np.array_equal(loaded.grid, gm.grid) and loaded.long_run_error == gm.long_run_error


def test_a_map_that_never_adapted_loads_with_no_long_run_error_yet(tmp_path):
    write_map(_small_map(adaptations=0), tmp_path / "fresh.npz")
    loaded = read_map(tmp_path / "fresh.npz")
    assert loaded.adaptations == 0 and np.isnan(loaded.long_run_error)
    assert loaded.adapt((10.0, 10.0, 1.0), (1.0, -1.0, 0.5)).accepted and np.isfinite(loaded.long_run_error)


def test_a_file_without_surprised_loads_with_none_pending(tmp_path):
    members = _members(_saved(tmp_path))
    del members["surprised.npy"]
    assert read_map(_write_members(tmp_path / "older.npz", members)).surprised == 0.0


POSE = (5.0, -10.0, 8.0)


def test_a_pose_aware_map_loads_and_continues_identically(tmp_path):
    gm = _small_map(pose=True, adaptations=30)
    assert np.isfinite(gm.fit_errors).all()  # its pose-aware part learned
    write_map(gm, tmp_path / "m.npz")
    assert {"pose_coef.npy", "pose_covariance.npy", "pose_noise.npy", "fit_errors.npy"} <= _members(tmp_path / "m.npz").keys()
    loaded = read_map(tmp_path / "m.npz")
    np.testing.assert_array_equal(loaded.pose_polynomial.coef, gm.pose_polynomial.coef)
    np.testing.assert_array_equal(loaded.fit_errors, gm.fit_errors)
    rng = np.random.default_rng(7)
    for _ in range(5):
        position, command = (rng.uniform(0, 31), rng.uniform(0, 23), rng.uniform(-5, 5)), rng.uniform(-5, 5, 3)
        pose = (rng.uniform(-40, 40), rng.uniform(-25, 25), rng.uniform(3, 20))
        assert gm.adapt(position, command, pose=pose).retinal_error == loaded.adapt(position, command,
                                                                                      pose=pose).retinal_error
        np.testing.assert_array_equal(gm.command(position, pose=pose), loaded.command(position, pose=pose))
        assert gm.uncertainty(position, pose=pose) == loaded.uncertainty(position, pose=pose)


def _older_file(tmp_path: Path, gm: GazeMap) -> Path:
    """`gm` as a map file from before the pose inputs: no pose parameters, noise or pose entries."""
    write_map(gm, tmp_path / "new.npz")
    members = _members(tmp_path / "new.npz")
    params = json.loads(np.load(io.BytesIO(members["params.npy"]))[()])
    for key in ("pose_degree", "pose_position_degree", "pose_cross_degree"):
        del params[key]
    members["params.npy"] = _npy(np.array(json.dumps(params, sort_keys=True)))
    for entry in ("polynomial_noise", "pose_coef", "pose_covariance", "pose_noise", "fit_errors"):
        members.pop(f"{entry}.npy", None)
    return _write_members(tmp_path / "older.npz", members)


@pytest.mark.parametrize("profile", ["default", "paper"])
def test_an_older_map_file_loads_answers_as_before_and_learns_the_pose(tmp_path, profile):
    gm = _small_map(profile, adaptations=30)
    loaded = read_map(_older_file(tmp_path, gm))
    # The parameters a config of the same profile makes today: the service keeps the file.
    assert loaded.params == GazeMapParams.profile_values(profile, **{
        k: getattr(gm.params, k) for k in ("image_size", "disparity_range", "grid_shape")})
    position = (12.0, 9.0, 1.0)
    np.testing.assert_array_equal(loaded.command(position), gm.command(position))
    np.testing.assert_array_equal(loaded.command(position, pose=POSE), gm.command(position))  # never saw a pose
    if profile == "default":
        assert loaded.pose_polynomial is not None and not loaded.pose_trusted
        assert loaded.adapt(position, (1.0, -1.0, 0.5), pose=POSE).accepted
        assert np.isfinite(loaded.fit_errors).all()
        write_map(loaded, tmp_path / "again.npz")
        assert "pose_coef.npy" in _members(tmp_path / "again.npz")


def test_pose_entries_come_all_or_none(tmp_path):
    write_map(_small_map(pose=True), tmp_path / "m.npz")
    members = _members(tmp_path / "m.npz")
    del members["pose_covariance.npy"]
    _refused(_write_members(tmp_path / "bad.npz", members), "'pose_covariance'", "all of")


def test_a_fortran_ordered_or_deflated_file_loads_the_same(tmp_path):
    path = _saved(tmp_path)
    original = read_map(path)
    members = _members(path)
    members["grid.npy"] = _npy(np.asfortranarray(original.grid))
    with zipfile.ZipFile(tmp_path / "other.npz", "w", compression=zipfile.ZIP_DEFLATED) as archive:
        for name, data in members.items():
            archive.writestr(name, data)
    assert np.array_equal(read_map(tmp_path / "other.npz").grid, original.grid)


# --- what is refused, and how ----------------------------------------------------------------------
def test_a_two_element_adaptations_is_refused_naming_the_entry(tmp_path):
    path = _replaced(tmp_path, "adaptations", _npy(np.array([3, 4], dtype=np.int64)))
    _refused(path, "'adaptations'", "(2,)", "expected an integer dtype of shape ()")


@pytest.mark.parametrize("entry, descr, shape", [
    ("grid", "<f8", (3, 1 << 40)),
    ("grid", "<f8", (1 << 40,)),
    ("recent_errors", "<f8", (1 << 40,)),
    ("polynomial_covariance", "<f8", (1 << 20, 1 << 20)),
    ("params", "<U1099511627776", ()),
])
def test_a_header_claiming_2_40_elements_fails_fast_without_allocating(tmp_path, entry, descr, shape):
    path = _replaced(tmp_path, entry, _npy_claiming(descr, shape, b"\0" * 64))
    tracemalloc.start()
    started = time.perf_counter()
    try:
        _refused(path, repr(entry))
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert time.perf_counter() - started < 1.0
    assert peak < 16 << 20  # a map's worth of memory at most, never the 8 TB claimed


def test_parameters_claiming_a_huge_grid_are_refused_before_the_grid_is_read(tmp_path):
    members = _members(_saved(tmp_path))
    params = json.loads(str(np.load(io.BytesIO(members["params.npy"]))))
    params["grid_shape"] = [1 << 14, 1 << 13, 1 << 13]
    members["params.npy"] = _npy(np.array(json.dumps(params)))
    members["grid.npy"] = _npy_claiming("<f8", (3, 1 << 14, 1 << 13, 1 << 13))
    started = time.perf_counter()
    _refused(_write_members(tmp_path / "huge.npz", members), "'params'", "grid_shape", "at most")
    assert time.perf_counter() - started < 1.0


@pytest.mark.parametrize("entry, array, fragment", [
    ("grid", None, "'grid' holds nan"),
    ("recent_errors", np.array([0.1, np.nan, 0.2]), "'recent_errors' holds nan at (1,)"),
    ("polynomial_coef", None, "'polynomial_coef' holds inf"),
    ("memory", np.array(np.nan), "'memory' holds nan"),
    ("residual_scale", np.array(np.inf), "'residual_scale' holds inf"),
    ("long_run_error", np.array(-np.inf), "'long_run_error' holds -inf"),
    ("grid", "huge", "'grid' holds 1e+12"),
])
def test_non_finite_values_are_refused_naming_the_entry(tmp_path, entry, array, fragment):
    gm = _small_map()
    if array is None:
        array = gm.grid.copy() if entry == "grid" else gm.polynomial.coef.copy()
        array[0, 1] = np.nan if entry == "grid" else np.inf
    elif isinstance(array, str):
        array = gm.grid.copy()
        array[1, 2, 3, 1] = 1e12
    _refused(_replaced(tmp_path, entry, _npy(array)), fragment, "finite" if "huge" not in fragment else "")


def test_a_nan_long_run_error_after_adaptations_is_refused(tmp_path):
    _refused(_replaced(tmp_path, "long_run_error", _npy(np.array(np.nan))), "long_run_error is nan after 12")


@pytest.mark.parametrize("name", ["evil.npy", "grid.txt", "../grid.npy"])
def test_an_unknown_entry_is_refused(tmp_path, name):
    members = _members(_saved(tmp_path))
    members[name] = _npy(np.zeros(3))
    _refused(_write_members(tmp_path / "extra.npz", members), f"unknown entry {name!r}")


def test_polynomial_entries_in_a_map_without_a_polynomial_are_refused(tmp_path):
    members = _members(_saved(tmp_path, "paper"))
    members["polynomial_coef.npy"] = _npy(np.zeros((20, 3)))
    _refused(_write_members(tmp_path / "extra.npz", members), "['polynomial_coef'] do not belong")


@pytest.mark.parametrize("entry", ["memory", "grid", "polynomial_covariance", "params"])
def test_a_missing_entry_is_refused(tmp_path, entry):
    members = _members(_saved(tmp_path))
    del members[f"{entry}.npy"]
    _refused(_write_members(tmp_path / "missing.npz", members), f"missing entries ['{entry}']")


def test_a_duplicate_entry_is_refused(tmp_path):
    members = list(_members(_saved(tmp_path)).items())
    with pytest.warns(UserWarning, match="Duplicate name"):
        _write_members(tmp_path / "twice.npz", members + [("memory.npy", _npy(np.array(1.0)))])
    _refused(tmp_path / "twice.npz", "'memory' appears twice")


@pytest.mark.parametrize("entry, array, fragment", [
    ("grid", np.zeros((3, 6, 5, 4), dtype=np.float32), "'grid' is <f4 of shape (3, 6, 5, 4), expected float64"),
    ("grid", np.zeros((3, 6, 5, 5)), "'grid' is <f8 of shape (3, 6, 5, 5), expected float64 of shape (3, 6, 5, 4)"),
    ("adaptations", np.array(12.0), "'adaptations' is <f8"),
    ("adaptations", np.array(-1, dtype=np.int64), "'adaptations' is -1"),
    ("memory", np.array(1, dtype=np.int64), "'memory' is <i8"),
    ("memory", np.array(0.5), "memory is 0.5"),
    ("residual_scale", np.array(1e-300), "residual_scale is 1e-300, expected at least 1e-100"),
    ("recent_errors", np.zeros(2, dtype=complex), "'recent_errors' is <c16"),
    ("grid", np.zeros((3, 6, 5, 4), dtype=complex), "'grid' is 5888 bytes uncompressed; float64 of shape (3, 6, 5, 4)"),
    ("recent_errors", np.zeros(11), "expected float64 of shape (0..10,)"),
    ("recent_errors", np.array([0.1, -0.2]), "never negative"),
    ("format", np.array(b"calib_free.GazeMap/1"), "'format' is |S20"),
    ("params", np.array(["{}", "{}"]), "'params' is <U2 of shape (2,)"),
])
def test_a_wrong_dtype_shape_or_value_is_refused_naming_what_was_expected(tmp_path, entry, array, fragment):
    _refused(_replaced(tmp_path, entry, _npy(array)), fragment)


class _Payload:
    """Unpickling this creates a directory: proof that a pickle ran."""

    def __init__(self, marker: Path) -> None:
        self.marker = marker

    def __reduce__(self):
        return os.mkdir, (str(self.marker),)


@pytest.mark.parametrize("entry", ["recent_errors", "params", "grid"])
def test_object_arrays_are_refused_and_their_pickles_never_run(tmp_path, entry):
    marker = tmp_path / "pickle-ran"
    array = np.empty(1, dtype=object)
    array[0] = _Payload(marker)
    _refused(_replaced(tmp_path, entry, _npy(array)), f"'{entry}' holds Python objects", "pickles are never loaded")
    assert not marker.exists()


@pytest.mark.parametrize("params, fragment", [
    ("not json", "'params' is not JSON"),
    ("[1, 2]", "a JSON list, expected an object"),
    ('{"grid_shape": [6, 5]}', "invalid map parameters"),
    ('{"adaptation_rate": 2.0}', "adaptation_rate must be in (0, 1]"),
    ('{"global_memory": 0}', "global_memory must be >= 1"),
    ('{"disparity_range": [-6.0, NaN]}', "disparity_range"),
    ('{"grid_shape": [6.5, 5, 4]}', "grid_shape is (6.5, 5, 4)"),
    ('{"interpolate": "yes"}', "interpolate is 'yes'"),
    ('{"surprise": 1}', "unknown gaze map parameters"),
    ("[" * 100_000, "'params'"),
])
def test_invalid_parameters_are_refused(tmp_path, params, fragment):
    members = _members(_saved(tmp_path))
    values = json.loads(str(np.load(io.BytesIO(members["params.npy"]))))
    try:
        values.update(json.loads(params))
        text = json.dumps(values)
    except (ValueError, TypeError, RecursionError):
        text = params[:8000]
    if params.startswith("[1"):
        text = params
    members["params.npy"] = _npy(np.array(text))
    _refused(_write_members(tmp_path / "params.npz", members), fragment)


def test_a_map_for_another_format_is_refused(tmp_path):
    _refused(_replaced(tmp_path, "format", _npy(np.array("calib_free.GazeMap/2"))), "format 'calib_free.GazeMap/2'")
    np.savez(tmp_path / "foreign.npz", weights=np.zeros(3))
    _refused(tmp_path / "foreign.npz", "no 'format' entry: not a gaze map file")


@pytest.mark.parametrize("cut", [0.5, 0.99, 22, 100])
def test_a_truncated_file_is_refused(tmp_path, cut):
    path = _saved(tmp_path)
    raw = path.read_bytes()
    path.write_bytes(raw[:int(len(raw) * cut) if isinstance(cut, float) else cut])
    _refused(path, "not a")


@pytest.mark.parametrize("content, fragment", [(b"not a map", "not a zip archive"),
                                               (b"", "an empty file"),
                                               (b"PK\x05\x06" + b"\0" * 18, "not a gaze map file")])
def test_what_is_not_a_map_file_is_refused(tmp_path, content, fragment):
    path = tmp_path / "x.npz"
    path.write_bytes(content)
    _refused(path, fragment)


def test_a_missing_file_or_a_directory_is_refused(tmp_path):
    _refused(tmp_path / "absent.npz", "no such gaze map file")
    (tmp_path / "dir.npz").mkdir()
    _refused(tmp_path / "dir.npz", "not a regular file")


def test_a_zip_bomb_like_member_is_refused_before_it_is_inflated(tmp_path):
    members = _members(_saved(tmp_path))
    members["grid.npy"] = _npy(np.zeros((3, 6, 5, 4))) + b"\0" * (256 << 20)  # 256 MB of zeros, 256 kB deflated
    with zipfile.ZipFile(tmp_path / "bomb.npz", "w", compression=zipfile.ZIP_DEFLATED) as archive:
        for name, data in members.items():
            archive.writestr(name, data)
    del members
    assert (tmp_path / "bomb.npz").stat().st_size < 1 << 20
    tracemalloc.start()
    started = time.perf_counter()
    try:
        _refused(tmp_path / "bomb.npz", "'grid' is 2684", "bytes uncompressed")
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert time.perf_counter() - started < 1.0 and peak < 16 << 20


def test_an_absurd_number_of_members_is_refused_before_the_directory_is_parsed(tmp_path):
    members = [(f"m{i}.npy", b"") for i in range(5000)]
    _refused(_write_members(tmp_path / "many.npz", members), f"a zip of 5000 members; a map file has at most {MAX_MEMBERS}")


def test_an_encrypted_or_oddly_compressed_member_is_refused(tmp_path):
    members = _members(_saved(tmp_path))
    with zipfile.ZipFile(tmp_path / "lzma.npz", "w") as archive:
        for name, data in members.items():
            archive.writestr(name, data, compress_type=zipfile.ZIP_LZMA if name == "grid.npy" else zipfile.ZIP_STORED)
    _refused(tmp_path / "lzma.npz", "'grid': compression method 14")


def test_temporary_files_are_what_write_map_leaves(tmp_path):
    for name in ("gaze_map.npz.ab12cd_9.tmp", "gaze_map.npz.ab12cd_9.tmp.prev", "before-reset.npz.x1y2z3a4.tmp"):
        (tmp_path / name).write_bytes(b"x")
    for name in ("gaze_map.npz", "gaze_map.npz.prev", "gaze_map.npz.bad", "api.url", "headctl.lock"):
        (tmp_path / name).write_bytes(b"x")
    assert [p.name for p in temporary_files(tmp_path)] == [
        "before-reset.npz.x1y2z3a4.tmp", "gaze_map.npz.ab12cd_9.tmp", "gaze_map.npz.ab12cd_9.tmp.prev"]
    assert temporary_files(tmp_path / "absent") == []


# --- corrupted at random: a usable map or MapFileError, nothing else -------------------------------
_DTYPES = ["<f8", ">f8", "<f4", "<i8", "<u8", "<i1", "|b1", "<c16", "<U8", "|S4", "|O", "<m8[s]"]


def _random_array(draw, shape_like: tuple[int, ...]) -> np.ndarray:
    dtype = np.dtype(draw(st.sampled_from(_DTYPES)))
    shape = draw(st.one_of(st.just(shape_like), st.lists(st.integers(0, 4), max_size=3).map(tuple)))
    count = int(np.prod(shape))
    if dtype.kind == "f" and count <= 64:
        values = draw(st.lists(st.floats(width=64, allow_nan=True, allow_infinity=True), min_size=count,
                               max_size=count))
        with np.errstate(over="ignore"):  # float32 from a float64 beyond its range: inf, what a file may hold
            return np.array(values, dtype=dtype).reshape(shape)
    if dtype.kind == "O":
        return np.array([None] * count, dtype=object).reshape(shape)
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    raw = rng.integers(0, 256, size=count * dtype.itemsize, dtype=np.uint8).tobytes()
    return np.frombuffer(raw, dtype=dtype).reshape(shape).copy()


@st.composite
def _corruptions(draw):
    kind = draw(st.sampled_from(["flip", "truncate", "replace", "plausible", "extra", "remove"]))
    if kind == "flip":
        return kind, draw(st.lists(st.tuples(st.floats(0, 1, exclude_max=True), st.integers(1, 255)),
                                   min_size=1, max_size=8))
    if kind == "truncate":
        return kind, draw(st.floats(0, 1, exclude_max=True))
    entry = draw(st.sampled_from(sorted(_ENTRY_SHAPES)))
    if kind == "remove":
        return kind, entry
    if kind == "plausible":  # the right dtype and shape, values near a map's own, now and then not finite
        entry = draw(st.sampled_from(sorted(set(_ENTRY_SHAPES) - {"format", "params"})))
        rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
        if entry == "adaptations":
            return kind, (entry, np.array(draw(st.integers(-5, 2**63 - 1)), dtype=np.int64))
        shape = _ENTRY_SHAPES[entry] if entry != "recent_errors" else (draw(st.integers(0, 12)),)
        array = rng.uniform(draw(st.sampled_from([0.0, -1.0, -1e3])), draw(st.sampled_from([1e-300, 1.0, 1e3, 1e10])),
                            size=shape)
        if array.size and draw(st.booleans()):
            array.flat[rng.integers(array.size)] = draw(st.sampled_from([np.nan, np.inf, -np.inf, 0.0, -1.0]))
        return kind, (entry, array)
    if kind == "extra":
        entry = draw(st.sampled_from(["extra", "grid2", "format", "../x", "surprised"]))
    return kind, (entry, _random_array(draw, _ENTRY_SHAPES.get(entry, (2,))))


_ENTRY_SHAPES = {"format": (), "params": (), "grid": (3, 6, 5, 4), "recent_errors": (10,), "adaptations": (),
                 "long_run_error": (), "memory": (), "residual_scale": (), "surprised": (),
                 "polynomial_coef": (20, 3), "polynomial_covariance": (20, 20), "polynomial_noise": (3,),
                 "pose_coef": (106, 3), "pose_covariance": (106, 106), "pose_noise": (3,), "fit_errors": (2,)}


@pytest.fixture(scope="module")
def valid_file(tmp_path_factory) -> bytes:
    path = tmp_path_factory.mktemp("valid") / "m.npz"
    write_map(_small_map(pose=True), path)
    return path.read_bytes()


@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(corruption=_corruptions())
def test_a_randomly_corrupted_file_gives_a_usable_map_or_map_file_error(tmp_path, valid_file, corruption):
    kind, what = corruption
    path = tmp_path / "corrupt.npz"
    raw = bytearray(valid_file)
    if kind == "flip":
        for where, mask in what:
            raw[int(where * len(raw))] ^= mask
        path.write_bytes(bytes(raw))
    elif kind == "truncate":
        path.write_bytes(bytes(raw[:int(what * len(raw))]))
    else:
        members = _members_of(bytes(raw))
        if kind == "remove":
            del members[f"{what}.npy"]
        else:
            name, array = what
            members[f"{name}.npy"] = _npy(array)
        _write_members(path, members)
    try:
        gm = read_map(path)
    except MapFileError as err:
        assert str(err).startswith(str(path))
        event(f"{kind}: refused")
        return
    event(f"{kind}: loaded")
    # Loaded: every value finite, and the map answers and learns.
    assert np.isfinite(gm.grid).all() and all(np.isfinite(gm.recent_errors))
    assert gm.polynomial is None or (np.isfinite(gm.polynomial.coef).all()
                                     and np.isfinite(gm.polynomial.covariance).all())
    with np.errstate(all="ignore"):
        assert np.isfinite(gm.command((16.0, 12.0, 0.0))).all()
        assert np.isfinite(gm.command((16.0, 12.0, 0.0), pose=POSE)).all()
        result = gm.adapt((10.0, 10.0, 1.0), (1.0, -1.0, 0.5), pose=POSE)
    assert result.accepted and np.isfinite(gm.grid).all() and np.isfinite(result.mean_retinal_error)


def _members_of(raw: bytes) -> dict[str, bytes]:
    with zipfile.ZipFile(io.BytesIO(raw)) as archive:
        return {info.filename: archive.read(info) for info in archive.infolist()}
