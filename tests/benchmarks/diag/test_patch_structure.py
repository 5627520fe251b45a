"""The patch-structure diagnostic: an edge's structure tensor, and the rows it reads from recorded looks."""
from __future__ import annotations

import json

import numpy as np
import pytest

from benchmarks.diag import patch_structure
from benchmarks.diag.patch_structure import first_searches, structure


def test_a_straight_edge_has_structure_in_one_direction_and_noise_texture_in_every_one():
    edge = np.zeros((60, 60), np.float32)
    edge[:, 30:] = 100.0
    smaller, larger = structure(edge, (30.0, 30.0))
    assert smaller == pytest.approx(0.0, abs=1e-6) and larger > 1000.0
    texture = np.random.default_rng(0).uniform(0, 255, (60, 60)).astype(np.float32)
    smaller, larger = structure(texture, (30.0, 30.0))
    assert larger / smaller < 2.0
    assert structure(texture, (5.0, 30.0)) is None  # the patch reaches beyond the image


def test_first_searches_reads_each_look_taken_on_and_sorts_by_the_ratio(tmp_path):
    rng = np.random.default_rng(1)
    edge = np.zeros((60, 60), np.float32)
    edge[:, 30:] = 100.0
    edge += rng.normal(0, 1.0, edge.shape).astype(np.float32)
    texture = rng.uniform(0, 255, (60, 60)).astype(np.float32)
    for k, source in enumerate((edge, texture)):
        np.savez_compressed(tmp_path / f"search-{k:03d}.npz", source=source, source_xy=np.array([30.0, 30.0]))

    def look(saved, truth, search, on_target):
        return {"state": "done", "xy": [30.0, 30.0], "on_target": on_target,
                "steps": [{"aim": [30.0, 30.0, 0.0], "true_error_px": truth}, {"search": search, "saved": saved}]}

    steps = {"looks": [look(0, 0.3, 4.1, False), look(1, 0.2, 0.3, True),
                       {"state": "refused", "xy": [1.0, 1.0], "on_target": False, "steps": []}]}
    (tmp_path / "steps.json").write_text(json.dumps(steps))
    rows = first_searches(tmp_path / "steps.json", tmp_path, noise=2.3)
    assert [r["on_target"] for r in rows] == [True, False]  # the texture first, the edge last
    assert rows[0]["ratio"] < 2.0 < 20.0 < rows[1]["ratio"]
    assert rows[1]["truth_px"] == 0.3 and rows[1]["search_px"] == 4.1
    assert rows[1]["noise_bound_px"] > rows[0]["noise_bound_px"]


def test_rendered_ratios_counts_only_the_targets_the_look_accepts(monkeypatch):
    ratios = patch_structure.rendered_ratios(pixels=30, poses=1, seed=0)
    assert ratios.size > 0 and np.all(ratios >= 1.0)
    monkeypatch.setattr(patch_structure.target_patch, "target_patch_problem", lambda *args: "refused")
    assert patch_structure.rendered_ratios(pixels=30, poses=1, seed=0).size == 0
