"""Subcommands of `headctl` for the service: `run` (the daemon), `check` (a config), `status`.

`run [--config F]` runs the daemon (`headctl.service.daemon.Daemon`), its front ends the HTTP
API and the ROS 2 interface the config enables (`headctl.api.compose`), until SIGTERM/SIGINT;
without `--config` it runs the simulated head of `configs/sim.yaml`. `check --config F` validates a config and tries
every servo and camera it names, a line each (`headctl.cli.check`). Both prepare the
config in one way (`_prepare`), so `check`, with or without `--no-connect`, refuses a config
exactly where `run` would: exit 2 naming the file, the key path, the value and what was
expected. `status`, `look` and `track` are clients of the running daemon's HTTP API
(`headctl.api.client`).
"""
from __future__ import annotations

import argparse
import json
import logging
import sys
import time
from typing import TYPE_CHECKING

from drivers.errors import DriverError
from headctl import log_limit
from headctl.config.head import HeadConfig, check_runtime, load_config
from headctl.errors import ConfigError, HeadctlError
from headctl.json_types import JSONObject

if TYPE_CHECKING:
    from headctl.api.client import ApiClient

log = logging.getLogger(__name__)


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Add this module's subcommands to `sub`."""
    run = sub.add_parser(
        "run", help="run the service (default: the simulated head of configs/sim.yaml)",
        description="Run the daemon for one head until SIGTERM or SIGINT: servo loop, cameras, exploratory "
                    "fixations, online learning with checkpoints, the HTTP control API and dashboard, systemd "
                    "notifications.")
    _config_args(run)
    run.add_argument("--api-port", type=int, metavar="PORT",
                     help="override api.port (0: an ephemeral port, written to <state_dir>/api.url)")
    run.set_defaults(func=_run)

    check = sub.add_parser(
        "check", help="validate a head's config, then connect and report each servo and camera",
        description="Validate a config (file, key path, value and what was expected on error); unless "
                    "--no-connect, open the servo bus and both cameras and report each servo, the USB adapter's "
                    "latency timer and each camera with its exposure control, trying every part even when one "
                    "fails; exit 1 when any part failed.")
    _config_args(check)
    check.add_argument("--no-connect", action="store_true",
                       help="validate only: the file, the state directory and log file, the devices built but not "
                            "opened")
    check.add_argument("--timeout", type=float, default=5.0, metavar="S", help="seconds to wait for frames")
    check.set_defaults(func=_check)

    status = sub.add_parser(
        "status", help="the running daemon's state (joints, fixations, learning, faults)",
        description="Ask the running daemon through its HTTP API (GET /api/v1/state).")
    _client_args(status)
    status.add_argument("--json", action="store_true", help="print the whole state as JSON")
    status.set_defaults(func=_status)

    look = sub.add_parser(
        "look", help="look at an image target X Y [D] (px), or at joint angles with --angles P T V (deg)",
        description="Send a look to the running daemon and wait for it: an image target (x, y px in the left "
                    "image, disparity d px; without D the daemon measures it there) is fixated by a saccade "
                    "and fine vergence; --angles moves to pan, tilt, vergence (deg), --relative to the "
                    "present pose. Ctrl-C while waiting cancels the look.")
    _client_args(look)
    look.add_argument("values", nargs="+", type=float, metavar="X Y [D] | P T V",
                      help="x, y and optionally d (px); with --angles pan, tilt, vergence (deg)")
    look.add_argument("--angles", action="store_true", help="the values are pan, tilt, vergence in degrees")
    look.add_argument("--relative", action="store_true", help="with --angles: relative to the present pose")
    look.add_argument("--wait", type=float, default=20.0, metavar="S",
                      help="seconds to wait for the look to finish (0: queue it and print its id)")
    look.add_argument("--replace", action="store_true",
                      help="cancel the looks still queued and stop the running one first")
    look.add_argument("--json", action="store_true", help="print the look as JSON")
    look.set_defaults(func=_look)

    track = sub.add_parser(
        "track", help="pursue the target at X Y (px in the left image, or 'fovea'); --stop, --status",
        description="Start smooth pursuit on the running daemon: the patch at (x, y) of the left image (or what is "
                    "on the fovea) is kept on both foveae as it moves, until stopped (--stop, Ctrl-C while "
                    "--wait-ing), lost, or preempted by a look or another track. --status shows the last track.")
    _client_args(track)
    track.add_argument("target", nargs="*", metavar="X Y | fovea", help="x and y (px), or the word fovea")
    track.add_argument("--stop", action="store_true", help="stop the track running")
    track.add_argument("--status", action="store_true", help="show the last track and its figures")
    track.add_argument("--wait", type=float, default=0.0, metavar="S",
                       help="wait up to S seconds for the track to end (Ctrl-C stops it); 0: start it and return")
    track.add_argument("--json", action="store_true", help="print the track as JSON")
    track.set_defaults(func=_track)


