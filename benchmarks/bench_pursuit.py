"""Smooth pursuit on the real-time simulated daemon: frame-to-command latency and tracking error.

For each speed, a daemon (in this process: servo loop in its own process, 30 fps cameras,
exploration off) runs with a cube sweeping in its room (`sim_objects`) and a map learned on the
geometric head model; a track is started on the cube's front face through the API and runs for
`--seconds`. Reported from the daemon's own track figures: the frame-to-command latency
(exposure of a pair to its goal written by the servo loop) and the retinal error of the patch
as the tracker measured it; and the ground truth: the cube's distance from the left fovea,
sampled every 20 ms from the servos' true positions (after the first second).

    .venv/bin/python benchmarks/bench_pursuit.py [--speeds 10,30] [--seconds 8]
"""
from __future__ import annotations

import argparse
import dataclasses
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from drivers.sim_motion import MovingObject  # noqa: E402
from headctl.client import ApiClient  # noqa: E402
from headctl.config import load_config  # noqa: E402
from headctl.online import SimulatedHeadRig  # noqa: E402
from headctl.pursuit_experiment import learned_map  # noqa: E402
from headctl.service import Daemon  # noqa: E402


def cube_in_left_image(world, cube: MovingObject) -> np.ndarray:
    point = cube.centre(world.scene.motion.elapsed_s()) - np.array([cube.size_m / 2, 0.0, 0.0])
    j = world.true_joints()
    (rotation, centre), _ = world.model.eye_frames_from_joints(j["pan"], j["tilt"], j["left_eye"], j["right_eye"])
    uv, _ = world.model.lens_left.project((rotation @ (point - centre))[None])
    return np.asarray(uv[0])


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--speeds", default="10,30")
    parser.add_argument("--seconds", type=float, default=8.0)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp, SimulatedHeadRig() as rig:
        state = Path(tmp)
        learned_map(rig).save(state / "gaze_map.npz")
        for speed in (float(s) for s in args.speeds.split(",")):
            cube = MovingObject(speed_deg_s=speed)
            config = load_config().with_state_dir(state).with_api(port=0)
            config = dataclasses.replace(config, sim_objects=(cube,),
                                         fixation=dataclasses.replace(config.fixation, explore=False))
            with Daemon(config) as daemon:
                client = ApiClient(daemon.api_url)
                world = daemon.parts.devices.world
                time.sleep(0.5)
                x, y = cube_in_left_image(world, cube)
                client.track(float(x), float(y))
                started = time.monotonic()
                truth = []
                while time.monotonic() - started < args.seconds:
                    time.sleep(0.02)
                    if time.monotonic() - started >= 1.0:
                        truth.append(float(np.hypot(*(cube_in_left_image(world, cube) - (159.5, 119.5)))))
                track = client.get_track()
                stats = track["result"].get("stats") or {}
                if track["state"] == "running":
                    client.stop_track()
            latency, error = stats.get("frame_to_command_ms", {}), stats.get("retinal_error_px", {})
            t = np.asarray(truth)
            print(f"{speed:5.0f} deg/s: {track['state']} {track['outcome']}; {stats.get('found')} pairs; "
                  f"frame-to-command p50 {latency.get('p50', 0):.1f} ms, p95 {latency.get('p95', 0):.1f} ms; "
                  f"tracker's retinal error rms {error.get('rms', 0):.2f} px, p95 {error.get('p95', 0):.2f} px; "
                  f"true error rms {np.sqrt(np.mean(t ** 2)):.2f} px, p95 {np.percentile(t, 95):.2f} px")
    return 0


if __name__ == "__main__":
    sys.exit(main())
