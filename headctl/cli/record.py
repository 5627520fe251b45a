"""`headctl record`: rosbag2 recordings of the running daemon (`/api/v1/record`).

    headctl record start [--out DIR]     start a bag in DIR (default ros2.recording.directory)
    headctl record stop                  stop it; prints the bag's path
    headctl record status                the recording's state, files and message counts
    headctl record --seconds N [--out DIR]
                                         start, wait N seconds, stop, print where the bag is

The daemon writes the bag (headctl.ros2.recorder); `--out` is resolved here, so a relative
directory is the caller's.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING

from headctl.cli.service import _client, _client_args
from headctl.json_types import JSONObject

if TYPE_CHECKING:
    from headctl.api.client import ApiClient

POLL_S = 0.2


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    parser = sub.add_parser("record", help="record the running daemon's topics as a rosbag2 bag (MCAP)",
                            description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("action", nargs="?", choices=("start", "stop", "status"),
                        help="start, stop or show a recording (none: record for --seconds)")
    parser.add_argument("--seconds", type=float, help="record this long, then stop and print the bag's path")
    parser.add_argument("--out", metavar="DIR", help="the directory the bag is made in")
    _client_args(parser)
    parser.set_defaults(func=_record)


def _summary(status: JSONObject) -> str:
    messages = status.get("messages") or {}
    total = sum(int(v) for v in messages.values()) if isinstance(messages, dict) else 0
    files = status.get("files") or []
    return (f"{status.get('state')}: {status.get('path')} ({len(files) if isinstance(files, list) else 0} "
            f"files, {total} messages){': ' + str(status['error']) if status.get('error') else ''}")


def _record(args: argparse.Namespace) -> int:
    from headctl.api.client import ApiError

    if args.action is None and args.seconds is None:
        print("headctl record: give start, stop or status, or --seconds N", file=sys.stderr)
        return 2
    if args.action is not None and args.seconds is not None and args.action != "start":
        print(f"headctl record {args.action}: --seconds goes with start or alone", file=sys.stderr)
        return 2
    client = _client(args, "record")
    if client is None:
        return 1
    out = None
    if args.out:
        Path(args.out).mkdir(parents=True, exist_ok=True)
        out = str(Path(args.out).resolve())
    try:
        if args.action == "status":
            print(json.dumps(client.record_status(), indent=2))
            return 0
        if args.action == "stop":
            print(_summary(client.record_stop()))
            return 0
        started = client.record_start(out, args.seconds)
        if args.action == "start":
            print(f"recording to {started['path']}")
            return 0
        status = _wait(client, float(args.seconds))
    except ApiError as err:
        print(f"headctl record: {err}", file=sys.stderr)
        return 1
    print(_summary(status))
    print(status.get("path"))
    return 0 if status.get("state") == "stopped" else 1


def _wait(client: "ApiClient", seconds: float) -> JSONObject:
    """Wait for the daemon to stop the recording after `seconds` (it was started with them);
    stop it here if it has not a few seconds later, or on Ctrl-C."""
    deadline = time.monotonic() + seconds + 5.0
    try:
        while time.monotonic() < deadline:
            status = client.record_status()
            if status.get("state") != "recording":
                return status
            time.sleep(POLL_S)
    except KeyboardInterrupt:
        pass
    return client.record_stop()
