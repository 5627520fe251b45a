"""Benchmark: looks at random pixels on the real-time simulated daemon after it explored.

The daemon (`headctl.api.compose.serve`, in this process: servo loop in its own process,
streamed cameras, the adapter learning, as `headctl run` does) explores from a random map for
`--explore-s` seconds; exploration is then switched off and each of `--looks` looks starts
from a head near the centre of its range: an angles look to pan and tilt drawn within
±`--spread` degrees of 0 (the vergence as it is), then a look at a uniformly random pixel of the
left image sent without d (`POST /api/v1/look/target`, the daemon measures d or refuses the
pixel with 422, as it does one the map sends beyond the joint limits). Reported: the share
ending on target (`done`) of all looks, of those within reach and of those the daemon took on
(not refused), the final error's quantiles
(the daemon's own, on target), the look's wall time (`duration_s`), and the others' outcomes
and details; the looks taken on whose first saccade the map sent beyond the pan or tilt limits,
by how far, and how many of those ended on target (what the API's reach margin,
`calib_free.gaze.look_geometry.REACH_MARGIN_DEG`, refuses or lets through); beside them the truth, the world point the pixel showed before the look (the
first surface along its ray through the left camera's own lens) projected at the servos' true
final position, its distance from the fovea.

    .venv/bin/python -m benchmarks.bench.looks_daemon [--config configs/sim.yaml] [--explore-s 300]
        [--looks 60] [--spread 5] [--seed 0] [--json FILE]
"""
from __future__ import annotations

import argparse
import collections
import json
import os
import re
import sys
import tempfile
import time
from pathlib import Path
from typing import Any, Callable

import numpy as np

from benchmarks.bench.looks import finishing_steps, second_attempts, world_error_px
from calib_free.gaze.fixation import LookParams
from headctl.api.client import ApiClient, ApiError
from headctl.api.compose import serve
from headctl.config.head import DEFAULT_CONFIG, load_config


def beyond_deg(goal: list[float] | None, low: np.ndarray, high: np.ndarray) -> float | None:
    """How far (deg) the first saccade's pan or tilt goal lay beyond the joint limits (0 within)."""
    if goal is None:
        return None
    return float(max(0.0, *(max(low[i] - goal[i], goal[i] - high[i]) for i in range(2))))


def one_look(client: ApiClient, world, lens, rng, spread: float, width: int, height: int,
             vergence_range: tuple[float, float], low: np.ndarray, high: np.ndarray,
             before_post: Callable[[dict[str, float], tuple[float, float]], None] | None = None) -> dict[str, Any]:
    """One look from a head near the centre at a random pixel, with its truth; `before_post`
    is told the servos' true joints and the pixel just before the look is sent."""
    pan, tilt = (float(rng.uniform(-spread, spread)) for _ in range(2))
    vergence = float(np.clip(client.state()["pose"]["vergence"], vergence_range[0] + 0.5, vergence_range[1] - 0.5))
    client.look_angles(pan, tilt, vergence, wait_s=10.0)  # the vergence as it is, inside its range
    time.sleep(0.1)  # a pair exposed at rest
    x, y = float(rng.uniform(0, width - 1)), float(rng.uniform(0, height - 1))
    before = world.true_joints()
    if before_post is not None:
        before_post(before, (x, y))
    try:
        answer = client.look_target(x, y, wait_s=20.0)
    except ApiError as err:
        return {"xy": [x, y], "state": "refused", "outcome": f"{err.status}", "detail": str(err), "on_target": False}
    result = answer.get("result") or {}
    truth, hidden = world_error_px(world.model, world.scene, lens, before, world.true_joints(), (x, y))
    planned, pose_before = result.get("planned"), result.get("pose_before")
    goal = None if planned is None or pose_before is None else [a + b for a, b in zip(pose_before, planned)]
    pose_after = result.get("pose_after")  # after the look's last fixation
    # Where the eyes ended against the vergence the first saccade planned for the target's d:
    # the look's own judgement of another depth (`max_vergence_mismatch_deg`).
    vergence_off = None if goal is None or pose_after is None \
        else float(pose_after[2] - np.clip(goal[2], *vergence_range))
    return {"xy": [x, y], "start": [pan, tilt], "state": str(answer["state"]), "outcome": answer["outcome"],
            "detail": answer["detail"], "on_target": bool(result.get("on_target")),
            "final_error_px": result.get("final_error_px"), "duration_s": result.get("duration_s"),
            "corrective_steps": result.get("corrective_steps"), "attempts": result.get("attempts"),
            "d_measured": answer["request"].get("d_measured"),
            "true_error_px": truth, "hidden": hidden, "first_goal": goal,
            "first_goal_beyond_deg": beyond_deg(goal, low, high), "final_pose": pose_after,
            "vergence_off_deg": vergence_off}


