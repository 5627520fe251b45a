"""Faults injected into a running servo emulator from outside: a line protocol over stdin
or a Unix socket.

`headctl emulate-servos --control PATH` serves it on a Unix socket at PATH (mode 0600), and
`--control -` on its stdin (answers on stdout); both may be given. One command a line, one
answer a line, `ok ...` or `error <reason>`; blank lines and lines starting with `#` are
skipped. A bad command is answered with an error and changes nothing.

    drop ID [N]            the next N replies of servo ID are not sent (default 1)
    corrupt ID [N]         the next N replies of ID go out with a wrong CRC
    delay ID SECONDS [N]   the next N replies of ID go out SECONDS late (real time, at most 10 s)
    hwerror ID BITS        raise Hardware Error Status bits on ID: a number (32, 0x20, 0b100000)
                           or names joined by '+' (voltage, overheating, encoder, shock,
                           overload); the bits of the servo's Shutdown setting cut its torque;
                           latched until the servo reboots, as on a real servo
    powercycle ID          ID loses power and comes back: RAM defaults (torque off, hardware
                           error cleared, indirect addresses gone), silent while it boots
    remove ID              ID leaves the bus (cable unplugged, unpowered): it hears and answers
                           nothing, as a servo missing at start
    add ID                 ID is back on the bus, just powered up: RAM defaults (torque off),
                           silent while it boots
    brownout SECONDS [BITS]  every servo loses power: silent for SECONDS (at most 3600), then
                           back with RAM defaults as after `powercycle`, and Hardware Error
                           Status BITS if given (`voltage`: the Input Voltage error)
    vanish [SECONDS]       the adapter is unplugged (the pty closes, the link goes); back by
                           itself after SECONDS (real time), else on `reappear`
    reappear               the adapter is back now (a new pty; the link follows it)
    clear [ID]             cancel the pending drops, corruptions and delays of ID (or of all)
    status                 what is injected now: `ok ` and one line of JSON
    help                   the commands

`EmulatorControl.execute(line)` is the protocol; `ControlSocket` and `serve_stream` carry it.
"""
from __future__ import annotations

import errno
import json
import logging
import os
import selectors
import socket
import stat
import threading
from collections.abc import Callable
from typing import IO

from drivers.dynamixel.emulator.server import DxlEmulator
from drivers.errors import DriverError

log = logging.getLogger(__name__)

MAX_LINE_BYTES = 1024
MAX_COUNT = 1_000_000
MAX_DELAY_S = 10.0  # a reply delay holds the emulator's thread: longer would look like a hang
MAX_VANISH_S = 3600.0
MAX_BROWNOUT_S = 3600.0

# Hardware Error Status bits by short name (X-series address 70).
BIT_NAMES: dict[str, int] = {"voltage": 0x01, "overheating": 0x04, "encoder": 0x08, "shock": 0x10, "overload": 0x20}

USAGE = ("commands: drop ID [N] | corrupt ID [N] | delay ID SECONDS [N] | hwerror ID BITS | powercycle ID | "
         "remove ID | add ID | brownout SECONDS [BITS] | vanish [SECONDS] | reappear | clear [ID] | status | help")


class CommandError(ValueError):
    """A command that cannot be carried out; its message is the answer's reason."""