def _config_args(parser: argparse.ArgumentParser, state_dir: bool = True) -> None:
    parser.add_argument("--config", metavar="FILE", help="the head's YAML file (default: configs/sim.yaml)")
    if state_dir:
        parser.add_argument("--state-dir", metavar="DIR", help="override the config's state_dir")


def _client_args(parser: argparse.ArgumentParser) -> None:
    _config_args(parser)
    parser.add_argument("--url", help="the daemon's API (default: from the state directory or the config)")
    parser.add_argument("--token", help="the API token (default: $HEADCTL_TOKEN, or the config's api.token)")
    parser.add_argument("--cacert", metavar="FILE",
                        help="HTTPS: the CA (or the daemon's own) certificate to check the daemon against "
                             "(default: the config's api.tls_cert, pinned; else the system's CAs)")


def _client(args: argparse.Namespace, command: str) -> ApiClient | None:
    from headctl.api.client import ApiClient, ApiError

    config = _load(args, command)
    if config is None:
        return None
    try:
        return ApiClient.for_config(config, url=args.url, token=args.token, cafile=args.cacert)
    except ApiError as err:
        print(f"headctl {command}: {err}", file=sys.stderr)
        return None


def _load(args: argparse.Namespace, command: str) -> HeadConfig | None:
    try:
        config = load_config(args.config)
    except ConfigError as err:
        print(f"headctl {command}: {err}", file=sys.stderr)
        return None
    if getattr(args, "state_dir", None):
        config = config.with_state_dir(args.state_dir)
    return config


def _prepare(args: argparse.Namespace, command: str) -> tuple[HeadConfig | None, int]:
    """The config as `run` uses it, checked as far as `run` checks it before it starts
    anything: the file (`load_config`), the command line's overrides, what running needs of
    this machine (`check_runtime`), and the devices built through their backends, not opened.
    (config, 0), or (None, the exit status): 2 for a config error, 1 for any other failure."""
    config = _load(args, command)
    if config is None:
        return None, 2
    api_port = getattr(args, "api_port", None)
    if api_port is not None:
        if not 0 <= api_port <= 65535:
            print(f"headctl {command}: --api-port {api_port}: expected a TCP port, 0 for an ephemeral one",
                  file=sys.stderr)
            return None, 2
        config = config.with_api(port=api_port)
    missing = _ros2_missing(config) or _foxglove_missing(config)
    if missing is not None:
        print(f"headctl {command}: {config.path}: {missing}", file=sys.stderr)
        return None, 1
    try:
        check_runtime(config)
        _build_devices(config)
    except ConfigError as err:
        if err.file is None:
            err.file = config.path
        print(f"headctl {command}: {err}", file=sys.stderr)
        return None, 2
    except (HeadctlError, DriverError, OSError) as err:
        print(f"headctl {command}: {err}", file=sys.stderr)
        return None, 1
    except Exception as err:  # a backend class of the user's own whose constructor fails
        print(f"headctl {command}: {config.path}: building the devices failed: {err!r}", file=sys.stderr)
        return None, 1
    return config, 0


def _ros2_missing(config: HeadConfig) -> str | None:
    """Why the ROS 2 interface the config enables cannot run here (its extra not installed)."""
    if not config.ros2.enabled:
        return None
    from headctl.ros2.interface import missing_dependency

    return missing_dependency()


def _foxglove_missing(config: HeadConfig) -> str | None:
    """Why the Foxglove view the config enables cannot run here (its extra not installed)."""
    if not config.foxglove.enabled:
        return None
    from headctl.foxglove.view import missing_dependency

    return missing_dependency()


