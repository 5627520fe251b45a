"""`headctl setup`: set a new head up by looking, not by reading a datasheet (docs/setup.md).

From a partial config (`servo_bus` without `joints`, and `cameras`): scan the bus and list
each servo; with the person's confirmation (`--yes` for none) move each a few degrees and
back, slowly, torque and velocity limited, while both cameras stream, and read off from the
image motion which joint it turns and which way; propose zeros and conservative limits,
widened by `--jog JOINT DEG`; write the config with a comment per value and run `headctl
check` on it. The assistant is `headctl.setup.assistant`; this module asks and tells.

Ctrl-C at any moment leaves every servo holding where it is, torque as it was, and exits 130.
"""
from __future__ import annotations

import argparse
import contextlib
import signal
import sys
import threading
from collections.abc import Iterator
from pathlib import Path
from types import FrameType

from drivers.errors import DriverError
from headctl.errors import ConfigError, HeadctlError
from headctl.setup.assistant import SetupOutcome, SetupRequest, assist, read_partial
from headctl.setup.identify import Interrupted

# Exit status of each way the assistant ends short of a written config.
EXIT_STATUS = {SetupOutcome.PROPOSED: 0, SetupOutcome.NO_SERVOS: 1, SetupOutcome.DECLINED: 1,
               SetupOutcome.JOINTS_MISSING: 1, SetupOutcome.UNKNOWN_JOG: 2, SetupOutcome.MIXED_BUS_SETTINGS: 1}


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Add `setup` to `sub`."""
    setup = sub.add_parser(
        "setup", help="set a new head up: find each servo's joint, direction, zero and limits from the images",
        description="Scan the bus, move each servo a few degrees and back (slowly, torque limited) while both "
                    "cameras stream, name its joint and direction from the image motion, propose zeros and "
                    "limits, write the config with a comment per value and check it. Ctrl-C leaves every servo "
                    "holding where it is. Walk-through: docs/setup.md.")
    setup.add_argument("--config", required=True, metavar="FILE",
                       help="a partial config: servo_bus (backend, port; joints may be left out) and cameras")
    setup.add_argument("--port", help="override servo_bus.port (e.g. /dev/head-servos)")
    setup.add_argument("--write", metavar="OUT", help="write the complete config here and run headctl check on it")
    setup.add_argument("--yes", action="store_true", help="move the servos without asking")
    setup.add_argument("--baud", type=lambda t: [int(b) for b in t.split(",")], metavar="B[,B...]",
                       help="scan only these baud rates (default: every one)")
    setup.add_argument("--protocol", choices=["1.0", "2.0"], action="append",
                       help="scan only this protocol (may be given twice; default both)")
    setup.add_argument("--ids", type=lambda t: range(int(t.split("-")[0]), int(t.split("-")[-1]) + 1),
                       metavar="LO-HI", help="ids a Protocol 1.0 scan pings (default 0-252)")
    setup.add_argument("--step", type=float, default=3.0, metavar="DEG", help="probing move (default 3 deg)")
    setup.add_argument("--jog", nargs=2, action="append", default=[], metavar=("JOINT", "DEG"),
                       help="move JOINT to DEG (joint frame, from the proposed zero) and widen its limit to it; "
                            "may be repeated")
    setup.add_argument("--frame-timeout", type=float, default=3.0, metavar="S", help="seconds to wait for a pair")
    setup.set_defaults(func=_setup)


class _Terminal:
    """The person at the terminal, as `headctl.setup.assistant.Person`."""

    def say(self, text: str) -> None:
        print(text, flush=True)

    def confirm(self, question: str) -> bool:
        return input(question).strip().lower() in ("y", "yes")

    @contextlib.contextmanager
    def stopping(self, stop: threading.Event) -> Iterator[None]:
        """Ctrl-C sets `stop` (the probing stops at its next check, servos held); a second one
        interrupts at once."""
        def handler(signum: int, frame: FrameType | None) -> None:
            if stop.is_set():
                raise KeyboardInterrupt
            stop.set()

        previous = signal.signal(signal.SIGINT, handler)
        try:
            yield
        finally:
            signal.signal(signal.SIGINT, previous)


def _request(args: argparse.Namespace) -> SetupRequest:
    return SetupRequest(
        Path(args.config), port=args.port, write=Path(args.write) if args.write else None, yes=args.yes,
        bauds=tuple(args.baud) if args.baud else None,
        protocols=tuple(float(p) for p in args.protocol) if args.protocol else None, ids=args.ids,
        step_deg=args.step, jogs=tuple((joint, float(deg)) for joint, deg in args.jog),
        frame_timeout_s=args.frame_timeout)


def _setup(args: argparse.Namespace) -> int:
    person = _Terminal()
    try:
        request = _request(args)
    except ValueError as err:
        print(f"headctl setup: --jog: expected a joint and degrees ({err})", file=sys.stderr)
        return 2
    try:
        partial = read_partial(request.config, request.port)
    except ConfigError as err:
        print(f"headctl setup: {err}", file=sys.stderr)
        return 2
    try:
        result = assist(request, partial, person)
    except Interrupted:
        person.say("interrupted: every servo moved was left holding where it is, torque as it was; nothing written")
        return 130
    except (DriverError, HeadctlError, OSError) as err:
        print(f"headctl setup: {err}", file=sys.stderr)
        return 1
    if result.outcome is SetupOutcome.UNKNOWN_JOG:
        print(f"headctl setup: {result.detail}", file=sys.stderr)
    if result.outcome is not SetupOutcome.WRITTEN or result.written is None:
        return EXIT_STATUS.get(result.outcome, 1)
    person.say(f"wrote {result.written}; checking it:")  # the bus is closed now, for check to open
    return _check(result.written)


def _check(path: Path) -> int:
    """`headctl check --config PATH`: the written config validated, connected and reported."""
    from headctl.cli import service

    parser = argparse.ArgumentParser(prog="headctl")
    service.register(parser.add_subparsers(dest="command", required=True))
    args = parser.parse_args(["check", "--config", str(path)])
    status: int = args.func(args)
    return status


__all__ = ["register"]