def failure_kind(row: dict[str, Any]) -> str:
    """A failed look's kind: its state, outcome and the first clause of its detail, without the
    pixel's coordinates and the figures."""
    if row["state"] == "refused" and "beyond the joint limits" in row["detail"]:
        return f"refused ({row['outcome']}): beyond the joint limits"
    if row["state"] == "refused":  # why the look's patch cannot find it (after why d was not measured)
        detail = re.sub(r"^the target's patch at \([^)]*\) ", "", row["detail"].split("cannot be looked at: ")[-1])
        return f"refused ({row['outcome']}): " + re.split(r"[;:(]", detail)[0].strip()
    if row["outcome"].startswith("target beyond the joint limits"):
        return f"{row['state']}: {row['outcome']}"
    clause = re.split(r"[;:(]", row["detail"])[0]
    return f"{row['state']}: {row['outcome']}: " + re.sub(r"-?\d+(\.\d+)?", "#", clause).strip()


def beyond_bands(rows: list[dict[str, Any]]) -> dict[str, list[dict[str, Any]]]:
    bands: dict[str, list[dict[str, Any]]] = {"0-0.25 deg": [], "0.25-0.5 deg": [], "0.5-1 deg": [], "over 1 deg": []}
    for r in rows:
        b = r.get("first_goal_beyond_deg")
        if b is None or b <= 0.0:
            continue
        key = "0-0.25 deg" if b <= 0.25 else "0.25-0.5 deg" if b <= 0.5 else "0.5-1 deg" if b <= 1.0 else "over 1 deg"
        bands[key].append(r)
    return bands


def summary(rows: list[dict[str, Any]], max_corrective_steps: int = LookParams().max_corrective_steps
            ) -> dict[str, Any]:
    on = [r for r in rows if r["on_target"]]
    run = [r for r in rows if r["state"] != "refused"]

    def q(values: list[float], p: float) -> float | None:
        return float(np.percentile(values, p)) if values else None

    final = [r["final_error_px"] for r in on]
    times = [r["duration_s"] for r in run if r.get("duration_s") is not None]
    truth = [r["true_error_px"] for r in on]
    failed = collections.Counter(failure_kind(r) for r in rows if not r["on_target"])
    reachable = [r for r in rows if not r["outcome"].startswith("target beyond the joint limits")
                 and "beyond the joint limits" not in r["detail"]]
    run_within_reach = [r for r in run if not r["outcome"].startswith("target beyond the joint limits")]
    return {"looks": len(rows), "on_target": len(on), "on_target_fraction": len(on) / len(rows),
            "on_target_fraction_of_reachable": len(on) / len(reachable) if reachable else None,
            # of the looks the daemon took on: not refused before the head moved (422)
            "on_target_fraction_of_accepted": len(on) / len(run) if run else None,
            # the same, leaving out the looks taken on that ended at the joint limits, the target
            # beyond them (a reason a client can act on: the head cannot reach it)
            "on_target_fraction_of_accepted_within_reach":
                len(on) / len(run_within_reach) if run_within_reach else None,
            "refused_422": len(rows) - len(run),
            "final_error_px": {"p50": q(final, 50), "p90": q(final, 90), "max": q(final, 100)},
            "duration_s": {"p50": q(times, 50), "p90": q(times, 90)},
            "true_error_px_on_target": {"p50": q(truth, 50), "p90": q(truth, 90), "max": q(truth, 100),
                                        "over_3px": sum(t > 3 for t in truth)},
            "d_not_measured": sum(r.get("d_measured") is False for r in run),
            "second_attempts": second_attempts(run),
            "finishing_steps": finishing_steps(run, max_corrective_steps),
            # the looks taken on whose first saccade the map sent beyond the pan or tilt limits,
            # by how far, and how many of them ended on target: what the API's reach margin costs
            "first_goal_beyond": {band: {"looks": len(mine), "on_target": sum(r["on_target"] for r in mine)}
                                  for band, mine in beyond_bands(run).items()},
            "failures": dict(failed.most_common())}


