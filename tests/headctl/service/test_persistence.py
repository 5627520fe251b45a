"""Map restore with its fallbacks, leftover temporary files, and atomic checkpoints by count and on
time (headctl.service.persistence)."""
from __future__ import annotations

import contextlib
import dataclasses
import errno
import io
import json
import logging
import os
import re
import zipfile
from pathlib import Path

import numpy as np
import pytest
import yaml

from calib_free.gaze.magnification import MIN_SAMPLES, LearnedMagnification
from calib_free.map.file import read_map, temporary_files, write_map
from calib_free.map.gaze_map import GazeMap
from calib_free.map.adapter import MapAdapter, Sample
from drivers.clock import ManualClock
from headctl.api.client import ApiClient, ApiError
from headctl.config.head import load_config
from headctl.errors import ConfigError, ControlError
from headctl.service.parts import MapOrigin
from headctl.service.persistence import Checkpointer, MagnificationFile, restore_magnification, restore_map
from tests.conftest import sim_head_config, wait_until
from tests.support import CONFIGS


def _config(tmp_path):
    return load_config().with_state_dir(tmp_path)


def test_restore_starts_fresh_then_loads_what_was_saved(tmp_path):
    config = _config(tmp_path)
    gm, source, problems = restore_map(config)
    assert source == "new" and not problems
    gm.adapt((160, 120, -10), (1.0, 2.0, -1.0))
    write_map(gm, config.map_path)
    again, source, problems = restore_map(config)
    assert source == str(config.map_path) and again.adaptations == 1 and not problems
    assert np.allclose(again.command((100, 100, 0)), gm.command((100, 100, 0)))


def test_a_corrupt_map_is_reported_moved_aside_and_the_previous_one_used(tmp_path):
    config = _config(tmp_path)
    gm, _, _ = restore_map(config)
    write_map(gm, config.map_path)
    gm.adapt((160, 120, -10), (1.0, 2.0, -1.0))
    write_map(gm, config.map_path)  # the first save is now .prev
    config.map_path.write_bytes(b"not a map")
    restored, source, problems = restore_map(config)
    assert source == f"{config.map_path}.prev" and restored.adaptations == 0
    assert len(problems) == 1 and "not a readable gaze map file" in problems[0]
    assert (tmp_path / "gaze_map.npz.bad").read_bytes() == b"not a map"
    assert read_map(config.map_path).adaptations == 0  # a good main file again


def test_a_map_for_other_parameters_is_refused(tmp_path):
    config = _config(tmp_path)
    write_map(GazeMap.for_image(640, 480), config.map_path)
    gm, source, problems = restore_map(config)
    assert source == "new" and "saved for other map parameters" in problems[0]


def test_checkpoints_every_n_adaptations_are_loadable(tmp_path):
    config = _config(tmp_path)
    gm, _, _ = restore_map(config)
    done = []
    with MapAdapter(gm) as adapter:
        cp = Checkpointer(adapter, config.map_path, every=2)
        adapter.on_adapted = lambda s, r: (done.append(r), cp.maybe(adapter.map.adaptations))
        for i in range(5):
            adapter.submit(Sample(np.array([100.0 + i, 120.0, -5.0]), np.array([1.0, 0.5, -0.5]), 1.0))
        assert adapter.wait_idle(10)
    assert cp.count == 2 and cp.last_adaptations == 4
    assert read_map(config.map_path).adaptations == 4
    assert read_map(f"{config.map_path}.prev").adaptations == 2




# --- no map file takes the service down ---------------------------------------------------------
def _rewritten(path, **entries):
    """`path` rewritten with `entries` (name -> .npy bytes) replacing or adding members."""
    with zipfile.ZipFile(path) as archive:
        members = {info.filename: archive.read(info) for info in archive.infolist()}
    members.update({f"{name}.npy": data for name, data in entries.items()})
    with zipfile.ZipFile(path, "w") as archive:
        for name, data in members.items():
            archive.writestr(name, data)


def _npy(array):
    buffer = io.BytesIO()
    np.lib.format.write_array(buffer, np.asanyarray(array))
    return buffer.getvalue()


