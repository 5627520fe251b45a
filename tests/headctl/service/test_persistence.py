"""Map restore with its fallbacks and atomic checkpoints (headctl.service.persistence)."""
from __future__ import annotations

import numpy as np

from calib_free import GazeMap
from calib_free.adapter import MapAdapter, Sample
from headctl.config import load_config
from headctl.service.persistence import Checkpointer, restore_map


def _config(tmp_path):
    return load_config().with_state_dir(tmp_path)


def test_restore_starts_fresh_then_loads_what_was_saved(tmp_path):
    config = _config(tmp_path)
    gm, source, problems = restore_map(config)
    assert source == "new" and not problems
    gm.adapt((160, 120, -10), (1.0, 2.0, -1.0))
    gm.save(config.map_path)
    again, source, problems = restore_map(config)
    assert source == str(config.map_path) and again.adaptations == 1 and not problems
    assert np.allclose(again.command((100, 100, 0)), gm.command((100, 100, 0)))


def test_a_corrupt_map_is_reported_moved_aside_and_the_previous_one_used(tmp_path):
    config = _config(tmp_path)
    gm, _, _ = restore_map(config)
    gm.save(config.map_path)
    gm.adapt((160, 120, -10), (1.0, 2.0, -1.0))
    gm.save(config.map_path)  # the first save is now .prev
    config.map_path.write_bytes(b"not a map")
    restored, source, problems = restore_map(config)
    assert source == f"{config.map_path}.prev" and restored.adaptations == 0
    assert len(problems) == 1 and "not a readable gaze map file" in problems[0]
    assert (tmp_path / "gaze_map.npz.bad").read_bytes() == b"not a map"
    assert GazeMap.load(config.map_path).adaptations == 0  # a good main file again


def test_a_map_for_other_parameters_is_refused(tmp_path):
    config = _config(tmp_path)
    GazeMap.for_image(640, 480).save(config.map_path)
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
    assert GazeMap.load(config.map_path).adaptations == 4
    assert GazeMap.load(f"{config.map_path}.prev").adaptations == 2


