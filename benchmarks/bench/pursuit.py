"""Smooth pursuit on the real-time simulated daemon: frame-to-command latency and tracking error.

For each speed, a daemon (in this process: servo loop in its own process, 30 fps cameras,
exploration off) runs with a cube sweeping in its room (`sim_objects`) and a map learned on the
geometric head model; a track is started on the cube's front face through the API and runs for
`--seconds`. With `--start fixated` (the default, as `headctl experiment pursuit` does on the
manual clock) the cube rests at its sweep's centre while the head looks at it and settles, the
track starts there on the fovea, and the sweep once the track has found its first pair; with
`--start anywhere` the track starts half a second after the daemon, wherever the moving cube is
then (the client's target and the tracker's first pair are tens of milliseconds apart, so the
patch taken is not quite the face's centre the truth measures from: an offset of speed x that
delay). Reported from the daemon's own track figures: the frame-to-command latency
(exposure of a pair to its goal written by the servo loop) and the retinal error of the patch
as the tracker measured it; and the ground truth: the cube's distance from the left fovea,
sampled every 20 ms (after the first second), the cube and the servos' true positions taken at
one instant 20 ms in the past (the simulated world's trace of the joints). Also how late the
simulated cameras rendered their frames (from a frame's timestamp to its render's start, and
to its image ready; what a frame shows is the world at its timestamp all the same) and the
load average (1 min) before and after each speed.

    .venv/bin/python -m benchmarks.bench.pursuit [--config configs/sim.yaml] [--speeds 10,20,30] [--seconds 8]

The map is learned on the geometric head model, the same for every config (the nominal
lenses and exact servos): a realistic world's tracker starts from a map that does not know
its lens and servo differences.
"""
from __future__ import annotations

import argparse
import dataclasses
import math
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from calib_free.map.file import write_map
from drivers.sim.motion import MovingObject
from headctl.api.client import ApiClient
from headctl.api.compose import serve
from headctl.config.head import DEFAULT_CONFIG, load_config
from headctl.experiments.online import SimulatedHeadRig
from headctl.experiments.pursuit import learned_map

TRUTH_DELAY_S = 0.02  # the truth is taken this far in the past: inside the joints' trace, never extrapolated


def cube_in_left_image(world, cube: MovingObject, time_s: float, lens) -> np.ndarray:
    """The cube's front-face centre in the left image at `time_s`, both from the same instant,
    through `lens`, the left camera's own (a simulated unit's lens differs from the model's)."""
    point = cube.centre(world.scene.motion.elapsed_s(time_s)) - np.array([cube.size_m / 2, 0.0, 0.0])
    j = world.true_joints_at(time_s)
    (rotation, centre), _ = world.model.eye_frames_from_joints(j["pan"], j["tilt"], j["left_eye"], j["right_eye"])
    uv, _ = lens.project((rotation @ (point - centre))[None])
    return np.asarray(uv[0])


def look_at_sweep_centre(daemon, world, cube: MovingObject) -> None:
    """The head at the sweep's centre (pan, tilt, the vergence of its distance), settled. The
    bench moves the head itself: exploration is off, so the fixation thread is idle until the
    track is queued."""
    head = daemon.parts.running.head
    vergence = math.degrees(2 * math.atan(world.model.baseline_m / 2 / cube.distance_m))
    head.move_to(np.array([cube.azimuth_deg, cube.elevation_deg, vergence]))
    head.wait_settled(3.0)