_HUGE_GRID = (b"\x93NUMPY\x01\x00v\x00{'descr': '<f8', 'fortran_order': False, 'shape': (3, 1099511627776), }"
              + b" " * 43 + b"\n")

BAD_FILES = {
    "adaptations of two": lambda p: _rewritten(p, adaptations=_npy(np.array([1, 2]))),
    "a 2**40-element grid": lambda p: _rewritten(p, grid=_HUGE_GRID),
    "nan in recent errors": lambda p: _rewritten(p, recent_errors=_npy(np.array([0.1, np.nan]))),
    "nan in the grid": lambda p: _rewritten(p, grid=_npy(np.full((3, 100, 75, 21), np.nan))),
    "an unknown entry": lambda p: _rewritten(p, extra=_npy(np.zeros(2))),
    "not a zip": lambda p: p.write_bytes(b"not a map"),
    "an empty file": lambda p: p.write_bytes(b""),
    "truncated": lambda p: p.write_bytes(p.read_bytes()[:1000]),
}


def _good_main_and_prev(config):
    gm, _, _ = restore_map(config)
    write_map(gm, config.map_path)
    gm.adapt((160, 120, -10), (1.0, 2.0, -1.0))
    write_map(gm, config.map_path)  # the first save (0 adaptations) is now .prev


@pytest.mark.parametrize("bad", sorted(BAD_FILES))
def test_a_malformed_main_file_falls_back_to_prev(tmp_path, bad):
    config = _config(tmp_path)
    _good_main_and_prev(config)
    BAD_FILES[bad](config.map_path)
    gm, source, problems = restore_map(config)
    assert source == f"{config.map_path}.prev" and gm.adaptations == 0
    assert len(problems) == 1 and problems[0].startswith(f"{config.map_path}: ")
    assert (tmp_path / "gaze_map.npz.bad").exists() and read_map(config.map_path).adaptations == 0


def test_both_files_malformed_give_a_random_map_and_both_are_moved_aside(tmp_path):
    config = _config(tmp_path)
    _good_main_and_prev(config)
    BAD_FILES["adaptations of two"](config.map_path)
    BAD_FILES["nan in recent errors"](Path(f"{config.map_path}.prev"))
    gm, source, problems = restore_map(config)
    assert source == "new" and gm.adaptations == 0 and len(problems) == 2
    assert "'adaptations'" in problems[0] and "'recent_errors' holds nan" in problems[1]
    assert sorted(p.name for p in tmp_path.glob("gaze_map.npz*")) == ["gaze_map.npz.bad", "gaze_map.npz.prev.bad"]


def test_leftover_temporary_files_are_removed_at_start_and_logged(tmp_path, caplog):
    config = _config(tmp_path)
    _good_main_and_prev(config)
    leftovers = [tmp_path / "gaze_map.npz.k2j4_x9a.tmp", tmp_path / "gaze_map.npz.k2j4_x9a.tmp.prev",
                 tmp_path / "before-reset.npz.00aa11bb.tmp"]
    for leftover in leftovers:
        leftover.write_bytes(b"\0" * 1000)
    with caplog.at_level(logging.WARNING, logger="headctl.service.persistence"):
        gm, source, problems = restore_map(config)
    assert source == str(config.map_path) and not problems
    assert not any(p.exists() for p in leftovers)
    assert sum("temporary file of an interrupted save" in r.getMessage() for r in caplog.records) == 3
    assert sorted(p.name for p in tmp_path.iterdir()) == ["gaze_map.npz", "gaze_map.npz.prev"]