class EmulatorControl:
    """The control protocol over one `DxlEmulator`; safe to call from several threads."""

    def __init__(self, emulator: DxlEmulator) -> None:
        self.emulator = emulator
        self._commands: dict[str, Callable[[list[str]], str]] = {
            "drop": self._drop, "corrupt": self._corrupt, "delay": self._delay, "hwerror": self._hwerror,
            "powercycle": self._powercycle, "remove": self._remove, "add": self._add, "brownout": self._brownout,
            "vanish": self._vanish, "reappear": self._reappear,
            "clear": self._clear, "status": self._status, "help": lambda args: self._no_args(args, USAGE),
        }

    def execute(self, line: str | bytes) -> str | None:
        """The answer to one command line (without its newline), or None for a blank line or
        a comment. Never raises."""
        if isinstance(line, bytes):
            try:
                line = line.decode("utf-8")
            except UnicodeDecodeError:
                return "error not UTF-8 text"
        words = line.split()
        if not words or words[0].startswith("#"):
            return None
        name, args = words[0].lower(), words[1:]
        command = self._commands.get(name)
        if command is None:
            return f"error unknown command {name!r}; {USAGE}"
        try:
            answer = "ok " + command(args)
        except CommandError as err:
            return f"error {name}: {err}"
        except (DriverError, OSError, ValueError) as err:
            log.warning("dxl emulator control: %s failed: %s", line.strip(), err)
            return f"error {name}: {err}"
        except Exception as err:  # a bug must not take the emulator down with it
            log.exception("dxl emulator control: %s failed", line.strip())
            return f"error {name}: internal error: {type(err).__name__}: {err}"
        if name not in ("status", "help"):
            log.info("dxl emulator control: %s -> %s", " ".join(words), answer)
        return answer

    # -- arguments ---------------------------------------------------------------------------
    def _servo_id(self, word: str) -> int:
        try:
            servo_id = int(word, 0)
        except ValueError:
            raise CommandError(f"servo id {word!r} is not a number") from None
        if servo_id not in self.emulator.servos:
            raise CommandError(f"no servo with id {servo_id}; ids: {', '.join(map(str, self.emulator.servos))}")
        return servo_id

    @staticmethod
    def _count(args: list[str], index: int) -> int:
        if len(args) <= index:
            return 1
        try:
            count = int(args[index], 0)
        except ValueError:
            raise CommandError(f"count {args[index]!r} is not a whole number") from None
        if not 1 <= count <= MAX_COUNT:
            raise CommandError(f"count {count}: expected 1 to {MAX_COUNT}")
        return count

    @staticmethod
    def _seconds(word: str, most: float) -> float:
        try:
            seconds = float(word)
        except ValueError:
            raise CommandError(f"{word!r} is not a number of seconds") from None
        if not 0.0 <= seconds <= most:  # also refuses nan
            raise CommandError(f"{word} s: expected 0 to {most:g} s")
        return seconds

    @staticmethod
    def _arity(args: list[str], least: int, most: int, usage: str) -> None:
        if not least <= len(args) <= most:
            raise CommandError(f"expected {usage}")

    @staticmethod
    def _bits(word: str) -> int:
        try:
            bits = int(word, 0)
        except ValueError:
            names = word.lower().split("+")
            unknown = [n for n in names if n not in BIT_NAMES]
            if unknown:
                raise CommandError(f"bits {word!r}: expected a number (0x20) or names joined by '+' "
                                   f"({', '.join(BIT_NAMES)})") from None
            bits = sum({BIT_NAMES[n] for n in names})
        if not 1 <= bits <= 0xFF:
            raise CommandError(f"bits {word}: expected 1 to 0xff (a hardware error is cleared only by a reboot "
                               "or a power cycle)")
        return bits

    @staticmethod
    def _no_args(args: list[str], answer: str) -> str:
        if args:
            raise CommandError("takes no arguments")
        return answer

    # -- commands ------------------------------------------------------------------------------
    def _drop(self, args: list[str]) -> str:
        self._arity(args, 1, 2, "drop ID [N]")
        servo_id, count = self._servo_id(args[0]), self._count(args, 1)
        self.emulator.drop_replies(servo_id, count)
        return f"id {servo_id}: the next {count} repl{'y' if count == 1 else 'ies'} dropped"

    def _corrupt(self, args: list[str]) -> str:
        self._arity(args, 1, 2, "corrupt ID [N]")
        servo_id, count = self._servo_id(args[0]), self._count(args, 1)
        self.emulator.corrupt_replies(servo_id, count)
        return f"id {servo_id}: the next {count} repl{'y' if count == 1 else 'ies'} with a bad CRC"

    def _delay(self, args: list[str]) -> str:
        self._arity(args, 2, 3, "delay ID SECONDS [N]")
        servo_id, seconds, count = self._servo_id(args[0]), self._seconds(args[1], MAX_DELAY_S), self._count(args, 2)
        self.emulator.delay_replies(servo_id, seconds, count)
        return f"id {servo_id}: the next {count} repl{'y' if count == 1 else 'ies'} {seconds:g} s late"

    def _hwerror(self, args: list[str]) -> str:
        self._arity(args, 2, 2, "hwerror ID BITS")
        servo_id, bits = self._servo_id(args[0]), self._bits(args[1])
        self.emulator.set_hardware_error(servo_id, bits)
        servo = self.emulator.injected()["servos"][servo_id]
        names = "+".join(name for name, bit in BIT_NAMES.items() if bits & bit) or "unknown bits"
        return (f"id {servo_id}: hardware error 0x{bits:02x} ({names}) raised; status now "
                f"0x{servo['hardware_error']:02x}, torque {'on' if servo['torque_on'] else 'off'}")

    def _powercycle(self, args: list[str]) -> str:
        self._arity(args, 1, 1, "powercycle ID")
        servo_id = self._servo_id(args[0])
        self.emulator.power_cycle(servo_id)
        return f"id {servo_id}: power cycled (RAM defaults, torque off; booting)"

    def _remove(self, args: list[str]) -> str:
        self._arity(args, 1, 1, "remove ID")
        servo_id = self._servo_id(args[0])
        self.emulator.remove_servo(servo_id)
        return f"id {servo_id}: off the bus (it answers nothing until `add {servo_id}`)"

    def _add(self, args: list[str]) -> str:
        self._arity(args, 1, 1, "add ID")
        servo_id = self._servo_id(args[0])
        self.emulator.add_servo(servo_id)
        return f"id {servo_id}: back on the bus (RAM defaults, torque off; booting)"
    def _brownout(self, args: list[str]) -> str:
        self._arity(args, 1, 2, "brownout SECONDS [BITS]")
        seconds = self._seconds(args[0], MAX_BROWNOUT_S)
        bits = self._bits(args[1]) if len(args) > 1 else 0
        self.emulator.brown_out(seconds, bits)
        return (f"every servo without power for {seconds:g} s, then back with RAM defaults"
                + (f" and hardware error 0x{bits:02x}" if bits else ""))

    def _vanish(self, args: list[str]) -> str:
        self._arity(args, 0, 1, "vanish [SECONDS]")
        if not args:
            self.emulator.vanish()
            return "port vanished until `reappear`"
        seconds = self._seconds(args[0], MAX_VANISH_S)
        self.emulator.vanish(for_s=seconds)
        return f"port vanished for {seconds:g} s"

    def _reappear(self, args: list[str]) -> str:
        self._no_args(args, "")
        self.emulator.reappear()
        return f"port back at {self.emulator.port}"

    def _clear(self, args: list[str]) -> str:
        self._arity(args, 0, 1, "clear [ID]")
        servo_id = self._servo_id(args[0]) if args else None
        self.emulator.clear_faults(servo_id)
        return ("pending drops, corruptions and delays cancelled"
                + (f" for id {servo_id}" if servo_id is not None else " for every id"))

    def _status(self, args: list[str]) -> str:
        self._no_args(args, "")
        return json.dumps(self.emulator.injected(), separators=(",", ":"))