def render_lags_ms(cameras) -> str:
    """Quantiles of how late both eyes rendered their frames, ms after the frames' timestamps."""
    lags = [lag for camera in cameras.values() if hasattr(camera, "render_lags_s") for lag in camera.render_lags_s()]
    if not lags:
        return "no simulated frames"
    start, ready = (np.asarray([lag[i] for lag in lags]) * 1e3 for i in (1, 2))
    return (f"render start p50 {np.percentile(start, 50):.1f} / p95 {np.percentile(start, 95):.1f} ms, "
            f"image ready p50 {np.percentile(ready, 50):.1f} / p95 {np.percentile(ready, 95):.1f} / "
            f"max {ready.max():.1f} ms after the timestamp ({len(lags)} frames)")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--config", type=Path, default=DEFAULT_CONFIG,
                        help="the simulated head (default: the packaged sim.yaml, the realistic world)")
    parser.add_argument("--speeds", default="10,20,30")
    parser.add_argument("--seconds", type=float, default=8.0)
    parser.add_argument("--start", choices=("fixated", "anywhere"), default="fixated")
    parser.add_argument("--lead-ms", type=float, default=None,
                        help="the pursuit's lead (tracking.lead_s; default: the config's)")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp, SimulatedHeadRig(config=load_config(args.config)) as rig:
        state = Path(tmp)
        write_map(learned_map(rig), state / "gaze_map.npz")
        for speed in (float(s) for s in args.speeds.split(",")):
            cube = MovingObject(speed_deg_s=speed)
            config = load_config(args.config).with_state_dir(state).with_api(port=0)
            config = dataclasses.replace(config, sim_objects=(cube,),
                                         fixation=dataclasses.replace(config.fixation, explore=False))
            if args.lead_ms is not None:
                params = dataclasses.replace(config.tracking.params, lead_s=args.lead_ms / 1000.0)
                config = dataclasses.replace(config, tracking=dataclasses.replace(config.tracking, params=params))
            load_before = os.getloadavg()[0]
            with serve(config) as daemon:
                client = ApiClient(daemon.api_url)
                world = daemon.parts.devices.world
                lens = getattr(daemon.parts.devices.cameras["left"], "unit_lens", world.model.lens_left)
                time.sleep(0.5)
                if args.start == "fixated":
                    world.scene.motion.start_s = math.inf  # the cube rests at its sweep's centre
                    look_at_sweep_centre(daemon, world, cube)
                    time.sleep(TRUTH_DELAY_S)
                x, y = cube_in_left_image(world, cube, time.monotonic() - TRUTH_DELAY_S, lens)
                client.track(float(x), float(y))
                if args.start == "fixated":
                    deadline = time.monotonic() + 5.0
                    while not (client.get_track()["result"].get("stats") or {}).get("found"):
                        if time.monotonic() > deadline:
                            track = client.get_track()
                            raise SystemExit(f"{speed:g} deg/s: the track found no patch within 5 s: "
                                             f"{track['state']} {track['outcome']} {track['detail']}")
                        time.sleep(0.005)
                    world.scene.motion.start_s = time.monotonic()  # the sweep starts from the centre
                started = time.monotonic()
                truth = []
                while time.monotonic() - started < args.seconds:
                    time.sleep(0.02)
                    if time.monotonic() - started >= 1.0:
                        uv = cube_in_left_image(world, cube, time.monotonic() - TRUTH_DELAY_S, lens)
                        truth.append(float(np.hypot(*(uv - (159.5, 119.5)))))
                track = client.get_track()
                stats = track["result"].get("stats") or {}
                if track["state"] == "running":
                    client.stop_track()
                lags = render_lags_ms(daemon.parts.devices.cameras)
            latency, error = stats.get("frame_to_command_ms", {}), stats.get("retinal_error_px", {})
            t = np.asarray(truth)
            print(f"{speed:5.0f} deg/s: {track['state']} {track['outcome']}; {stats.get('found')} pairs; "
                  f"frame-to-command p50 {latency.get('p50', 0):.1f} ms, p95 {latency.get('p95', 0):.1f} ms; "
                  f"tracker's retinal error rms {error.get('rms', 0):.2f} px, p95 {error.get('p95', 0):.2f} px; "
                  f"true error rms {np.sqrt(np.mean(t ** 2)):.2f} px, p95 {np.percentile(t, 95):.2f} px; "
                  f"load {load_before:.1f} -> {os.getloadavg()[0]:.1f}")
            print(f"        cameras: {lags}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
