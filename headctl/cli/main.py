"""The `headctl` command line: one entry point, one module per group of subcommands.

Each module in `COMMAND_MODULES` has `register(subparsers)`, which adds its subcommands and
sets `func(args) -> int` on each. Logging is configured here (a command's config may add a log
file and set the repeat limit's interval: `headctl.cli.service`): stderr (the journal under
systemd) behind the repeat limit of `headctl.log_limit`.
"""
from __future__ import annotations

import argparse
import importlib
import logging
import sys

from headctl import __version__, log_limit

COMMAND_MODULES = (
    "headctl.cli.experiment",  # experiment: the paper's experiments on the simulated head
    "headctl.cli.servos",      # emulate-servos, scan
    "headctl.cli.setup",       # setup: a new head's joints from the images
    "headctl.cli.cameras",     # cameras, snapshot
    "headctl.cli.service",     # run, check, status: the daemon
    "headctl.cli.record",      # record: rosbag2 bags of the running daemon
)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="headctl",
        description="Calibration-free driver service for a stereo camera head on Dynamixel servos.",
    )
    parser.add_argument("--version", action="version", version=f"headctl {__version__}")
    parser.add_argument(
        "--log-level", default="INFO", choices=["DEBUG", "INFO", "WARNING", "ERROR"],
        help="logging level (default INFO)",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for name in COMMAND_MODULES:
        importlib.import_module(name).register(sub)
    return parser


def configure_logging(level: str) -> None:
    """stderr at `level` behind the repeat limit (a fault's repeats: the first in full, then one
    summary line per interval); as `logging.basicConfig`, nothing if logging is set up already."""
    root = logging.getLogger()
    if root.handlers:
        return
    root.setLevel(getattr(logging, level))
    console = logging.StreamHandler()
    console.setFormatter(logging.Formatter("%(asctime)s %(levelname)-7s %(name)s: %(message)s"))
    log_limit.install(console)


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    configure_logging(args.log_level)
    try:
        return int(args.func(args) or 0)
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