@pytest.mark.parametrize("prev_good", [True, False])
def test_the_service_starts_whatever_the_map_files_hold(tmp_path, start_service, prev_good):
    state = tmp_path / "state"
    config = sim_head_config(state)
    state.mkdir()
    _good_main_and_prev(config)
    BAD_FILES["a 2**40-element grid"](config.map_path)
    if not prev_good:
        BAD_FILES["nan in the grid"](Path(f"{config.map_path}.prev"))
    (state / "gaze_map.npz.abcdefgh.tmp").write_bytes(b"\0" * 100)
    daemon = start_service(config)
    status = daemon.control.snapshot().as_dict()
    json.dumps(status, allow_nan=False)
    assert status["state"] in ("running", "degraded")
    assert status["map"]["restored_from"] == (f"{config.map_path}.prev" if prev_good else "new")
    assert len(status["map"]["problems"]) == (1 if prev_good else 2)
    assert "'grid'" in status["map"]["problems"][0]
    assert not (state / "gaze_map.npz.abcdefgh.tmp").exists()


def test_loading_a_malformed_file_through_the_api_is_a_conflict_naming_the_file(tmp_path, start_service):
    config = sim_head_config(tmp_path / "state")
    daemon = start_service(config)
    client = ApiClient(daemon.api_url, timeout_s=10.0)
    for bad in ("adaptations of two", "a 2**40-element grid", "nan in recent errors", "not a zip"):
        path = config.state_dir / "bad.npz"
        write_map(GazeMap(config.map_params(), seed=1), path, keep_previous=False)
        BAD_FILES[bad](path)
        with pytest.raises(ControlError) as caught:
            daemon.control.load_map("bad.npz")
        assert caught.value.field == "name" and str(caught.value).startswith(f"{path}: ")
        with pytest.raises(ApiError) as answer:
            client.request("POST", "/api/v1/map/load", {"name": "bad.npz"})
        assert answer.value.status == 409 and answer.value.field == "name", bad
    # Every float of the map's in the status goes through `plain`: non-finite ones become null.
    daemon.parts.map_origin = MapOrigin("x", [], 3, [0.1, float("nan"), float("inf")])
    assert daemon.control.snapshot().as_dict()["map"]["restored"]["recent_retinal_errors"] == [0.1, None, None]
    assert client.state()["map"]["restored"]["recent_retinal_errors"] == [0.1, None, None]


# --- checkpoints on time ---------------------------------------------------------------------------
def _sample(i=0):
    return Sample(np.array([100.0 + i, 120.0, -5.0]), np.array([1.0, 0.5, -0.5]), 1.0)


def _learn(adapter, count):
    for i in range(count):
        adapter.submit(_sample(i))
    assert adapter.wait_idle(10)


@contextlib.contextmanager
def _checkpointing(tmp_path, every, interval_s=30.0):
    """(config, clock, adapter, checkpointer): a map adapting on its thread, checkpointed after
    each adaptation on a manual clock."""
    config = _config(tmp_path)
    clock = ManualClock()
    gm, _, _ = restore_map(config)
    with MapAdapter(gm) as adapter:
        cp = Checkpointer(adapter, config.map_path, every=every, clock=clock, interval_s=interval_s)
        adapter.on_adapted = lambda s, r: cp.maybe(adapter.map.adaptations)
        yield config, clock, adapter, cp


def test_checkpoints_come_on_time_as_well_and_only_for_a_changed_map(tmp_path):
    config = _config(tmp_path)
    clock = ManualClock()
    gm, _, _ = restore_map(config)
    with MapAdapter(gm) as adapter:
        cp = Checkpointer(adapter, config.map_path, every=1000, clock=clock, interval_s=30.0)
        adapter.on_adapted = lambda s, r: cp.maybe(adapter.map.adaptations)
        clock.advance(60.0)
        assert not cp.due() and not cp.maybe_on_time() and cp.count == 0  # nothing learned: nothing to save
        _learn(adapter, 3)  # 60 s since the last checkpoint: the adapter thread saves after the first
        assert cp.count == 1 and cp.last_adaptations == 1
        clock.advance(29.0)
        assert not cp.maybe_on_time()  # changed (3 vs 1) but not yet due
        clock.advance(1.0)
        assert cp.due() and cp.maybe_on_time() and cp.count == 2 and cp.last_adaptations == 3
        clock.advance(300.0)
        assert not cp.changed() and not cp.maybe_on_time() and cp.count == 2
        assert read_map(config.map_path).adaptations == 3
        adapter.replace_map(GazeMap(config.map_params(), seed=5))  # a reset is a change too
        assert cp.changed() and cp.maybe_on_time() and cp.last_adaptations == 0


