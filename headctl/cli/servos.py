"""Subcommands of `headctl` for the servos: `emulate-servos` and `scan`.

`emulate-servos` serves virtual servos, Protocol 2.0 X-series or Protocol 1.0 AX, RX and
MX, on a pseudo-terminal (see `drivers.dynamixel.emulator.server`) so anyone can develop without a head, and with `--control` takes
injected faults from outside (`drivers.dynamixel.emulator.control`); `scan` finds the servos on a
port, which is what people do first with a new head.
"""
from __future__ import annotations

import argparse
import contextlib
import signal
import sys
import threading

from drivers.errors import ServoError


def _int_list(text: str) -> list[int]:
    try:
        values = [int(part) for part in text.split(",") if part.strip()]
    except ValueError as err:
        raise argparse.ArgumentTypeError(f"expected comma-separated integers, got {text!r}") from err
    if not values:
        raise argparse.ArgumentTypeError("expected at least one value")
    return values


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Add this module's subcommands to `sub`."""
    from drivers.dynamixel.tables.x_series import X_BAUD_CODES, X_MODELS
    from drivers.dynamixel.tables.v1 import P1_MODELS

    emulate = sub.add_parser(
        "emulate-servos",
        help="serve virtual Dynamixel servos (Protocol 2.0 X-series, or 1.0 AX/RX/MX) on a pseudo-terminal",
        description="Serve virtual Dynamixel servos on a pseudo-terminal and print its path; "
                    "runs until interrupted (Ctrl-C or SIGTERM).",
    )
    emulate.add_argument("--ids", type=_int_list, default=[1, 2, 3, 4], help="servo ids (default 1,2,3,4)")
    emulate.add_argument("--protocol", choices=["1.0", "2.0"], default="2.0",
                         help="protocol the servos speak (default 2.0)")
    emulate.add_argument("--model", choices=sorted(X_MODELS) + sorted(P1_MODELS),
                         help="servo model (default XM430-W350 on Protocol 2.0, AX-12A on 1.0)")
    emulate.add_argument("--firmware", type=int, metavar="N",
                         help="the servos' firmware version (default 48 on 2.0, which has Fast Sync Read "
                              "from 45; 24 on 1.0)")
    emulate.add_argument("--baud", type=int, choices=sorted(X_BAUD_CODES), default=1_000_000,
                         help="the servos' baud rate (default 1000000; on 1.0: 9600, 57600, 115200 or 1000000)")
    emulate.add_argument("--link", metavar="PATH",
                         help="also keep a symlink PATH pointing at the pty (a stable name, like a udev rule's)")
    emulate.add_argument("--control", metavar="PATH", action="append", default=[],
                         help="take fault-injection commands (drop, corrupt, delay, hwerror, powercycle, vanish, "
                              "reappear, clear, status, help; one a line, one answer a line) on a Unix socket at "
                              "PATH, or on stdin with answers on stdout for '-'; may be given twice")
    emulate.set_defaults(func=_emulate)

    scan = sub.add_parser(
        "scan",
        help="find the Dynamixel servos on a port",
        description="Ping ids 0-252 at each baud rate and print id, model, firmware and baud.",
    )
    scan.add_argument("--port", required=True, help="serial port, e.g. /dev/head-servos or /dev/ttyUSB0")
    scan.add_argument("--baud", type=_int_list, default=[57600, 1_000_000],
                      help="comma-separated baud rates to try (default 57600,1000000)")
    scan.add_argument("--protocol", choices=["1.0", "2.0"], default="2.0", help="protocol version (default 2.0)")
    scan.set_defaults(func=_scan)


def _emulate(args: argparse.Namespace) -> int:
    from drivers.dynamixel.emulator.server import DxlEmulator
    from drivers.dynamixel.emulator.control import ControlSocket, EmulatorControl, serve_stream

    sockets = [path for path in args.control if path != "-"]
    if len(args.control) - len(sockets) > 1 or len(set(sockets)) != len(sockets):
        print("headctl emulate-servos: --control: each PATH (and '-') at most once", file=sys.stderr)
        return 2
    stop = threading.Event()
    previous = signal.signal(signal.SIGTERM, lambda *_: stop.set())
    try:
        with contextlib.ExitStack() as stack:
            try:
                emulator = DxlEmulator(args.ids, protocol=float(args.protocol), model=args.model,
                                       firmware=args.firmware, baud=args.baud, link=args.link)
            except ValueError as err:
                print(f"headctl emulate-servos: {err}", file=sys.stderr)
                return 2
            stack.enter_context(emulator)
            control = EmulatorControl(emulator)
            for path in sockets:
                try:
                    stack.enter_context(ControlSocket(control, path))
                except OSError as err:
                    print(f"headctl emulate-servos: --control {path}: {err}", file=sys.stderr)
                    return 2
            print(emulator.pty_path, flush=True)
            if args.link:
                print(f"{args.link} -> {emulator.pty_path}", file=sys.stderr, flush=True)
            for path in sockets:
                print(f"fault control on {path} (`help` lists the commands)", file=sys.stderr, flush=True)
            if "-" in args.control:
                # Answers go to stdout after the pty line; end of input ends this control only.
                threading.Thread(target=serve_stream, args=(control, sys.stdin, sys.stdout),
                                 name="dxl-emulator-control(stdin)", daemon=True).start()
                print("fault control on stdin (`help` lists the commands)", file=sys.stderr, flush=True)
            models = sorted({servo.model for servo in emulator.servos.values()})
            print(f"serving {len(args.ids)} {', '.join(models)} servo(s), ids {','.join(map(str, args.ids))}, "
                  f"Protocol {args.protocol}, {args.baud} baud; Ctrl-C to stop", file=sys.stderr, flush=True)
            try:
                while not stop.wait(1.0):
                    pass
            except KeyboardInterrupt:
                pass
    finally:
        signal.signal(signal.SIGTERM, previous)
    return 0


def _scan(args: argparse.Namespace) -> int:
    from drivers.dynamixel.scan import scan

    try:
        found = scan(args.port, args.baud, protocol=float(args.protocol))
    except ServoError as err:
        print(f"headctl scan: {err}", file=sys.stderr)
        return 2
    if not found:
        print(f"no servos found on {args.port} at {', '.join(map(str, args.baud))} baud "
              f"(protocol {args.protocol}); check power, wiring and the baud rate")
        return 1
    print(f"{'id':>3}  {'model':<12} {'number':>6}  {'firmware':>8}  {'baud':>8}")
    for r in found:
        print(f"{r.servo_id:>3}  {r.model_name:<12} {r.model_number:>6}  {r.firmware:>8}  {r.baud:>8}")
    return 0
