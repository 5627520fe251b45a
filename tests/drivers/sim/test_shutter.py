"""A frame rendered over its exposure (`drivers.sim.camera_effects.shutter`): motion blur only while the head
moves, and a rolling shutter's rows exposed one after another, so a vertical edge leans
while the head pans. A still head costs one render, as the ideal camera's."""
from __future__ import annotations

import numpy as np
import pytest

from drivers.sim.scene import Marker
from drivers.sim.camera_effects.shutter import RowBand, row_bands
from tests.support.sim_camera import REST, PanningPose, sim_camera, wall_scene

SIZE = (320, 240)
RATE_DEG_S = 150.0  # the pan's speed once it moves (from 1 s on)
EXPOSURE_S = 0.01  # the reference exposure (no auto exposure here)


def _edge_scene():
    """The far wall with a dark half-plane to the right of a vertical edge straight ahead (a
    disc 1.2 m in radius: its edge is nearly straight over the view), in 2.5 mm texels."""
    return wall_scene(markers=[Marker((0.4, -1.2, 0.0), 1.2, (40, 40, 40))], half_width_m=3.0, texels_per_m=400.0)


def _edge_column(row: np.ndarray) -> float:
    """Where a row crosses halfway from the bright side (left) to the dark side, sub-pixel."""
    row = row.astype(float)
    middle = (np.median(row[:40]) + np.median(row[-40:])) / 2
    below = np.flatnonzero((row[:-1] >= middle) & (row[1:] < middle))
    assert len(below) == 1, f"{len(below)} edges in the row"
    i = below[0]
    return float(i + (row[i] - middle) / (row[i] - row[i + 1]))


def _still(camera, time_s: float) -> np.ndarray:
    """What an ideal camera shows at the pan of `time_s`."""
    return camera.render(PanningPose(RATE_DEG_S, 1.0).at(time_s), time_s)


def test_motion_blur_spreads_an_edge_over_the_exposures_motion_only_while_moving():
    scene, pose = _edge_scene(), PanningPose(RATE_DEG_S, start_s=1.0)
    with sim_camera({"motion_blur": True, "blur_samples_max": 16}, size=SIZE, scene=scene, pose=pose) as camera, \
            sim_camera({}, size=SIZE, scene=scene) as ideal:
        renders = camera._shutter.renders
        still = camera.render(pose.at(0.5), 0.5)
        assert camera._shutter.renders == renders + 1  # a still head: one render
        assert np.array_equal(still, ideal.render(pose.at(0.5), 0.5))
        t = 1.05
        blurred = camera.render(pose.at(t), t)
        assert camera._shutter.renders > renders + 2
        # The exposure as a box filter over time, from 32 still renders.
        reference = np.mean([_still(ideal, t + EXPOSURE_S * (k + 0.5) / 32).astype(float) for k in range(32)], axis=0)
        start, end = (_edge_column(_still(ideal, s)[120]) for s in (t, t + EXPOSURE_S))
    travel = abs(end - start)
    assert travel > 4.0  # pixels the edge moves during the exposure
    row, sharp = blurred[120].astype(float), still[120].astype(float)
    assert np.abs(row - reference[120]).max() < 8.0 and np.abs(row - reference[120]).mean() < 1.0

    def ramp_width(profile):
        low, high = np.median(profile[-40:]), np.median(profile[:40])
        inside = (profile < low + 0.9 * (high - low)) & (profile > low + 0.1 * (high - low))
        return int(inside.sum())
    assert ramp_width(sharp) <= 3 and 0.6 * travel <= ramp_width(row) <= travel + 3


def test_a_vertical_edge_leans_by_the_rolling_shutters_skew_while_panning():
    readout_s, bands = 0.03, 24
    scene, pose = _edge_scene(), PanningPose(RATE_DEG_S, start_s=1.0)
    sensor = {"readout_s": readout_s, "readout_bands": bands}
    with sim_camera(sensor, size=SIZE, scene=scene, pose=pose) as camera, sim_camera({}, size=SIZE, scene=scene) as ideal:
        still = camera.render(pose.at(0.5), 0.5)
        flat = ideal.render(pose.at(0.5), 0.5)
        t = 1.05
        skewed = camera.render(pose.at(t), t)
        columns, expected, first = [], [], []
        for r in (12, 60, 120, 180, 228):
            # Row r's exposure starts r / height of the readout after the first row's.
            row_time = t + readout_s * r / SIZE[1] + EXPOSURE_S / 2
            columns.append(_edge_column(skewed[r]))
            expected.append(_edge_column(_still(ideal, row_time)[r]))
            first.append(_edge_column(_still(ideal, t + EXPOSURE_S / 2)[r]))
    assert np.array_equal(still, flat)  # no lean while still
    # A band's rows share its middle row's time: within half a band (0.6 ms, 0.1 deg) of the row's.
    assert columns == pytest.approx(expected, abs=0.5)
    # Against the image all rows would show at the first row's time, later rows lag further
    # behind (most in the middle rows, where the fish-eye magnifies most).
    skew = np.subtract(columns, first)
    assert np.all(np.diff(skew) > 0.5) and skew[2] > 6.0, skew


def test_row_bands_split_the_rows_evenly_and_render_their_part_of_the_lens():
    assert row_bands(10, 3) == [slice(0, 3), slice(3, 7), slice(7, 10)]
    assert len(row_bands(5, 64)) == 5
    camera = sim_camera({})
    band = RowBand(camera.lens, slice(40, 60))
    uv = np.array([[10.0, 0.0], [100.0, 19.0]])
    assert np.allclose(band.unproject(uv), camera.lens.unproject(uv + [0.0, 40.0]))
    back, seen = band.project(camera.lens.unproject(np.array([[10.0, 45.0], [10.0, 70.0]])))
    assert np.allclose(back, [[10.0, 5.0], [10.0, 30.0]]) and seen.tolist() == [True, False]