def test_the_count_and_the_time_whichever_comes_first(tmp_path):
    with _checkpointing(tmp_path, every=4) as (config, clock, adapter, cp):
        _learn(adapter, 6)
        assert cp.count == 1 and cp.last_adaptations == 4  # by count, at 4
        clock.advance(30.0)
        assert cp.maybe_on_time() and cp.last_adaptations == 6  # by time, 2 adaptations later
        _learn(adapter, 4)
        assert cp.count == 3 and cp.last_adaptations == 10  # by count again, counted from the last one


def test_an_interval_of_0_checkpoints_by_count_only(tmp_path):
    with _checkpointing(tmp_path, every=50, interval_s=0.0) as (config, clock, adapter, cp):
        _learn(adapter, 3)
        clock.advance(1e6)
        assert cp.changed() and not cp.due() and not cp.maybe_on_time() and cp.count == 0


def test_a_failing_checkpoint_is_retried_at_the_same_pace_not_after_every_adaptation(tmp_path):
    config = _config(tmp_path)
    clock = ManualClock()
    gm, _, _ = restore_map(config)
    with MapAdapter(gm) as adapter:
        cp = Checkpointer(adapter, tmp_path / "absent" / "gaze_map.npz", every=2, clock=clock, interval_s=30.0)
        attempts = []
        adapter.on_adapted = lambda s, r: attempts.append(cp.maybe(adapter.map.adaptations))
        _learn(adapter, 3)
        assert cp.error and "checkpoint of gaze_map.npz failed: ENOENT" in cp.error and cp.count == 0
        assert attempts == [False, False, False]
        (tmp_path / "absent").mkdir()
        _learn(adapter, 1)  # 2 adaptations since the failed attempt
        assert cp.count == 1 and cp.error is None and cp.last_adaptations == 4


# --- a state directory full or read-only, then writable again --------------------------------------
class _FailingDisk:
    """The state directory refusing writes as a full (ENOSPC: the temporary file's bytes do not
    fit, half of them written) or a read-only (EROFS: no file can be created) file system does.
    Root ignores permissions, so the failure goes in at the file operations, for that directory only."""

    def __init__(self, monkeypatch, directory, code):
        self.directory, self.code, self.failed = str(directory), code, 0
        real_open, real_fdopen = os.open, os.fdopen

        def guarded_open(path, flags, *args, **kwargs):
            if self.active and code == errno.EROFS and flags & os.O_CREAT and str(path).startswith(self.directory):
                self.failed += 1
                raise OSError(errno.EROFS, os.strerror(errno.EROFS), str(path))
            return real_open(path, flags, *args, **kwargs)

        def guarded_fdopen(fd, *args, **kwargs):
            f = real_fdopen(fd, *args, **kwargs)
            if self.active and code == errno.ENOSPC and os.readlink(f"/proc/self/fd/{fd}").startswith(self.directory):
                return _FullFile(f, self)
            return f

        self.active = True
        monkeypatch.setattr(os, "open", guarded_open)
        monkeypatch.setattr(os, "fdopen", guarded_fdopen)