def look_arguments(description: str | None) -> argparse.ArgumentParser:
    """The options of a run of looks on the daemon (this benchmark's, and the diagnostics')."""
    parser = argparse.ArgumentParser(description=description, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--config", type=Path, default=DEFAULT_CONFIG, help="the head's config (default: sim.yaml)")
    parser.add_argument("--explore-s", type=float, default=300.0, help="seconds of exploring first (default 300)")
    parser.add_argument("--looks", type=int, default=60)
    parser.add_argument("--spread", type=float, default=5.0, help="start pan and tilt within ±this (deg, default 5)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--json", type=Path, help="write every look and the summary here")
    return parser


def run_looks(client: ApiClient, config, world, lens, rng, spread: float, looks: int,
              before_post: Callable[[dict[str, float], tuple[float, float]], None] | None = None,
              after_look: Callable[[dict[str, Any]], dict[str, Any]] | None = None) -> list[dict[str, Any]]:
    """`looks` looks (`one_look`) within the config's image and limits; `after_look` may add
    to each row."""
    width, height = config.cameras.left.width, config.cameras.left.height
    verge = config.fixation.vergence_range or (-90.0, 90.0)
    joints = config.servo_bus.joints
    low = np.array([joints["pan"].min_angle, joints["tilt"].min_angle])
    high = np.array([joints["pan"].max_angle, joints["tilt"].max_angle])
    rows = []
    for _ in range(looks):
        row = one_look(client, world, lens, rng, spread, width, height, verge, low, high, before_post)
        rows.append(after_look(row) if after_look is not None else row)
    return rows


def main() -> int:
    args = look_arguments(__doc__).parse_args()
    rng = np.random.default_rng(args.seed)
    with tempfile.TemporaryDirectory(prefix="bench-looks-") as state:
        config = load_config(args.config).with_state_dir(Path(state)).with_api(port=0)
        load = [os.getloadavg()[0]]
        with serve(config) as daemon:
            client = ApiClient(daemon.api_url)
            world = daemon.parts.devices.world
            lens = daemon.parts.devices.cameras["left"].unit_lens
            time.sleep(args.explore_s)
            explored = client.state()
            client.set_exploration(False)
            load.append(os.getloadavg()[0])
            rows = run_looks(client, config, world, lens, rng, args.spread, args.looks)
            load.append(os.getloadavg()[0])
    fix = explored["fixation"]
    out = {"config": args.config.name, "world": (explored.get("world") or {}).get("kind"),
           "explore_s": args.explore_s, "fixations": fix.get("done"), "taught": fix.get("taught"),
           "load_average": load, **summary(rows, config.fixation.params.look.max_corrective_steps)}
    report(out, {"rows": rows}, args.json)
    return 0


def report(out: dict[str, Any], detail: dict[str, Any], path: Path | None) -> None:
    """The summary `out` printed, and written with `detail` (every look) to `path` if given."""
    print(json.dumps(out, indent=2))
    if path is not None:
        path.write_text(json.dumps({**out, **detail}, indent=1, default=float) + "\n")


if __name__ == "__main__":
    sys.exit(main())