def _build_devices(config: HeadConfig) -> None:
    """Build (not open) the servo bus and the cameras as `run` will: a backend's own checks of
    its config (a pixel format it does not know) are met here, before anything starts."""
    from headctl.service.build import HeadDevices

    HeadDevices.build(config)


def _apply_logging(config: HeadConfig, args: argparse.Namespace) -> None:
    root = logging.getLogger()
    if args.log_level == "INFO":  # the CLI's default: the config decides
        root.setLevel(getattr(logging, config.logging.level))
    log_limit.configure(config.logging.repeat_summary_s)
    if config.logging.file:
        handler = logging.FileHandler(config.logging.file)
        handler.setFormatter(logging.Formatter("%(asctime)s %(levelname)-7s %(name)s: %(message)s"))
        log_limit.install(handler, config.logging.repeat_summary_s)  # behind the same repeat limit as stderr


# --- run -------------------------------------------------------------------------------------
def _run(args: argparse.Namespace) -> int:
    from headctl.api.compose import front_ends
    from headctl.service.daemon import Daemon

    config, status = _prepare(args, "run")
    if config is None:
        return status
    try:
        _apply_logging(config, args)
    except OSError as err:  # the log file went away since check_runtime looked
        print(f"headctl run: {config.path}: logging.file: got {config.logging.file!r}, expected a file that can be "
              f"written ({err.strerror})", file=sys.stderr)
        return 2
    try:
        return Daemon(config, front_end=front_ends(config)).run()
    except (HeadctlError, DriverError, OSError) as err:
        log.error("headctl run: %s", err)
        print(f"headctl run: {err}", file=sys.stderr)
        return 1


# --- check -------------------------------------------------------------------------------------
def _check(args: argparse.Namespace) -> int:
    config, status = _prepare(args, "check")
    if config is None:
        return status
    params = config.map_params()
    print(f"{config.path}: valid")
    print(f"  servo bus: {config.servo_bus.backend} on {config.servo_bus.port} at {config.servo_bus.baud} baud")
    for side in ("left", "right"):
        cam = getattr(config.cameras, side)
        where = cam.device or cam.id or cam.serial or cam.eye or "first found"
        print(f"  camera {side}: {cam.backend} {where} {cam.width} x {cam.height} at {cam.fps or 'default'} fps")
    print(f"  gaze map: {params.profile} profile, grid {params.grid_shape}, disparity {params.disparity_range} px; "
          f"state in {config.state_dir}")
    ros2 = config.ros2
    if ros2.enabled:
        print(f"  ros2: node {ros2.namespace}/{ros2.node_name} on DDS domain {ros2.domain_id} ({ros2.distro}), "
              f"{'localhost only' if ros2.localhost_only else 'all interfaces'}, "
              f"commands {'accepted' if ros2.commands else 'off'}")
    if config.foxglove.enabled:
        print(f"  foxglove: live view on ws://{config.foxglove.host}:{config.foxglove.port}")
    if args.no_connect:
        return 0
    from headctl.cli.check import connect_and_report

    return connect_and_report(config, args.timeout)


# --- status ------------------------------------------------------------------------------------
def _status(args: argparse.Namespace) -> int:
    from headctl.api.client import ApiError

    client = _client(args, "status")
    if client is None:
        return 2
    try:
        status = client.state()
    except ApiError as err:
        print(f"headctl status: {err}", file=sys.stderr)
        return 1
    if args.json:
        print(json.dumps(status, indent=2))
        return 0
    print(format_status(status))
    return 0 if status["state"] == "running" else 3