class _FullFile:
    def __init__(self, f, disk):
        self.f, self.disk = f, disk

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.f.close()

    def write(self, data):
        self.f.write(bytes(data)[:len(data) // 2])
        self.f.flush()
        self.disk.failed += 1
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    def __getattr__(self, name):
        return getattr(self.f, name)


@pytest.mark.parametrize("code", [errno.ENOSPC, errno.EROFS], ids=["full", "read-only"])
def test_checkpoints_fail_naming_the_directory_keep_the_last_good_one_and_resume(tmp_path, monkeypatch, code):
    with _checkpointing(tmp_path, every=2) as (config, clock, adapter, cp):
        _learn(adapter, 2)
        assert cp.count == 1 and read_map(config.map_path).adaptations == 2
        good = config.map_path.read_bytes()
        disk = _FailingDisk(monkeypatch, tmp_path, code)
        _learn(adapter, 4)  # two attempts, both refused
        assert disk.failed == 2 and cp.failures == 2 and cp.count == 1
        name = errno.errorcode[code]
        assert cp.error == (f"state directory {tmp_path}: checkpoint of gaze_map.npz failed: {name} "
                            f"({os.strerror(code)}); the last good checkpoint (2 adaptations) is kept; "
                            "retried every 2 adaptations or 30 s")
        clock.advance(30.0)
        assert not cp.maybe_on_time() and cp.failures == 3  # on time too, at the same pace
        assert adapter.map.adaptations == 6  # learning goes on
        assert config.map_path.read_bytes() == good  # the last good checkpoint, intact
        assert not temporary_files(tmp_path)  # no half-written file left behind
        disk.active = False  # writable again
        _learn(adapter, 2)
        assert cp.count == 2 and cp.error is None and cp.failures == 0
        assert read_map(config.map_path).adaptations == 8
        assert read_map(f"{config.map_path}.prev").adaptations == 2  # the last good one, now the previous


@pytest.mark.timeout(180)
def test_a_service_whose_state_directory_fills_up_is_degraded_goes_on_learning_and_heals(tmp_path, monkeypatch):
    from headctl.service.daemon import Daemon
    config = sim_head_config(tmp_path / "state")
    config = dataclasses.replace(config, service=dataclasses.replace(config.service, checkpoint_every=1))
    daemon = Daemon(config).start()
    try:
        cp = daemon.parts.running.checkpointer
        wait_until(lambda: cp.count >= 1, 90, "a first checkpoint")
        disk = _FailingDisk(monkeypatch, config.state_dir, errno.ENOSPC)
        faults = wait_until(lambda: daemon.control.snapshot().faults.get("checkpoint"), 90,
                            "the checkpoint fault")
        assert faults.startswith(f"state directory {config.state_dir}: checkpoint of gaze_map.npz failed: ENOSPC")
        assert daemon.control.snapshot().as_dict()["state"] == "degraded"
        good, kept = config.map_path.read_bytes(), cp.last_adaptations
        learned = daemon.parts.running.adapter.map.adaptations
        wait_until(lambda: daemon.parts.running.adapter.map.adaptations >= learned + 2, 90, "learning while degraded")
        assert config.map_path.read_bytes() == good and read_map(config.map_path).adaptations == kept
        disk.active = False
        wait_until(lambda: cp.error is None and cp.last_adaptations > kept, 90, "checkpoints resumed")
        wait_until(lambda: "checkpoint" not in daemon.control.snapshot().faults, 10, "the fault cleared")
        assert read_map(config.map_path).adaptations > kept
    finally:
        daemon.stop()


@pytest.mark.parametrize("value, error", [(None, None), (0, None), (5.5, None), (-1, "got -1"),
                                          (1e6, "expected a time in [0, 86400] s (0: off)")])
def test_the_checkpoint_interval_is_a_service_setting(tmp_path, value, error):
    data = yaml.safe_load((CONFIGS / "sim.yaml").read_text())
    if value is not None:
        data["service"]["checkpoint_interval_s"] = value
    path = tmp_path / "head.yaml"
    path.write_text(yaml.safe_dump(data))
    if error is None:
        assert load_config(path).service.checkpoint_interval_s == (30.0 if value is None else value)
    else:
        with pytest.raises(ConfigError, match=re.escape(f"service.checkpoint_interval_s: {error}")
                           if error.startswith("got") else re.escape(error)):
            load_config(path)


def test_the_simulated_full_disk_degrades_the_service_and_writable_again_heals_it(tmp_path):
    """`SimFault.STATE_DIR_FULL` / `STATE_DIR_WRITABLE`: the fault the soak and the API inject."""
    from headctl.service.control import SimFault
    from headctl.service.daemon import Daemon
    config = sim_head_config(tmp_path / "state")
    config = dataclasses.replace(config, service=dataclasses.replace(config.service, checkpoint_every=1))
    with Daemon(config) as daemon:
        cp = daemon.parts.running.checkpointer
        wait_until(lambda: cp.count >= 1, 90, "a first checkpoint")
        kept = cp.last_adaptations
        good = config.map_path.read_bytes()
        daemon.control.inject_fault(SimFault.STATE_DIR_FULL)
        fault = wait_until(lambda: daemon.control.snapshot().faults.get("checkpoint"), 90, "the checkpoint fault")
        assert "ENOSPC" in fault and str(config.state_dir) in fault
        assert config.map_path.read_bytes() == good  # the last good checkpoint untouched
        daemon.control.inject_fault(SimFault.STATE_DIR_WRITABLE)
        wait_until(lambda: cp.error is None and cp.last_adaptations > kept, 90, "checkpoints resumed")
        wait_until(lambda: "checkpoint" not in daemon.control.snapshot().faults, 10, "the fault cleared")


# --- the lens's magnification the looks learned ----------------------------------------------
def _profile(scale: float, count: int = MIN_SAMPLES) -> LearnedMagnification:
    profile = LearnedMagnification()
    for k in range(count):
        profile.record(80.0 + k, scale)
    return profile


def test_the_lens_magnification_is_saved_when_it_changed_and_restored(tmp_path):
    path = tmp_path / "lens_magnification.json"
    assert restore_magnification(path)[0].expected(85.0) is None and restore_magnification(path)[1] == []
    profile = LearnedMagnification()
    saver = MagnificationFile(path, profile)  # the profile as restored: nothing to save yet
    assert not saver.maybe_save() and not path.exists()
    for k in range(MIN_SAMPLES):
        profile.record(80.0 + k, 1.12)
    assert saver.maybe_save() and not saver.maybe_save()  # saved once; unchanged since
    restored, problems = restore_magnification(path)
    assert not problems and restored.expected(85.0) == pytest.approx(1.12)
    profile.record(150.0, 1.5)
    assert saver.maybe_save()
    assert json.loads(path.read_text())["scales_by_distance_px"]["150"] == [1.5]


def test_a_lens_magnification_that_cannot_be_saved_is_reported_once_and_saved_later(tmp_path, caplog):
    missing = tmp_path / "gone"
    profile = LearnedMagnification()
    saver = MagnificationFile(missing / "lens_magnification.json", profile)
    profile.record(80.0, 1.1)
    with caplog.at_level(logging.ERROR, logger="headctl.service.persistence"):
        assert not saver.maybe_save() and not saver.maybe_save()  # retried: still changed, still failing
    assert saver.error is not None and saver.error.startswith(f"{missing / 'lens_magnification.json'}: cannot save")
    assert len([r for r in caplog.records if "cannot save the lens magnification" in r.getMessage()]) == 1
    missing.mkdir()
    assert saver.maybe_save() and saver.error is None


@pytest.mark.parametrize("content", [b"{not json", b'{"format": 9}', b"\xff\xfe"])
def test_a_lens_magnification_file_that_cannot_be_used_is_moved_aside_and_learned_again(tmp_path, content):
    path = tmp_path / "lens_magnification.json"
    path.write_bytes(content)
    profile, problems = restore_magnification(path)
    assert profile.expected(85.0) is None and len(problems) == 1 and problems[0].startswith(f"{path}: ")
    assert not path.exists() and (tmp_path / "lens_magnification.json.bad").read_bytes() == content


def test_the_service_looks_with_the_saved_lens_magnification_and_saves_it_at_shutdown(tmp_path, start_service):
    config = sim_head_config(tmp_path / "state")
    config.state_dir.mkdir()
    MagnificationFile(config.magnification_path, _profile(1.2)).save()
    daemon = start_service(config)
    learned = daemon.parts.running.fixation.looker.magnification
    assert learned.expected(85.0) == pytest.approx(1.2)
    learned.record(200.0, 1.9)  # as a look on target records it
    daemon.stop()
    saved = json.loads(config.magnification_path.read_text())["scales_by_distance_px"]
    assert saved["80"] == [1.2] * MIN_SAMPLES and saved["200"] == [1.9]