def serve_stream(control: EmulatorControl, infile: IO[str], outfile: IO[str]) -> None:
    """Answer the commands read from `infile` on `outfile` until end of file."""
    for line in infile:
        answer = control.execute(line[:MAX_LINE_BYTES]) if len(line) <= MAX_LINE_BYTES else \
            f"error line longer than {MAX_LINE_BYTES} bytes"
        if answer is not None:
            outfile.write(answer + "\n")
            outfile.flush()


class _Connection:
    def __init__(self, sock: socket.socket) -> None:
        self.sock = sock
        self.buffer = bytearray()
        self.skipping = False  # inside a line that was too long: drop up to its newline


class ControlSocket:
    """The control protocol on a Unix stream socket at `path`, served from one named thread.

    Any number of clients at once, each answered in order. The socket is made mode 0600
    (the user's alone); a stale socket left by a dead emulator is replaced, a live one (or
    anything else at `path`) is refused. Use as a context manager or `start()`/`stop()`.
    """

    SEND_TIMEOUT_S = 1.0  # a client that does not read its answers is dropped

    def __init__(self, control: EmulatorControl, path: str) -> None:
        self.control = control
        self.path = path
        self._listener: socket.socket | None = None
        self._thread: threading.Thread | None = None
        self._wake_r, self._wake_w = os.pipe()

    def start(self) -> "ControlSocket":
        self._clear_stale()
        listener = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        old_umask = os.umask(0o177)
        try:
            listener.bind(self.path)
        except OSError:
            listener.close()
            raise
        finally:
            os.umask(old_umask)
        listener.listen(8)
        listener.setblocking(False)
        self._listener = listener
        self._thread = threading.Thread(target=self._run, name=f"dxl-emulator-control({self.path})", daemon=True)
        self._thread.start()
        log.info("dxl emulator control on %s", self.path)
        return self

    def stop(self, timeout: float = 2.0) -> None:
        """Close every connection and the socket, and remove its file. Safe to call twice."""
        if self._thread is not None:
            os.write(self._wake_w, b"x")
            self._thread.join(timeout)
            self._thread = None
        if self._listener is not None:
            self._listener.close()
            self._listener = None
            try:
                os.unlink(self.path)
            except FileNotFoundError:
                pass
        for fd in (self._wake_r, self._wake_w):
            try:
                os.close(fd)
            except OSError:
                pass
        self._wake_r = self._wake_w = -1

    def __enter__(self) -> "ControlSocket":
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def _clear_stale(self) -> None:
        try:
            mode = os.lstat(self.path).st_mode
        except FileNotFoundError:
            return
        if not stat.S_ISSOCK(mode):
            raise FileExistsError(errno.EEXIST, "exists and is not a socket; not replaced", self.path)
        probe = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        try:
            probe.connect(self.path)
        except (ConnectionRefusedError, FileNotFoundError):
            os.unlink(self.path)  # left by an emulator that died
            return
        finally:
            probe.close()
        raise OSError(errno.EADDRINUSE, "another emulator's control socket answers there", self.path)

    def _run(self) -> None:
        listener = self._listener
        assert listener is not None
        sel = selectors.DefaultSelector()
        sel.register(listener, selectors.EVENT_READ)
        sel.register(self._wake_r, selectors.EVENT_READ)
        connections: dict[int, _Connection] = {}
        try:
            while True:
                for key, _events in sel.select():
                    if key.fileobj == self._wake_r:
                        return
                    if key.fileobj is listener:
                        try:
                            sock, _address = listener.accept()
                        except (BlockingIOError, InterruptedError):
                            continue
                        sock.settimeout(self.SEND_TIMEOUT_S)
                        connections[sock.fileno()] = _Connection(sock)
                        sel.register(sock, selectors.EVENT_READ)
                        continue
                    assert isinstance(key.fileobj, socket.socket)
                    conn = connections[key.fileobj.fileno()]
                    if not self._serve(conn):
                        sel.unregister(conn.sock)
                        del connections[conn.sock.fileno()]
                        conn.sock.close()
        except Exception:  # the control must not die silently
            log.exception("dxl emulator control on %s: stopped by an error", self.path)
        finally:
            for conn in connections.values():
                conn.sock.close()
            sel.close()

    def _serve(self, conn: _Connection) -> bool:
        """Read what the client sent and answer each complete line; False once it is gone."""
        try:
            data = conn.sock.recv(4096)
        except OSError:
            return False
        if not data:
            return False
        conn.buffer += data
        answers: list[str] = []
        while True:
            newline = conn.buffer.find(b"\n")
            if newline < 0:
                if len(conn.buffer) > MAX_LINE_BYTES and not conn.skipping:
                    answers.append(f"error line longer than {MAX_LINE_BYTES} bytes")
                    conn.skipping = True
                if conn.skipping:
                    conn.buffer.clear()
                break
            line = bytes(conn.buffer[:newline])
            del conn.buffer[:newline + 1]
            if conn.skipping:
                conn.skipping = False
                continue
            if len(line) > MAX_LINE_BYTES:
                answers.append(f"error line longer than {MAX_LINE_BYTES} bytes")
                continue
            answer = self.control.execute(line)
            if answer is not None:
                answers.append(answer)
        if answers:
            try:
                conn.sock.sendall("".join(a + "\n" for a in answers).encode("utf-8"))
            except OSError:
                return False
        return True