def format_status(s: JSONObject) -> str:
    """The daemon's state for people."""
    lines = [f"{s['state']}  (pid {s['pid']}, up {s['uptime_s']:.0f} s, {s['config']})"]
    world = s.get("world")
    if isinstance(world, dict):
        lines.append(f"  simulated world: {world['text']}")
    if s.get("api"):
        lines.append(f"  api and dashboard: {s['api']}/")
    lines += [f"  fault: {f}" for f in s["faults"]]
    for joint, j in s["joints"].items():
        goal = "-" if j["goal_deg"] is None else f"{j['goal_deg']:.2f}"
        flags = ("moving " if j["moving"] else "") + ("" if j["torque_on"] else "torque off ")
        lines.append(f"  {joint:10s} {j['position_deg']:8.2f} deg  goal {goal:>7s}  {flags}"
                     f"{', '.join(j['hardware_errors'])}")
    loop = s["servo_loop"] or {}
    lines.append(f"  servo loop: {loop.get('rate_hz')} Hz, {loop.get('cycles')} cycles, period p50/p99 "
                 f"{loop.get('period_p50_ms')}/{loop.get('period_p99_ms')} ms, overruns {loop.get('overruns')}")
    pose = s.get("pose")
    if pose:
        lines.append(f"  pose: pan {pose['pan']:.2f}, tilt {pose['tilt']:.2f}, vergence {pose['vergence']:.2f} deg; "
                     f"torque {'on' if s.get('torque') else 'off'}")
    fx = s["fixation"]
    lines.append(f"  fixation: {fx['state']}; exploration {'on' if fx['explore'] else 'off'}; {fx['done']} done, "
                 f"{fx['taught']} taught; {fx.get('looks_queued', 0)} looks queued")
    for reason, n in sorted(fx["refused"].items(), key=lambda kv: -kv[1]):
        lines.append(f"    refused {n:5d}: {reason}")
    le = s["learning"]
    if le:
        mre = le.get("mean_retinal_error")
        lines.append(f"  learning: {le['adaptations']} adaptations ({le['adaptations_this_run']} this run), "
                     f"mean retinal error {'-' if mre is None else f'{mre:.3f}'}, "
                     f"output error {le.get('output_error_deg')} deg")
    mp = s["map"]
    lines.append(f"  map: {mp['path']} (restored from {mp['restored_from']}), {mp['checkpoints']} checkpoints")
    lines += [f"    problem: {p}" for p in mp["problems"]]
    for side, c in s["cameras"].items():
        lines.append(f"  camera {side}: {c['health']}, {c['stats'].get('frames')} frames, "
                     f"last {c['frame_age_s']} s ago")
    return "\n".join(lines)


# --- look ----------------------------------------------------------------------------------------
def _look(args: argparse.Namespace) -> int:
    """0: done; 1: the look failed or the daemon refused it; 4: still running after --wait."""
    from headctl.api.client import ApiError

    if args.relative and not args.angles:
        print("headctl look: --relative needs --angles (an image target is always relative to the view)",
              file=sys.stderr)
        return 2
    wanted = (3,) if args.angles else (2, 3)
    if len(args.values) not in wanted:
        what = "P T V (pan, tilt, vergence)" if args.angles else "X Y [D] (an image target)"
        print(f"headctl look: {len(args.values)} values given, expected {what}", file=sys.stderr)
        return 2
    client = _client(args, "look")
    if client is None:
        return 2
    a, b, c = (*args.values, None)[:3]
    job: JSONObject | None = None
    try:
        # Queued first, then waited on by id: Ctrl-C while waiting can then cancel it.
        if args.angles:
            job = client.look_angles(a, b, c, relative=args.relative, replace=args.replace)
        else:
            job = client.look_target(a, b, c, replace=args.replace)
        if args.wait > 0:
            print(f"look {job['id']} {job['state']}; waiting up to {args.wait:g} s (Ctrl-C cancels it)",
                  file=sys.stderr, flush=True)
            job = client.look(job["id"], wait_s=args.wait)
    except ApiError as err:
        print(f"headctl look: {err}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        if job is None:
            return 130
        try:
            job = client.cancel_look(job["id"], wait_s=5.0)
        except ApiError as err:  # it ended meanwhile, or the daemon went away
            print(f"headctl look: interrupted; look {job['id']} not cancelled: {err}", file=sys.stderr)
            return 130
    if args.json:
        print(json.dumps(job, indent=2))
    else:
        print(format_look(job))
    return {"done": 0, "failed": 1, "cancelled": 1}.get(job["state"], 4)


# --- track ---------------------------------------------------------------------------------------
def _track(args: argparse.Namespace) -> int:
    """0: started (or stopped, shown); 1: refused, lost or failed; 2: usage."""
    from headctl.api.client import ApiError

    fovea = args.target == ["fovea"]
    if (args.stop or args.status) == bool(args.target) or not (fovea or len(args.target) in (0, 2)):
        print("headctl track: give X Y, or fovea, or --stop, or --status", file=sys.stderr)
        return 2
    try:
        x, y = (None, None) if fovea or not args.target else (float(args.target[0]), float(args.target[1]))
    except ValueError:
        print(f"headctl track: {' '.join(args.target)}: expected two numbers X Y (px), or fovea", file=sys.stderr)
        return 2
    client = _client(args, "track")
    if client is None:
        return 2
    job: JSONObject | None = None
    try:
        if args.stop:
            job = client.stop_track()
        elif args.status:
            job = client.get_track()
        else:
            job = client.track(x, y)
            deadline = time.monotonic() + args.wait
            while args.wait > 0 and job["state"] in ("queued", "running") and time.monotonic() < deadline:
                job = client.look(job["id"], wait_s=min(5.0, max(0.0, deadline - time.monotonic())))
    except ApiError as err:
        print(f"headctl track: {err}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        if job is None:
            return 130
        try:
            job = client.stop_track()
        except ApiError as err:
            print(f"headctl track: interrupted; track {job['id']} not stopped: {err}", file=sys.stderr)
            return 130
    print(json.dumps(job, indent=2) if args.json else format_track(job))
    return 1 if job["state"] == "failed" else 0


def format_track(job: JSONObject) -> str:
    request = job["request"]
    line = f"track {job['id']} at x {request['x']:.1f}, y {request['y']:.1f}: {job['state']}"
    if job["outcome"]:
        line += f", {job['outcome']}"
    if job["detail"]:
        line += f" ({job['detail']})"
    lines = [line]
    stats = (job.get("result") or {}).get("stats")
    if stats:
        err, lat = stats["retinal_error_px"], stats["frame_to_command_ms"]
        rms = "-" if err["rms"] is None else f"{err['rms']:.1f}"
        p95 = "-" if err["p95"] is None else f"{err['p95']:.1f}"
        p50 = "-" if lat["p50"] is None else f"{lat['p50']:.0f}"
        lines.append(f"  {stats['found']} of {stats['frames'] + 1} pairs found; retinal error rms {rms} px, "
                     f"p95 {p95} px; frame to command p50 {p50} ms")
    if job["state"] in ("queued", "running"):
        lines.append("  `headctl track --stop` stops it; `headctl track --status` shows it")
    return "\n".join(lines)


def format_look(job: JSONObject) -> str:
    request, result = job["request"], job["result"]
    if request.get("d_measured"):
        d = f"{request['d']:.2f} px (measured, NCC {request['d_ncc']:.2f})"
    elif request.get("d_reason"):
        d = f"{request.get('d', 0):g} px (not measured: {request['d_reason']})"
    else:
        d = f"{request.get('d', 0):g} px"
    what = (f"target x {request['x']:g}, y {request['y']:g}, d {d}"
            if request["kind"] == "target"
            else f"{'relative ' if request.get('relative') else ''}angles pan {request['pan']:g}, "
                 f"tilt {request['tilt']:g}, vergence {request['vergence']:g} deg")
    line = f"look {job['id']} ({what}): {job['state']}"
    if job["outcome"]:
        line += f", {job['outcome']}"
    if job["detail"]:
        line += f" ({job['detail']})"
    lines = [line]
    if job["state"] in ("queued", "running"):
        lines.append(f"  still {job['state']}: GET /api/v1/looks/{job['id']}?wait_s=10 to wait for it")
    pose = result.get("pose_after")
    if pose is not None:
        lines.append(f"  pose now: pan {pose[0]:.2f}, tilt {pose[1]:.2f}, vergence {pose[2]:.2f} deg")
    if result.get("final_error_px") is not None:
        where = "on target" if result.get("on_target") else "not on target"
        lines.append(f"  {where}: the target ended {result['final_error_px']:.2f} px from the left fovea "
                     f"(tolerance {result['tolerance_px']:g} px) after {result['corrective_steps']} corrective "
                     f"step(s); {result['vergence_steps']} vergence steps, {result['taught']} fixation(s) taught")
    if result.get("landing_error_px") is not None:
        lines.append(f"  the first saccade landed {result['landing_error_px']:.1f} px from the target; confidence "
                     f"{result['confidence']:.2f}")
    if (result.get("head_moved_deg") or 0.0) > 0.25:
        lines.append(f"  the head had moved {result['head_moved_deg']:.1f} deg before the look ran (exploration, or a "
                     f"look before it): it went back to the view the target was chosen in first")
    return "\n".join(lines)
